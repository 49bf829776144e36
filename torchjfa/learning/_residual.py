"""`ResidualDynamics`: identified rigid-body dynamics plus a learned residual, as an ``nn.Module``.

``tau = Y(q, qd, qdd) theta + r(features(q, qd, qdd))``: the physics part is an
`torchjfa.dynamics.InverseDynamics` (frozen, or fine-tuned through `VirtualParameters` so that
theta stays physically consistent while it trains), the residual ``r`` any ``nn.Module`` on the
concatenated state or on features the user gives: an `MLP` of the whole state by default, or a
`JointResidual`, where each joint's residual torque depends on that joint's own state only (the
shape of what rigid-body models leave out: armature, friction, springs and cables of a joint). Use it in plain
torch; `torchjfa.learning.ResidualDynamicsModule` trains it with Lightning. Without a physics
part (``inverse_dynamics=None``) it is a plain learned model, the baseline the residual model is
compared with. The residual networks themselves live in `torchjfa.learning._networks`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import nn

from ..dynamics import InverseDynamics
from ..dynamics._forward import regressor as traceable_regressor
from ..physical import VirtualParameters
from ._networks import MLP, JointResidual

__all__ = ["MLP", "JointResidual", "ResidualDynamics", "state_features"]

_RESIDUAL_KINDS = ("mlp", "joint")


def state_features(q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
    """The default residual input: ``(*batch, 3 n_dof)`` = ``[q, qd, qdd]`` concatenated."""
    return torch.cat([q, qd, qdd], -1)


class ResidualDynamics(nn.Module):
    """Joint torques as identified rigid-body dynamics plus a learned residual.

    Args:
        inverse_dynamics: the identified model; None for a purely learned model (then
            ``n_dof`` is required).
        residual: any module mapping ``(*batch, n_features)`` to ``(*batch, n_dof)``; default
            the network ``residual_kind`` names.
        residual_kind: the default residual: ``"mlp"``, ``MLP(n_features, n_dof,
            hidden=hidden, seed=seed)`` (a network of the whole state), or ``"joint"``,
            ``JointResidual(n_dof, n_features // n_dof, hidden=hidden, seed=seed)`` (each
            joint's residual from its own features: with the default features its own q, qd,
            qdd and a smooth Coulomb friction term).
        fine_tune: if True, theta is trained through `VirtualParameters` initialised at the
            identified theta (so it stays physically consistent: positive masses, PSD inertias,
            non-negative viscous friction); an inconsistent identified theta is first moved to a
            nearby consistent one. If False the identified theta is frozen.
        features: a callable (a function or an ``nn.Module``, saved with the model when it is
            one) mapping ``(q, qd, qdd)`` to ``(*batch, n_features)``; default `state_features`.
        n_features: width of ``features``' output; default ``3 n_dof`` (the default features).
        n_dof: joints, when there is no ``inverse_dynamics``.
        hidden: of the default `MLP`.
        seed: of the default `MLP`.

    Attributes:
        inverse_dynamics: the `InverseDynamics` (its theta frozen), or None.
        virtual: the `VirtualParameters` being fine-tuned, or None.
        residual: the residual module.

    Example:
        >>> idyn = torchjfa.io.load_identified("head.npz")          # doctest: +SKIP
        >>> model = ResidualDynamics(idyn)                            # doctest: +SKIP
        >>> tau = model(q, qd, qdd)   # (*batch, n_dof)               # doctest: +SKIP
    """

    def __init__(
        self,
        inverse_dynamics: InverseDynamics | None,
        residual: nn.Module | None = None,
        *,
        fine_tune: bool = False,
        features: Callable[..., torch.Tensor] | None = None,
        n_features: int | None = None,
        n_dof: int | None = None,
        hidden: Sequence[int] = (64, 64),
        seed: int | None = 0,
        residual_kind: str = "mlp",
    ) -> None:
        super().__init__()
        if residual_kind not in _RESIDUAL_KINDS:
            raise ValueError(
                f"residual_kind must be one of {_RESIDUAL_KINDS}, got {residual_kind!r}"
            )
        if inverse_dynamics is not None and not isinstance(inverse_dynamics, InverseDynamics):
            raise TypeError(
                f"inverse_dynamics must be an InverseDynamics or None, got {type(inverse_dynamics)}"
            )
        if inverse_dynamics is None:
            if n_dof is None:
                raise ValueError("n_dof is required when there is no inverse_dynamics")
            if fine_tune:
                raise ValueError("fine_tune=True needs an inverse_dynamics to fine-tune")
        else:
            if n_dof is not None and n_dof != inverse_dynamics.model.n_dof:
                raise ValueError(
                    f"n_dof={n_dof} but the inverse dynamics has {inverse_dynamics.model.n_dof}"
                )
            n_dof = inverse_dynamics.model.n_dof
            inverse_dynamics.requires_grad_(False)  # theta, or its parametrisation
        if features is not None and not callable(features):
            raise TypeError(f"features must be callable, got {type(features)}")
        self.n_dof = int(n_dof)
        self.inverse_dynamics = inverse_dynamics
        self.virtual = (
            VirtualParameters.from_theta(inverse_dynamics.theta.detach(), inverse_dynamics.model)
            if fine_tune
            else None
        )
        self.features = state_features if features is None else features
        self.n_features = 3 * self.n_dof if n_features is None else int(n_features)
        if features is not None and n_features is None and residual is None:
            raise ValueError("give n_features with custom features and the default residual")
        if residual is None and residual_kind == "joint":
            if self.n_features % self.n_dof:
                raise ValueError(
                    f"a joint residual needs n_features to be a multiple of n_dof={self.n_dof}, "
                    f"got {self.n_features}"
                )
            k = self.n_features // self.n_dof
            residual = JointResidual(self.n_dof, k, hidden=hidden, seed=seed)
        elif residual is None:
            residual = MLP(self.n_features, self.n_dof, hidden=hidden, seed=seed)
        if not isinstance(residual, nn.Module):
            raise TypeError(f"residual must be an nn.Module, got {type(residual)}")
        self.residual = residual

    @property
    def fine_tune(self) -> bool:
        return self.virtual is not None

    @property
    def has_physics(self) -> bool:
        return self.inverse_dynamics is not None

    def theta(self) -> torch.Tensor | None:
        """The current rigid-body parameters ``(n_params,)`` (None without physics)."""
        if self.inverse_dynamics is None:
            return None
        if self.virtual is not None:
            return self.virtual()
        return self.inverse_dynamics.theta

    def rigid_body_torque(
        self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor, *, regressor=None
    ) -> torch.Tensor:
        """``Y(q, qd, qdd) theta``, ``(*batch, n_dof)`` (zeros without physics).

        Args:
            q: ``(*batch, n_dof)`` positions.
            qd: ``(*batch, n_dof)`` velocities.
            qdd: ``(*batch, n_dof)`` accelerations.
            regressor: optionally the precomputed ``Y`` ``(*batch, n_dof, n_params)`` of these
                samples (`RigidBodyModel.regressor` is the expensive part; a data module can
                compute it once per sample).
        """
        if self.inverse_dynamics is None:
            return torch.zeros_like(q)
        if regressor is None:
            regressor = traceable_regressor(self.inverse_dynamics.model, q, qd, qdd)
        theta = self.theta()
        return regressor @ theta.to(dtype=regressor.dtype, device=regressor.device)

    def residual_torque(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """The learned part ``r(features(q, qd, qdd))``, ``(*batch, n_dof)``."""
        x = self.features(q, qd, qdd)
        out = self.residual(x)
        if out.shape != q.shape:
            raise ValueError(
                f"the residual returned shape {tuple(out.shape)}, expected {tuple(q.shape)}"
            )
        return out

    def forward(
        self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor, *, regressor=None
    ) -> torch.Tensor:
        """Joint torques (N m or N).

        Args:
            q: ``(*batch, n_dof)`` joint positions.
            qd: ``(*batch, n_dof)`` joint velocities.
            qdd: ``(*batch, n_dof)`` joint accelerations.
            regressor: optional precomputed ``(*batch, n_dof, n_params)`` (see
                `rigid_body_torque`).

        Returns:
            ``(*batch, n_dof)`` in q's dtype.
        """
        for name, v in (("q", q), ("qd", qd), ("qdd", qdd)):
            if not isinstance(v, torch.Tensor):
                raise TypeError(f"{name} must be a torch.Tensor, got {type(v)}")
            if v.ndim == 0 or v.shape[-1] != self.n_dof or v.shape != q.shape:
                raise ValueError(
                    f"q, qd and qdd must all have shape (*batch, {self.n_dof}); "
                    f"{name} has {tuple(v.shape)}"
                )
        tau = self.residual_torque(q, qd, qdd).to(q.dtype)
        if self.inverse_dynamics is not None:
            tau = tau + self.rigid_body_torque(q, qd, qdd, regressor=regressor).to(q.dtype)
        return tau

    def extra_repr(self) -> str:
        return f"n_dof={self.n_dof}, physics={self.has_physics}, fine_tune={self.fine_tune}"
