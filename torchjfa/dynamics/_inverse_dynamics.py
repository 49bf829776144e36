"""`InverseDynamics`: an identified (or nominal) rigid-body model as an ``nn.Module``.

``tau = Y(q, qd, qdd) @ theta`` with theta a parameter, trainable or frozen. Use it for
computed-torque control, to compare identified models on held-out data, or as the physics part
of a model whose residual is learned (it composes with any other module and trains by
gradient descent when ``trainable=True``). The regressor itself lives in `RigidBodyModel`.
"""

from __future__ import annotations

import torch
from torch import nn

from .._validation import as_tensor, check_finite
from ._model import RigidBodyModel

__all__ = ["InverseDynamics"]


class InverseDynamics(nn.Module):
    """Joint torques of a rigid-body model with parameters theta.

    Args:
        model: the `RigidBodyModel` (kinematics, layout, friction terms).
        theta: ``(n_params,)`` parameters; default ``model.nominal_theta``. Stored in float64.
        trainable: if True theta is an ``nn.Parameter`` with ``requires_grad=True``; otherwise
            a frozen parameter (``requires_grad=False``). Either way it is in ``state_dict``.

    Example:
        >>> model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda"))  # doctest: +SKIP
        >>> idyn = InverseDynamics(model, theta_hat)                          # doctest: +SKIP
        >>> tau = idyn(q, qd, qdd)   # (*batch, n_dof)                        # doctest: +SKIP
    """

    def __init__(self, model: RigidBodyModel, theta=None, *, trainable: bool = False) -> None:
        super().__init__()
        if not isinstance(model, RigidBodyModel):
            raise TypeError(f"model must be a RigidBodyModel, got {type(model)}")
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
        self.theta = nn.Parameter(theta.detach().clone(), requires_grad=bool(trainable))

    @property
    def trainable(self) -> bool:
        return self.theta.requires_grad

    def forward(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """Joint torques (N m) or forces (N).

        Args:
            q, qd, qdd: ``(*batch, n_dof)`` joint positions, velocities, accelerations.

        Returns:
            ``(*batch, n_dof)`` in the dtype of q (theta is cast to it) and theta's device.
        """
        Y = self.model.regressor(q, qd, qdd)
        return Y @ self.theta.to(dtype=Y.dtype, device=Y.device)

    def inertials(self):
        """Per-joint-body mass, centre of mass and inertia of the current theta."""
        return self.model.inertials(self.theta.detach())

    def extra_repr(self) -> str:
        return (
            f"n_dof={self.model.n_dof}, n_params={self.model.n_params}, trainable={self.trainable}"
        )
