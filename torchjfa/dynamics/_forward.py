"""Forward dynamics of a rigid-body model from its parameters theta, and rollouts.

Everything is built from the regressor, so it holds for any theta, identified or nominal, and is
differentiable with respect to theta and the states (batched, in the inputs' dtype and device):

- the bias forces ``h(q, qd) = Y(q, qd, 0) theta``: gravity, Coriolis and centrifugal torques
  and the joint terms that do not depend on the acceleration (viscous and Coulomb friction,
  offsets);
- the joint-space inertia (mass matrix) ``M(q)``, column by column
  ``M e_i = Y(q, 0, e_i) theta - Y(q, 0, 0) theta`` (velocity-dependent terms vanish at
  ``qd = 0``, gravity and offsets cancel, the armature ``ia`` lands on the diagonal);
- forward dynamics ``qdd = M(q)^-1 (tau - h(q, qd))``, which inverts
  ``tau = Y(q, qd, qdd) theta`` exactly (the torques are affine in ``qdd``);
- `rollout`: a torque sequence integrated from an initial state, semi-implicit Euler (MuJoCo's
  ``Euler`` without damping) or classical fourth-order Runge-Kutta (MuJoCo's ``RK4``).

`InverseDynamics` has the same as methods (`InverseDynamics.mass_matrix`,
`InverseDynamics.forward_dynamics`) with its own theta.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from .._validation import as_tensor
from ._inputs import check_state
from ._rnea import TreeConstants, regressor_into

__all__ = ["regressor", "bias_forces", "mass_matrix", "forward_dynamics", "rollout", "METHODS"]

METHODS = ("semi-implicit", "rk4")
# The mass matrix's columns are Y(q, 0, s e_i) theta minus Y(q, 0, 0) theta, divided by s: a
# power of two (exact division) large enough that the gravity torques, which cancel in the
# difference, are small next to s M and add rounding of eps |M| rather than eps |g torque|.
_UNIT_ACCELERATION = 1024.0


def regressor(model, q, qd, qdd) -> torch.Tensor:
    """``model.regressor(q, qd, qdd)``, ``(*batch, n_dof, n_params)``, traceable.

    In eager mode this is `RigidBodyModel.regressor` (the compiled kernel where it applies).
    While `torch.compile` or `torch.export` traces, it is the plain torch path with no
    data-dependent branches: no compiled kernel (opaque to the tracer), no chunking and no
    numpy-allocated output.
    """
    if not torch.compiler.is_compiling():
        return model.regressor(q, qd, qdd)
    q, qd, qdd = check_state(q, qd, qdd, joint_names=model.joint_names)
    n = model.n_dof
    q2, qd2, qdd2 = (v.reshape(-1, n) for v in (q, qd, qdd))
    # the model caches its constants per dtype and device; built while tracing they would be
    # the tracer's placeholders, which must not outlive the trace: build them uncached then
    consts = model._constants.get((q2.dtype, q2.device))
    if consts is None:
        consts = TreeConstants.from_tree(model._tree, q2.dtype, q2.device)
    Y = q2.new_zeros(q2.shape[0], n, model.n_params)
    regressor_into(Y, q2, qd2, qdd2, consts, model.friction)
    model._joint_terms(Y, qd2, qdd2)
    return Y.reshape(*q.shape[:-1], n, model.n_params)


def _theta_like(model, theta, like: torch.Tensor) -> torch.Tensor:
    theta = as_tensor(theta, name="theta")
    if theta.shape != (model.n_params,):
        raise ValueError(
            f"theta must have shape ({model.n_params},) for this model, got {tuple(theta.shape)}"
        )
    return theta.to(dtype=like.dtype, device=like.device)


def _inertia_and_bias(model, q, qd, theta) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``M (B, n, n)`` and (when ``qd`` is given) ``h (B, n)`` of flat ``q, qd (B, n)``, from
    one regressor call on ``n + 1`` (``n + 2``) stacked states per sample."""
    B, n = q.shape
    rows = [q.new_zeros(B, 1, n), torch.eye(n, dtype=q.dtype, device=q.device).expand(B, n, n)]
    qdd = torch.cat([rows[0], _UNIT_ACCELERATION * rows[1]], 1)  # (B, n + 1, n)
    qds = q.new_zeros(B, n + 1, n)
    if qd is not None:
        qdd = torch.cat([rows[0], qdd], 1)
        qds = torch.cat([qd[:, None], q.new_zeros(B, n + 1, n)], 1)
    qs = q[:, None].expand(B, qdd.shape[1], n)
    Y = regressor(model, qs, qds, qdd)
    f = Y @ _theta_like(model, theta, Y)  # (B, k, n): torques of each stacked state
    f0 = f[:, -(n + 1)]  # Y(q, 0, 0) theta
    M = (f[:, -n:] - f0[:, None]).transpose(-1, -2) / _UNIT_ACCELERATION
    M = 0.5 * (M + M.transpose(-1, -2))  # symmetric up to rounding; make it exactly so
    return M, (f[:, 0] if qd is not None else None)


def mass_matrix(model, q, theta) -> torch.Tensor:
    """The joint-space inertia ``M(q)`` of a model with parameters theta.

    ``tau = M(q) qdd + h(q, qd)`` with ``h`` the `bias_forces`; the armature terms ``ia`` (if
    the layout has them) are on the diagonal. ``M`` is symmetric, and positive definite for a
    physically consistent theta (`torchjfa.physical.check`).

    Args:
        model: the `RigidBodyModel`.
        q: ``(*batch, n_dof)`` joint positions, rad (revolute) or m (prismatic).
        theta: ``(n_params,)`` parameters in ``model.layout``; cast to q's dtype and device.

    Returns:
        ``(*batch, n_dof, n_dof)`` in q's dtype, kg m^2 (kg for prismatic rows and columns,
        kg m for mixed ones); differentiable with respect to q and theta.

    Raises:
        ValueError: on a wrong shape, NaN or inf in q, or a theta of the wrong shape.
    """
    (q,) = check_state(q, joint_names=model.joint_names, names=("q",))
    batch = q.shape[:-1]
    M, _ = _inertia_and_bias(model, q.reshape(-1, model.n_dof), None, theta)
    return M.reshape(*batch, model.n_dof, model.n_dof)


def bias_forces(model, q, qd, theta) -> torch.Tensor:
    """``h(q, qd) = Y(q, qd, 0) theta``: the torques at zero acceleration, ``(*batch, n_dof)``.

    Gravity, Coriolis and centrifugal torques plus the joint terms that do not depend on the
    acceleration (viscous and Coulomb friction, offsets), N m (N for prismatic joints).

    Args:
        model: the `RigidBodyModel`.
        q: ``(*batch, n_dof)`` joint positions.
        qd: ``(*batch, n_dof)`` joint velocities.
        theta: ``(n_params,)``; cast to q's dtype and device.
    """
    q, qd = check_state(q, qd, joint_names=model.joint_names, names=("q", "qd"))
    Y = regressor(model, q, qd, torch.zeros_like(q))
    return Y @ _theta_like(model, theta, Y)


def forward_dynamics(model, q, qd, tau, theta) -> torch.Tensor:
    """Joint accelerations ``qdd = M(q)^-1 (tau - h(q, qd))`` of a model with parameters theta.

    The inverse of ``tau = Y(q, qd, qdd) theta``: feeding the result back into
    `RigidBodyModel.inverse_dynamics` gives ``tau`` again (to rounding, amplified by the
    condition number of ``M``). ``M`` is factorised by LU (``torch.linalg.solve``), so an
    inconsistent theta works as long as ``M`` is invertible.

    Args:
        model: the `RigidBodyModel`.
        q: ``(*batch, n_dof)`` joint positions (rad or m).
        qd: ``(*batch, n_dof)`` joint velocities (rad/s or m/s).
        tau: ``(*batch, n_dof)`` joint torques (N m) or forces (N).
        theta: ``(n_params,)``; cast to the inputs' dtype and device.

    Returns:
        ``(*batch, n_dof)`` accelerations, rad/s^2 or m/s^2, in the inputs' promoted dtype;
        differentiable with respect to q, qd, tau and theta.

    Raises:
        ValueError: on wrong or mismatched shapes, NaN or inf inputs, a theta of the wrong
            shape.
        torch.linalg.LinAlgError: if ``M(q)`` is singular.
    """
    q, qd, tau = check_state(q, qd, tau, joint_names=model.joint_names, names=("q", "qd", "tau"))
    n = model.n_dof
    M, h = _inertia_and_bias(model, q.reshape(-1, n), qd.reshape(-1, n), theta)
    qdd = torch.linalg.solve(M, tau.reshape(-1, n) - h)
    return qdd.reshape(q.shape)


def _accelerations(dynamics) -> Callable[..., torch.Tensor]:
    step = getattr(dynamics, "forward_dynamics", None)
    if callable(step):
        return step
    if callable(dynamics):
        return dynamics
    raise TypeError(
        "dynamics must have a forward_dynamics(q, qd, tau) method (e.g. an InverseDynamics) or "
        f"be a callable (q, qd, tau) -> qdd, got {type(dynamics).__name__}"
    )


def rollout(
    dynamics, q0, qd0, tau, dt: float, *, method: str = "semi-implicit"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Integrate the forward dynamics over a sequence of torques held over each step.

    ``semi-implicit`` (symplectic Euler, first order; MuJoCo's ``Euler`` integrator without
    joint damping, which MuJoCo treats implicitly)::

        qd[k+1] = qd[k] + dt qdd(q[k], qd[k], tau[k]);  q[k+1] = q[k] + dt qd[k+1]

    ``rk4`` (classical fourth-order Runge-Kutta on ``(q, qd)``, ``tau[k]`` held over the step;
    MuJoCo's ``RK4`` integrator). The whole rollout is differentiable (backpropagation through
    time) with respect to the initial state, the torques and the dynamics' parameters.

    Args:
        dynamics: an object with ``forward_dynamics(q, qd, tau) -> qdd`` (an `InverseDynamics`)
            or a callable ``(q, qd, tau) -> qdd``.
        q0: ``(*batch, n_dof)`` initial joint positions.
        qd0: ``(*batch, n_dof)`` initial joint velocities.
        tau: ``(T, *batch, n_dof)`` torques, N m or N; ``tau[k]`` acts from step k to k + 1.
        dt: the step, s (> 0).
        method: ``"semi-implicit"`` or ``"rk4"``.

    Returns:
        ``(q, qd)``, each ``(T + 1, *batch, n_dof)``; index 0 is the initial state, index k the
        state at time ``k dt``.

    Raises:
        ValueError: on an unknown method, a step that is not a positive finite number, or
            shapes that do not match.
        TypeError: if ``dynamics`` gives no accelerations.
    """
    accel = _accelerations(dynamics)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if (
        isinstance(dt, bool)
        or not isinstance(dt, (int, float))
        or not (math.isfinite(dt) and dt > 0)
    ):
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    q, qd = (as_tensor(v, name=n) for v, n in ((q0, "q0"), (qd0, "qd0")))
    tau = as_tensor(tau, name="tau")
    if qd.shape != q.shape or tau.ndim != q.ndim + 1 or tau.shape[1:] != q.shape:
        raise ValueError(
            "q0 and qd0 must have one shape (*batch, n_dof) and tau (T, *batch, n_dof); got "
            f"q0 {tuple(q.shape)}, qd0 {tuple(qd.shape)}, tau {tuple(tau.shape)}"
        )
    qs, qds = [q], [qd]
    for u in tau.unbind(0):
        if method == "semi-implicit":
            qd = qd + dt * accel(q, qd, u)
            q = q + dt * qd
        else:
            q, qd = _rk4_step(accel, q, qd, u, dt)
        qs.append(q)
        qds.append(qd)
    return torch.stack(qs), torch.stack(qds)


def _rk4_step(accel, q, qd, u, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    a1 = accel(q, qd, u)
    v2 = qd + 0.5 * dt * a1
    a2 = accel(q + 0.5 * dt * qd, v2, u)
    v3 = qd + 0.5 * dt * a2
    a3 = accel(q + 0.5 * dt * v2, v3, u)
    v4 = qd + dt * a3
    a4 = accel(q + dt * v3, v4, u)
    q_next = q + (dt / 6.0) * (qd + 2.0 * v2 + 2.0 * v3 + v4)
    qd_next = qd + (dt / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q_next, qd_next
