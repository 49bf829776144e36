"""Computed-torque control in MuJoCo with an identified model, the paper's evaluation.

`computed_torque` runs the law

    tau = ID(q, qd, qdd_ref + Kp (q_ref - q) + Kd (qd_ref - qd))

at the control rate (the torque held between control steps, the physics at ``substeps`` times
the rate), where ``ID`` is the identified inverse dynamics (e.g. `InverseDynamics`) and Kp, Kd
are acceleration gains (``w^2`` and ``2 zeta w``, ``w = 2 pi bandwidth_hz``). It reports, per
joint and averaged over joints, the RMS position and velocity tracking errors and the RMS
feedback command, defined as the torque the controller adds to the identified feedforward:

    tau_fb = tau - ID(q_ref, qd_ref, qdd_ref).

A run FAILS (``success=False`` with a reason) when the identified parameters are unusable (the
joint-space inertia matrix of ID, ``M(q)[:, i] = ID(q, 0, e_i) - ID(q, 0, 0)``, is not positive
definite at some reference posture), ID returns NaN or inf, or the run goes unstable: the state
is not finite, MuJoCo warns of bad accelerations, a joint leaves its range by more than
``limit_margin`` or a position error exceeds ``max_position_error``. The paper reports such
runs as FAILURE.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from .._util import progress_bar
from ..data._joints import permutation
from ..dynamics import InverseDynamics, RigidBodyModel
from ._generate import DEFAULT_RATE, DEFAULT_RATES
from ._robots import check_hinge_robot, joint_names, joint_ranges, load_robot
from ._trajectory import SinusoidTrajectory

__all__ = ["ControlResult", "computed_torque", "evaluate_control"]


@dataclass(frozen=True)
class ControlResult:
    """The outcome of a computed-torque run (arrays in MuJoCo joint order).

    Attributes:
        success: False when the run failed (then every RMS is NaN).
        reason: why it failed, or None.
        joint_names: ``(n_dof,)`` joint names.
        rms_position: ``(n_dof,)`` RMS of ``q - q_ref``, rad.
        rms_velocity: ``(n_dof,)`` RMS of ``qd - qd_ref``, rad/s.
        rms_feedback: ``(n_dof,)`` RMS of ``tau - ID(q_ref, qd_ref, qdd_ref)``, N m.
        max_position_error: largest ``|q - q_ref|`` over the run, rad.
        n_steps: control steps run.
    """

    success: bool
    reason: str | None
    joint_names: tuple[str, ...]
    rms_position: np.ndarray
    rms_velocity: np.ndarray
    rms_feedback: np.ndarray
    max_position_error: float
    n_steps: int

    @property
    def mean_rms_position(self) -> float:
        """RMS position error averaged over joints, rad."""
        return float(np.mean(self.rms_position))

    @property
    def mean_rms_velocity(self) -> float:
        """RMS velocity error averaged over joints, rad/s."""
        return float(np.mean(self.rms_velocity))

    @property
    def mean_rms_feedback(self) -> float:
        """RMS feedback command averaged over joints, N m."""
        return float(np.mean(self.rms_feedback))


def _id_joint_names(inverse_dynamics, given) -> tuple[str, ...] | None:
    if given is not None:
        return tuple(given)
    for obj in (inverse_dynamics, getattr(inverse_dynamics, "model", None)):
        names = getattr(obj, "joint_names", None)
        if names is not None:
            return tuple(names)
    return None


def _inertia_ok(call, q: torch.Tensor) -> tuple[bool, str | None]:
    """Check ``M(q)`` of ``call`` is symmetric positive definite at postures ``q (S, n)``."""
    S, n = q.shape
    eye = torch.eye(n, dtype=q.dtype)
    qq = q[:, None, :].expand(S, n + 1, n)
    qdd = torch.cat([eye, torch.zeros(1, n, dtype=q.dtype)])[None].expand(S, n + 1, n)
    tau = call(qq, torch.zeros_like(qq), qdd)  # (S, n + 1, n)
    if not bool(torch.isfinite(tau).all()):
        return False, "the identified inverse dynamics returned NaN or inf"
    M = (tau[:, :n, :] - tau[:, n:, :]).transpose(-1, -2)  # column i = ID(q, 0, e_i) - ID(q, 0, 0)
    M = 0.5 * (M + M.transpose(-1, -2))
    eig = torch.linalg.eigvalsh(M)
    low = eig[:, 0]
    worst = int(torch.argmin(low))
    if float(low[worst]) <= 1e-12 * max(float(eig[:, -1].abs().max()), 1e-300):
        return False, (
            "the identified inertia matrix is not positive definite (smallest eigenvalue "
            f"{float(low[worst]):.3g} at q = {q[worst].tolist()})"
        )
    return True, None


def computed_torque(
    model: mujoco.MjModel,
    inverse_dynamics: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor],
    trajectory: SinusoidTrajectory,
    *,
    duration: float | None = None,
    control_rate: float = 420.0,
    substeps: int = 4,
    bandwidth_hz: float = 5.0,
    damping_ratio: float = 1.0,
    joint_names_id: Sequence[str] | None = None,
    max_position_error: float = 0.5,
    limit_margin: float = 0.3,
    check_inertia: bool = True,
    inertia_samples: int = 32,
    progress: bool = False,
) -> ControlResult:
    """Run a computed-torque controller with an identified model on a reference in MuJoCo.

    Args:
        model: the simulated robot (e.g. ``load_robot("head")``); it is not modified.
        inverse_dynamics: ``ID(q, qd, qdd) -> tau``, torch float64 ``(*batch, n_dof)`` in and
            out, e.g. an `InverseDynamics` module (called under ``torch.no_grad``).
        trajectory: the reference (a `SinusoidTrajectory` with the robot's joints); the robot
            starts on it at t = 0.
        duration: seconds to run; default one period of the trajectory.
        control_rate: Hz.
        substeps: physics steps per control step.
        bandwidth_hz: the bandwidth of the error dynamics ``e'' + Kd e' + Kp e = 0``.
        damping_ratio: their damping ratio.
        joint_names_id: ID's joint order; default ``inverse_dynamics.joint_names`` or
            ``inverse_dynamics.model.joint_names``, else MuJoCo's order.
        max_position_error: rad; larger errors mean the run failed.
        limit_margin: rad; leaving a joint range by more than this means the run failed.
        check_inertia: check ID's inertia matrix at ``inertia_samples`` reference postures.
        inertia_samples: postures for the check.
        progress: show a progress bar.

    Returns:
        A `ControlResult`.

    Raises:
        ValueError: on mismatched joints, a bad duration, rate or gains.
    """
    check_hinge_robot(model)
    names = joint_names(model)
    n = len(names)
    if trajectory.n_dof != n:
        raise ValueError(f"trajectory has {trajectory.n_dof} joints, the robot has {n}")
    id_names = _id_joint_names(inverse_dynamics, joint_names_id)
    if id_names is None:
        id_names = names
    to_id = np.array(  # id_vec = mj_vec[to_id]
        permutation(names, id_names, have_name="the MuJoCo robot", want_name="the model")
    )
    if not control_rate > 0 or not bandwidth_hz > 0 or not damping_ratio > 0:
        raise ValueError("control_rate, bandwidth_hz and damping_ratio must be positive")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps must be a positive int, got {substeps!r}")
    duration = trajectory.period if duration is None else float(duration)
    h = 1.0 / control_rate
    n_steps = int(round(duration * control_rate))
    if n_steps < 1:
        raise ValueError(f"duration must cover at least one control step, got {duration}")
    w = 2.0 * np.pi * bandwidth_hz

    def call(q, qd, qdd):
        with torch.no_grad():
            return inverse_dynamics(q, qd, qdd)

    run = _Run(
        names=names,
        to_id=to_id,
        call=call,
        reference=trajectory.evaluate_numpy(np.arange(n_steps) * h),
        h=h,
        kp=w * w,
        kd=2.0 * damping_ratio * w,
        max_position_error=max_position_error,
        limit_margin=limit_margin,
    )
    if check_inertia:
        idx = np.linspace(0, n_steps - 1, min(inertia_samples, n_steps)).round().astype(int)
        ok, reason = _inertia_ok(call, run.to_torch(run.reference[0][idx]))
        if not ok:
            return run.fail(reason, 0)
    tau_ref = run.feedforward()
    if not np.isfinite(tau_ref).all():
        return run.fail("the identified inverse dynamics returned NaN or inf on the reference", 0)
    old_dt = model.opt.timestep
    model.opt.timestep = h / substeps
    try:
        return _track(model, run, tau_ref, substeps, progress)
    finally:
        model.opt.timestep = old_dt


@dataclass(frozen=True)
class _Run:
    """What one computed-torque run needs at every step (arrays in MuJoCo joint order).

    Attributes:
        names: ``(n,)`` MuJoCo's joints; to_id: ``(n,)`` ID's order, ``id_vec = mj_vec[to_id]``.
        call: ID without grad.
        reference: ``(q_ref, qd_ref, qdd_ref)``, ``(n_steps, n)`` each.
        h: control step, s; kp, kd: acceleration gains, 1/s^2 and 1/s.
        max_position_error, limit_margin: rad, the failure thresholds.
    """

    names: tuple[str, ...]
    to_id: np.ndarray
    call: Callable
    reference: tuple[np.ndarray, np.ndarray, np.ndarray]
    h: float
    kp: float
    kd: float
    max_position_error: float
    limit_margin: float

    def to_torch(self, a: np.ndarray) -> torch.Tensor:
        """``(..., n)`` in MuJoCo's order -> float64 tensor in ID's order."""
        return torch.as_tensor(np.ascontiguousarray(a[..., self.to_id]), dtype=torch.float64)

    def fail(self, reason: str, steps: int, max_err: float = float("nan")) -> ControlResult:
        nan = np.full(len(self.names), np.nan)
        return ControlResult(False, reason, self.names, nan, nan, nan, max_err, steps)

    def feedforward(self) -> np.ndarray:
        """``(n_steps, n)`` ``ID(q_ref, qd_ref, qdd_ref)`` in MuJoCo's order."""
        q_ref, qd_ref, qdd_ref = self.reference
        tau_ref = np.empty_like(q_ref)
        tau_ref[:, self.to_id] = self.call(
            self.to_torch(q_ref), self.to_torch(qd_ref), self.to_torch(qdd_ref)
        ).numpy()
        return tau_ref

    def state_problem(self, q, err_q: np.ndarray, lo, hi, t: float) -> tuple[str, float] | None:
        """Why the run fails at this step (position error, joint range), with the worst error."""
        worst = float(np.abs(err_q).max())
        if worst > self.max_position_error:
            return (
                f"position error {worst:.3g} rad exceeds {self.max_position_error} rad at "
                f"t = {t:.4g} s"
            ), worst
        if np.any(q < lo) or np.any(q > hi):
            j = int(np.argmax(np.maximum(lo - q, q - hi)))
            return (
                f"joint {self.names[j]!r} left its range by more than {self.limit_margin} rad at "
                f"t = {t:.4g} s"
            ), worst
        return None


def _track(m: mujoco.MjModel, run: _Run, tau_ref: np.ndarray, substeps: int, progress: bool):
    """The control loop (``m.opt.timestep`` already the physics step); a `ControlResult`."""
    q_ref, qd_ref, qdd_ref = run.reference
    n_steps, n = q_ref.shape
    h, kp, kd, to_id = run.h, run.kp, run.kd, run.to_id
    data = mujoco.MjData(m)
    data.qpos[:] = q_ref[0]
    data.qvel[:] = qd_ref[0]
    mujoco.mj_forward(m, data)
    ranges = joint_ranges(m)
    lo, hi = ranges[:, 0] - run.limit_margin, ranges[:, 1] + run.limit_margin
    err_q = np.empty((n_steps, n))
    err_qd = np.empty((n_steps, n))
    fb = np.empty((n_steps, n))
    q_in = torch.empty(1, n, dtype=torch.float64)
    qd_in = torch.empty(1, n, dtype=torch.float64)
    a_in = torch.empty(1, n, dtype=torch.float64)
    qn, qdn, an = q_in.numpy()[0], qd_in.numpy()[0], a_in.numpy()[0]
    badqacc = int(mujoco.mjtWarning.mjWARN_BADQACC)
    with progress_bar(total=n_steps, desc="computed torque", enabled=progress) as bar:
        for k in range(n_steps):
            q, qd = data.qpos, data.qvel
            if not (np.isfinite(q).all() and np.isfinite(qd).all()):
                return run.fail(f"the state became NaN or inf at t = {k * h:.4g} s", k)
            np.subtract(q, q_ref[k], out=err_q[k])
            np.subtract(qd, qd_ref[k], out=err_qd[k])
            problem = run.state_problem(q, err_q[k], lo, hi, k * h)
            if problem is not None:
                return run.fail(problem[0], k, problem[1])
            qn[:] = q[to_id]
            qdn[:] = qd[to_id]
            an[:] = (qdd_ref[k] - kp * err_q[k] - kd * err_qd[k])[to_id]
            tau = run.call(q_in, qd_in, a_in)[0].numpy()
            if not np.isfinite(tau).all():
                return run.fail(f"the identified model returned NaN at t = {k * h:.4g} s", k)
            data.ctrl[to_id] = tau
            fb[k] = data.ctrl - tau_ref[k]
            mujoco.mj_step(m, data, substeps)
            if data.warning[badqacc].number > 0:
                return run.fail(f"MuJoCo reported bad accelerations at t = {k * h:.4g} s", k)
            bar.update(1)
    rms = lambda e: np.sqrt(np.mean(e * e, axis=0))
    return ControlResult(
        True,
        None,
        run.names,
        rms(err_q),
        rms(err_qd),
        rms(fb),
        float(np.abs(err_q).max()),
        n_steps,
    )


def evaluate_control(
    robot: str | mujoco.MjModel,
    model: RigidBodyModel,
    thetas: Mapping[str, torch.Tensor],
    trajectory,
    *,
    duration: float,
    unmodeled: bool | Mapping = True,
    bandwidth_hz: float = 5.0,
    progress: bool = False,
    control_rate: float | None = None,
) -> dict[str, ControlResult]:
    """Computed-torque control of the simulated robot with each parameter vector.

    Args:
        robot: ``"head"`` or ``"arm"``, or a compiled ``mujoco.MjModel`` of a robot with one
            gear-1 torque motor per hinge or slide joint (e.g. `load_description`'s
            ``model``, simulated with the joint effects it has; not modified).
        model: the rigid-body model the parameters belong to.
        thetas: name -> ``(n_params,)`` parameters.
        trajectory: the held-out reference (a `SinusoidTrajectory`).
        duration: seconds of control per run.
        unmodeled: a shipped robot's joint effects (as `load_robot`).
        bandwidth_hz: bandwidth of the error dynamics.
        progress: show a progress bar over the runs.
        control_rate: Hz; default the robot's own (`DEFAULT_RATES`, `DEFAULT_RATE` for an
            ``MjModel``).

    Returns:
        name -> `ControlResult` (``success=False`` is the paper's FAILURE).
    """
    if isinstance(robot, mujoco.MjModel):
        if unmodeled is not True:
            raise ValueError("unmodeled applies to a shipped robot's name, not an MjModel")
        mj, name, rate = robot, "robot", DEFAULT_RATE
    else:
        mj, name, rate = load_robot(robot, unmodeled=unmodeled), robot, DEFAULT_RATES[robot]
    rate = rate if control_rate is None else float(control_rate)
    out = {}
    with progress_bar(total=len(thetas), desc=f"control {name}", enabled=progress) as bar:
        for name, theta in thetas.items():
            out[name] = computed_torque(
                mj,
                InverseDynamics(model, theta),
                trajectory,
                duration=duration,
                control_rate=rate,
                bandwidth_hz=bandwidth_hz,
            )
            bar.update(1)
    return out
