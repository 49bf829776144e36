"""The residual networks of `ResidualDynamics`: an `MLP` of the whole state, a `JointResidual`.

Both are plain ``nn.Module`` maps from state features ``(*batch, n_features)`` to torques
``(*batch, n_dof)`` that standardise their inputs (and scale their outputs) from the training
data (`fit_normalization`) and initialise from a seed. `JointResidual` gives each joint a small
network of that joint's own features only, the shape of what rigid-body models leave out.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["MLP", "JointResidual"]

_ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "silu": nn.SiLU, "gelu": nn.GELU}
_MIN_RELATIVE_STD = 1e-2  # JointResidual: standardise by at least 1% of a feature's RMS


def _check_network(widths: dict, hidden: Sequence[int], activation: str) -> tuple[int, ...]:
    """Validate a network's widths and activation; returns ``hidden`` as a tuple."""
    for name, v in widths.items():
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    hidden = tuple(hidden)
    if any(isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in hidden):
        raise ValueError(f"hidden must be a sequence of positive ints, got {hidden!r}")
    if activation not in _ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {activation!r}")
    return hidden


class MLP(nn.Module):
    """A fully connected network with input and output standardisation.

    ``y = out_std * net((x - in_mean) / in_std) + out_mean``; the four statistics are buffers
    (saved in ``state_dict``), identity until `fit_normalization` sets them from data.

    Args:
        in_features: input width.
        out_features: output width.
        hidden: widths of the hidden layers.
        activation: ``"tanh"``, ``"relu"``, ``"silu"`` or ``"gelu"``.
        dtype: of the weights (float64 by default, as the physics part).
        device: of the weights.
        seed: seeds the weight initialisation (a local ``torch.Generator``), None: torch's
            global generator.
        zero_output: start the last layer at zero, so that the untrained network returns
            ``out_mean`` (a residual model then starts as its physics part).
    """

    def __init__(
        self,
        in_features: int,
        out_features: int,
        *,
        hidden: Sequence[int] = (64, 64),
        activation: str = "tanh",
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
        seed: int | None = 0,
        zero_output: bool = True,
    ) -> None:
        super().__init__()
        hidden = _check_network(
            {"in_features": in_features, "out_features": out_features}, hidden, activation
        )
        self.in_features, self.out_features = in_features, out_features
        self.hidden, self.activation = hidden, activation
        widths = (in_features, *hidden, out_features)
        layers: list[nn.Module] = []
        for k in range(len(widths) - 1):
            layers.append(nn.Linear(widths[k], widths[k + 1], dtype=dtype, device=device))
            if k < len(widths) - 2:
                layers.append(_ACTIVATIONS[activation]())
        self.net = nn.Sequential(*layers)
        self.zero_output = bool(zero_output)
        if seed is not None:
            self.reset_parameters(seed)
        elif self.zero_output:
            with torch.no_grad():
                layers[-1].weight.zero_()
                layers[-1].bias.zero_()
        kw = {"dtype": dtype, "device": device}
        self.register_buffer("in_mean", torch.zeros(in_features, **kw))
        self.register_buffer("in_std", torch.ones(in_features, **kw))
        self.register_buffer("out_mean", torch.zeros(out_features, **kw))
        self.register_buffer("out_std", torch.ones(out_features, **kw))

    def reset_parameters(self, seed: int) -> None:
        """Re-initialise the weights uniformly in ``+-1/sqrt(fan_in)`` (as ``nn.Linear``),
        from a generator seeded ``seed``; the last layer at zero with ``zero_output``."""
        g = torch.Generator(device="cpu").manual_seed(int(seed))
        linear = [m for m in self.net if isinstance(m, nn.Linear)]
        with torch.no_grad():
            for k, layer in enumerate(linear):
                bound = layer.in_features**-0.5
                for p in (layer.weight, layer.bias):
                    u = torch.rand(p.shape, generator=g, dtype=torch.float64)
                    p.copy_((2 * u - 1) * bound)
                    if self.zero_output and k == len(linear) - 1:
                        p.zero_()

    @torch.no_grad()
    def fit_normalization(self, inputs: torch.Tensor, targets: torch.Tensor | None = None) -> None:
        """Set the standardisation from data.

        Args:
            inputs: ``(n, in_features)``.
            targets: ``(n, out_features)``; None keeps the output statistics.
        """
        for name, x, width in (
            ("inputs", inputs, self.in_features),
            ("targets", targets, self.out_features),
        ):
            if x is None:
                continue
            if x.ndim != 2 or x.shape[1] != width or x.shape[0] < 2:
                raise ValueError(f"{name} must have shape (n >= 2, {width}), got {tuple(x.shape)}")
            mean, std = x.mean(0), x.std(0)
            std = torch.where(std > 0, std, torch.ones_like(std))
            prefix = "in" if name == "inputs" else "out"
            getattr(self, f"{prefix}_mean").copy_(mean)
            getattr(self, f"{prefix}_std").copy_(std)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(*batch, in_features)`` -> ``(*batch, out_features)`` in the weights' dtype."""
        x = x.to(self.in_mean.dtype)
        return self.net((x - self.in_mean) / self.in_std) * self.out_std + self.out_mean

    def extra_repr(self) -> str:
        return f"hidden={self.hidden}, activation={self.activation!r}"


class JointResidual(nn.Module):
    """A joint-local residual: joint ``j``'s torque from joint ``j``'s own features only.

    What a rigid-body model leaves out of a joint's torque is mostly that joint's own business:
    rotor inertia (armature, ``~ qdd_j``), viscous and dry friction (``~ qd_j``,
    ``~ sign(qd_j)``), springs and cables (``~ q_j``). A network of the whole state has to find
    that structure in the data, and from one trajectory it finds correlations that do not carry
    over to another; this module has it built in. For each joint::

        f_j   = [x_1j, ..., x_kj, tanh(x_vj / friction_velocity)]   (the last one optional)
        phi_j = (f_j - in_mean_j) / in_std_j
        r_j   = out_std_j * (linear_j . phi_j + mlp_j(phi_j)) + out_mean_j

    with a separate small network ``mlp_j`` per joint (all joints evaluated in one batched
    product) and a linear term, which `fit_normalization` sets by least squares, so that the
    networks only learn what a linear armature / friction / spring model leaves. The smooth
    sign ``tanh(qd / friction_velocity)`` is the usual regularised Coulomb friction.

    Args:
        n_dof: joints.
        n_inputs: features per joint ``k``; the input is ``(*batch, k n_dof)`` laid out feature
            by feature (``[x_1 of every joint, x_2 of every joint, ...]``), as `state_features`
            gives ``[q, qd, qdd]`` (``k = 3``).
        hidden: widths of each joint's hidden layers; ``()`` for the linear term alone.
        activation: ``"tanh"``, ``"relu"``, ``"silu"`` or ``"gelu"``.
        friction_velocity: velocity scale of the smooth Coulomb feature, in the units of the
            velocity feature (rad/s or m/s); None leaves the feature out.
        velocity_index: which of the ``k`` features is the joint velocity (1 for
            `state_features`).
        ridge: penalty of the least-squares fit of the linear term, per sample, on standardised
            features (the features of a joint that moved have variance 1 and are shrunk by
            ``1 / (1 + ridge)`` at most).
        dtype: as for `MLP`.
        device: as for `MLP`.
        seed: as for `MLP`.
        zero_output: as for `MLP` (the untrained residual is then ``out_mean``: zero before
            `fit_normalization`).

    Attributes:
        linear: ``(n_dof, k')`` weights of the linear term (``k' = k + 1`` with the friction
            feature); excluded from weight decay (`no_weight_decay`).
        weights, biases: the per-joint networks' layers, ``(n_dof, in, out)`` and
            ``(n_dof, out)``.
    """

    def __init__(
        self,
        n_dof: int,
        n_inputs: int = 3,
        *,
        hidden: Sequence[int] = (16, 16),
        activation: str = "tanh",
        friction_velocity: float | None = 0.01,
        velocity_index: int = 1,
        ridge: float = 1e-3,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
        seed: int | None = 0,
        zero_output: bool = True,
    ) -> None:
        super().__init__()
        hidden = _check_network({"n_dof": n_dof, "n_inputs": n_inputs}, hidden, activation)
        if friction_velocity is not None and not friction_velocity > 0:
            raise ValueError(f"friction_velocity must be > 0 or None, got {friction_velocity!r}")
        if friction_velocity is not None and not 0 <= velocity_index < n_inputs:
            raise ValueError(f"velocity_index must be in [0, {n_inputs}), got {velocity_index!r}")
        self.n_dof, self.n_inputs, self.hidden, self.activation = (
            n_dof,
            n_inputs,
            hidden,
            activation,
        )
        self.friction_velocity = None if friction_velocity is None else float(friction_velocity)
        self.velocity_index = int(velocity_index)
        if not ridge > 0:
            raise ValueError(f"ridge must be > 0, got {ridge!r}")
        self.ridge = float(ridge)
        self.zero_output = bool(zero_output)
        k = n_inputs + (friction_velocity is not None)
        kw = {"dtype": dtype, "device": device}
        widths = (k, *hidden, 1) if hidden else ()
        self.weights = nn.ParameterList(
            nn.Parameter(torch.zeros(n_dof, a, b, **kw))
            for a, b in zip(widths, widths[1:], strict=False)
        )
        self.biases = nn.ParameterList(
            nn.Parameter(torch.zeros(n_dof, b, **kw)) for b in widths[1:]
        )
        self.linear = nn.Parameter(torch.zeros(n_dof, k, **kw))
        self._act = _ACTIVATIONS[activation]()
        if seed is not None:
            self.reset_parameters(seed)
        self.register_buffer("in_mean", torch.zeros(n_dof, k, **kw))
        self.register_buffer("in_std", torch.ones(n_dof, k, **kw))
        self.register_buffer("out_mean", torch.zeros(n_dof, **kw))
        self.register_buffer("out_std", torch.ones(n_dof, **kw))

    def reset_parameters(self, seed: int) -> None:
        """Each joint's layers uniform in ``+-1/sqrt(fan_in)`` from a generator seeded ``seed``
        (the last layer at zero with ``zero_output``); the linear term at zero."""
        g = torch.Generator(device="cpu").manual_seed(int(seed))
        last = len(self.weights) - 1
        with torch.no_grad():
            for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
                bound = w.shape[1] ** -0.5
                for p in (w, b):
                    u = torch.rand(p.shape, generator=g, dtype=torch.float64)
                    p.copy_((2 * u - 1) * bound)
                    if self.zero_output and i == last:
                        p.zero_()
            self.linear.zero_()

    def no_weight_decay(self) -> set[str]:
        """Parameters an optimiser should not decay (the linear term is a physical model,
        fitted by least squares, not a network weight)."""
        return {"linear"}

    def joint_features(self, x: torch.Tensor) -> torch.Tensor:
        """``(*batch, k n_dof)`` -> the raw per-joint features ``(*batch, n_dof, k')``."""
        if x.shape[-1] != self.n_inputs * self.n_dof:
            raise ValueError(
                f"expected (*batch, {self.n_inputs * self.n_dof}) inputs ({self.n_inputs} "
                f"features of {self.n_dof} joints), got {tuple(x.shape)}"
            )
        f = x.to(self.in_mean.dtype).unflatten(-1, (self.n_inputs, self.n_dof)).transpose(-1, -2)
        if self.friction_velocity is None:
            return f
        v = f[..., self.velocity_index : self.velocity_index + 1]
        return torch.cat([f, torch.tanh(v / self.friction_velocity)], -1)

    @torch.no_grad()
    def fit_normalization(self, inputs: torch.Tensor, targets: torch.Tensor | None = None) -> None:
        """Set the standardisation from data and, given targets, the linear term by least
        squares (per joint, ridge-regularised, see ``ridge``; the intercept is ``out_mean``).

        Args:
            inputs: ``(n, k n_dof)``.
            targets: ``(n, n_dof)`` residual torques; None keeps the output statistics and the
                linear term.
        """
        if inputs.ndim != 2 or inputs.shape[0] < 2:
            raise ValueError(f"inputs must have shape (n >= 2, k n_dof), got {tuple(inputs.shape)}")
        f = self.joint_features(inputs)
        # a feature that hardly varies in these data (a velocity that never changes sign: its
        # friction feature is +-1 throughout) is scaled by at least 1% of its size, not by
        # its spread, so that other data do not land thousands of units away
        std = torch.maximum(f.std(0), _MIN_RELATIVE_STD * f.pow(2).mean(0).sqrt())
        self.in_mean.copy_(f.mean(0))
        self.in_std.copy_(torch.where(std > 0, std, torch.ones_like(std)))
        if targets is None:
            return
        if targets.shape != (inputs.shape[0], self.n_dof):
            raise ValueError(
                f"targets must have shape ({inputs.shape[0]}, {self.n_dof}), "
                f"got {tuple(targets.shape)}"
            )
        y = targets.to(f.dtype)
        std = y.std(0)
        self.out_mean.copy_(y.mean(0))
        self.out_std.copy_(torch.where(std > 0, std, torch.ones_like(std)))
        phi = ((f - self.in_mean) / self.in_std).transpose(0, 1)  # (n_dof, n, k')
        b = ((y - self.out_mean) / self.out_std).T.unsqueeze(-1)  # (n_dof, n, 1)
        # ridge regression on the centred, standardised features (the intercept is the mean):
        # a well-excited feature (variance 1) is hardly shrunk, a nearly constant one is zeroed
        k = phi.shape[-1]
        gram = phi.transpose(1, 2) @ phi + (self.ridge * phi.shape[1]) * torch.eye(k).to(phi)
        self.linear.copy_(torch.linalg.solve(gram, phi.transpose(1, 2) @ b)[..., 0])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(*batch, k n_dof)`` -> ``(*batch, n_dof)`` in the weights' dtype."""
        phi = (self.joint_features(x) - self.in_mean) / self.in_std
        out = (phi * self.linear).sum(-1)
        h = phi
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = torch.einsum("...ji,jio->...jo", h, w) + b
            if i < len(self.weights) - 1:
                h = self._act(h)
        if len(self.weights):
            out = out + h[..., 0]
        return out * self.out_std + self.out_mean

    def extra_repr(self) -> str:
        return (
            f"n_dof={self.n_dof}, n_inputs={self.n_inputs}, hidden={self.hidden}, "
            f"activation={self.activation!r}, friction_velocity={self.friction_velocity}"
        )
