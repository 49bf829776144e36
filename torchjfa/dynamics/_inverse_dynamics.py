"""`InverseDynamics`: an identified (or nominal) rigid-body model as an ``nn.Module``.

``tau = Y(q, qd, qdd) @ theta`` with theta frozen or trained. Use it for computed-torque
control, to compare identified models on held-out data, to simulate (`forward_dynamics`,
`mass_matrix`, `torchjfa.dynamics.rollout`), or as the physics part of a model whose residual
is learned. With ``trainable=True`` it trains through a physically consistent parametrisation
(log-Cholesky pseudo-inertias, non-negative friction and armature), so every optimiser step
gives a theta that `torchjfa.physical.check` accepts; ``trainable="unconstrained"`` trains theta
itself. The forward pass traces with `torch.export` and `torch.compile` (no data-dependent
branches while tracing). The regressor itself lives in `RigidBodyModel`.
"""

from __future__ import annotations

import torch
from torch import nn

from .._util import note
from .._validation import as_tensor, check_finite
from ._consistency import check
from ._forward import bias_forces, forward_dynamics, mass_matrix, regressor
from ._model import RigidBodyModel
from ._parameters import ParameterLayout
from ._parametrizations import LogCholeskyParameters

__all__ = ["InverseDynamics", "ConsistentTheta", "PARAMETRIZATIONS"]

PARAMETRIZATIONS = ("frozen", "consistent", "unconstrained")
_TRAINABLE = {False: "frozen", True: "consistent", "consistent": "consistent"}
_TRAINABLE["unconstrained"] = "unconstrained"
# a joint term that is 0 (or negative) starts at this fraction of the mean magnitude of the
# same term over the joints, and at least at _FLOOR_ABS (SI units), so that it can grow
_FLOOR_FRACTION = 1e-3
_FLOOR_ABS = 1e-6


def _softplus(x: torch.Tensor) -> torch.Tensor:
    return torch.logaddexp(x, torch.zeros_like(x))  # log(1 + e^x), accurate for every x


def _inverse_softplus(f: torch.Tensor) -> torch.Tensor:
    return f + torch.log(-torch.expm1(-f))  # log(e^f - 1) for f > 0


class ConsistentTheta(nn.Module):
    """theta of a `ParameterLayout` as a function of free variables, consistent for all values.

    Each body's inertial parameters come from the log-Cholesky factor of its pseudo-inertia
    (`torchjfa.physical.LogCholeskyParameters`, submodule ``inertial``: positive mass, positive
    definite inertia, triangle inequalities); each viscous, Coulomb and armature term is
    ``softplus(psi) = log(1 + e^psi) > 0`` of a free ``psi`` (``joint_terms``), an offset term is
    ``psi`` itself. Unlike a square, softplus has a non-zero gradient everywhere, so a term that
    starts near 0 can still grow.

    Args:
        layout: the `ParameterLayout`.
        theta: ``(n_params,)`` float64 starting point. Consistent bodies are reproduced to
            rounding (about 1e-15 relative); an inconsistent body starts at a nearby consistent
            one (see `LogCholeskyParameters.from_theta`); a viscous, Coulomb or armature term
            <= 0 starts at 1e-3 of that term's mean magnitude over the joints, at least 1e-6
            (N m s/rad, N m, kg m^2).
    """

    def __init__(self, layout: ParameterLayout, theta: torch.Tensor) -> None:
        super().__init__()
        self.layout = layout
        inertial, terms = layout.split(theta.detach().to(torch.float64))
        body_layout = ParameterLayout(layout.joint_names, ())
        self.inertial = LogCholeskyParameters.from_theta(inertial.reshape(-1), body_layout)
        signed = [kind != "offset" for kind in layout.friction]
        self.register_buffer("_signed", torch.tensor(signed, dtype=torch.bool), persistent=False)
        psi = terms.clone()
        for k, positive in enumerate(signed):
            if positive:
                f = terms[:, k]
                floor = max(_FLOOR_FRACTION * float(f.abs().mean()), _FLOOR_ABS)
                psi[:, k] = _inverse_softplus(torch.where(f > 0, f, torch.full_like(f, floor)))
        self.joint_terms = nn.Parameter(psi)

    def forward(self) -> torch.Tensor:
        """theta, ``(n_params,)`` in the variables' dtype, differentiable."""
        inertial = self.inertial().reshape(self.layout.n_joints, 10)
        psi = self.joint_terms
        terms = torch.where(self._signed, _softplus(psi), psi)
        return self.layout.join(inertial, terms)


class InverseDynamics(nn.Module):
    """Joint torques of a rigid-body model with parameters theta.

    Args:
        model: the `RigidBodyModel` (kinematics, layout, friction terms).
        theta: ``(n_params,)`` parameters; default ``model.nominal_theta``. Stored in float64.
        trainable: how theta is held (`parametrization`):

            - ``False`` (default): frozen, an ``nn.Parameter`` ``theta`` with
              ``requires_grad=False``; `theta` is exactly the given one.
            - ``True`` or ``"consistent"``: trained through a `ConsistentTheta` (submodule
              ``consistent``), so theta stays physically consistent under any optimiser step.
              It starts at the given theta to rounding when that is consistent; otherwise at a
              nearby consistent point (a note says so), and zero friction or armature terms
              start at a small positive value (see `ConsistentTheta`).
            - ``"unconstrained"``: the ``nn.Parameter`` ``theta`` itself is trained
              (``requires_grad=True``); any value, physical or not, can result.

            Either way the variables are in ``state_dict`` (``theta``, or ``consistent.*``).

    Attributes:
        theta: ``(n_params,)`` the current parameters; with ``trainable=True`` computed from
            the parametrisation at each access (differentiable).

    Example:
        >>> model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda"))  # doctest: +SKIP
        >>> idyn = InverseDynamics(model, theta_hat)                          # doctest: +SKIP
        >>> tau = idyn(q, qd, qdd)   # (*batch, n_dof)                        # doctest: +SKIP
        >>> qdd = idyn.forward_dynamics(q, qd, tau)                           # doctest: +SKIP
    """

    def __init__(self, model: RigidBodyModel, theta=None, *, trainable: bool | str = False) -> None:
        super().__init__()
        if not isinstance(model, RigidBodyModel):
            raise TypeError(f"model must be a RigidBodyModel, got {type(model)}")
        kind = _TRAINABLE.get(trainable) if isinstance(trainable, (bool, str)) else None
        if kind is None:
            raise ValueError(
                "trainable must be False, True (or 'consistent') or 'unconstrained', "
                f"got {trainable!r}"
            )
        self.model = model
        if theta is None:
            theta = model.nominal_theta
        theta = as_tensor(theta, name="theta", dtype=torch.float64)
        if theta.shape != (model.n_params,):
            raise ValueError(
                f"theta must have shape ({model.n_params},) for this model, "
                f"got {tuple(theta.shape)}"
            )
        check_finite(theta, "theta")
        self._parametrization = kind
        if kind == "consistent":
            report = check(theta.detach(), model.layout)
            if not report.ok:
                ok = report.body_ok.tolist()
                bad = [j for j, good in zip(model.joint_names, ok, strict=True) if not good]
                note(
                    f"theta is not physically consistent (bodies of {bad}); the consistent "
                    "parametrisation starts at a nearby consistent theta (trainable="
                    "'unconstrained' trains theta as it is)",
                    key="inverse-dynamics-consistent-start",
                )
            self.consistent = ConsistentTheta(model.layout, theta)
        else:
            self.register_parameter(
                "theta", nn.Parameter(theta.detach().clone(), requires_grad=kind != "frozen")
            )

    @property
    def theta(self) -> torch.Tensor:
        """``(n_params,)`` parameters (computed from `consistent` when it is used)."""
        if "theta" in self._parameters:
            return self._parameters["theta"]
        if "consistent" in self._modules:
            return self._modules["consistent"]()
        raise AttributeError("theta")

    @property
    def parametrization(self) -> str:
        """``"frozen"``, ``"consistent"`` or ``"unconstrained"`` (see ``trainable``)."""
        return self._parametrization

    @property
    def trainable(self) -> bool:
        """True when any variable of theta requires grad."""
        return any(p.requires_grad for p in self.parameters())

    def forward(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """Joint torques (N m) or forces (N).

        Args:
            q: ``(*batch, n_dof)`` joint positions.
            qd: ``(*batch, n_dof)`` joint velocities.
            qdd: ``(*batch, n_dof)`` joint accelerations.

        Returns:
            ``(*batch, n_dof)`` in the dtype of q (theta is cast to it) and theta's device.
        """
        Y = regressor(self.model, q, qd, qdd)
        return Y @ self.theta.to(dtype=Y.dtype, device=Y.device)

    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """The joint-space inertia ``M(q)``, ``(*batch, n_dof, n_dof)`` (armature on the
        diagonal); see `torchjfa.dynamics.mass_matrix`."""
        return mass_matrix(self.model, q, self.theta)

    def bias_forces(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """``h(q, qd)``: torques at zero acceleration (gravity, Coriolis, friction),
        ``(*batch, n_dof)``; see `torchjfa.dynamics.bias_forces`."""
        return bias_forces(self.model, q, qd, self.theta)

    def forward_dynamics(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor):
        """Joint accelerations ``M(q)^-1 (tau - h(q, qd))``, ``(*batch, n_dof)``, rad/s^2 or
        m/s^2; the inverse of `forward`. See `torchjfa.dynamics.forward_dynamics`."""
        return forward_dynamics(self.model, q, qd, tau, self.theta)

    def export(self, batch: int = 16, *, dtype=torch.float64, device=None):
        """``torch.export.export`` of `forward` whose batch dimension is dynamic: the program
        runs at any batch size (``program.module()(q, qd, qdd)``; save it with
        ``torch.export.save``). It traces the torch path of the regressor (the compiled C++
        kernel of eager CPU calls is not in the graph).

        Args:
            batch: the example's batch size (any size >= 2 gives the same program).
            dtype: the example's dtype, as the program's inputs will be.
            device: the example's device (default theta's).

        Returns:
            A ``torch.export.ExportedProgram`` taking ``(q, qd, qdd)`` of shape
            ``(batch, n_dof)``.
        """
        from torch.export import Dim

        if isinstance(batch, bool) or not isinstance(batch, int) or batch < 2:
            raise ValueError(
                f"batch must be an int >= 2 (1 would be traced as fixed), got {batch!r}"
            )
        device = self.theta.device if device is None else device
        example = tuple(
            torch.zeros(batch, self.model.n_dof, dtype=dtype, device=device) for _ in range(3)
        )
        dim = Dim("batch")
        return torch.export.export(self, example, dynamic_shapes=({0: dim}, {0: dim}, {0: dim}))

    def inertials(self):
        """Per-joint-body mass, centre of mass and inertia of the current theta."""
        return self.model.inertials(self.theta.detach())

    def extra_repr(self) -> str:
        return (
            f"n_dof={self.model.n_dof}, n_params={self.model.n_params}, "
            f"parametrization={self.parametrization!r}, trainable={self.trainable}"
        )
