"""Simulated identification data: a robot tracking a periodic excitation in MuJoCo.

`generate_log` rebuilds the paper's robot experiments in simulation: the robot follows a
sum-of-sinusoids reference (`random_trajectory`) under a computed-torque controller (PD on the
acceleration plus inverse dynamics) at the control rate (420 Hz for the head, 480 Hz for the
arm, as in the paper), with the physics at an integer multiple of it; q, qd and the applied
torques are recorded with Gaussian sensor noise at the control rate, and the acceleration
(optionally the velocity too) comes from numerical differentiation of the noisy signals
(`torchjfa.data.differentiate`), as on a real robot.

The controller is computed torque with the simulator's own model (every effect the simulated
robot has): ``tau = ID_mj(q, qd, qdd_ref + Kp (q_ref - q) + Kd (qd_ref - qd))`` by
`mujoco.mj_inverse` at the control rate, held between control steps, with acceleration gains
``Kp = w^2``, ``Kd = 2 zeta w``, ``w = 2 pi bandwidth_hz``. (A decentralised PD with
feedforward is not enough for the arm: its strongly coupled, light distal joints go unstable
at any useful gain at these rates.) By default the controller sees the true state, so the
motion is exactly periodic once settled and the spread between periods is the sensor noise
alone; with ``noisy_feedback=True`` the tracking errors use the measured state.

The torque is held between control steps, so the acceleration jumps at every sample. The
differentiated qdd estimates the acceleration averaged over the neighbouring torque-hold
intervals, and the logged torque ``tau`` is what a torque sensor sampled with the state reads:
the mean of the applied torque over the sampling interval centred on the sample, half the sum
of the previous and the current command. Both sides of ``tau = Y theta`` are then the same
average (to second order in the sampling interval). Logging the command instead (the torque
of the next interval, half a sample ahead of the motion it is compared with) left a
systematic residual of 0.05-0.14 N m on the arm's first four joints without noise, several
times the torque noise, which biased every estimate. The physics is integrated by RK4 (the
models' ``integrator``): with the semi-implicit Euler of ``implicitfast`` the positions trail
the velocities by half a physics step, a further 0.01-0.025 N m. The simulator's
instantaneous ``qacc`` at a sample (``qdd_true``) is exactly consistent with ``tau_true`` (the
command) and the state, and differs from the differentiated qdd by the sample-and-hold
ripple, about 1-3 % of the RMS acceleration for these robots even without noise. Use
``qdd_true`` with ``tau_true`` for exact checks.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from .._util import progress_bar
from ..data import DEFAULT_CUTOFF_HZ, differentiate
from ._log import SensorNoise, SimulatedLog
from ._robots import _fields, check_hinge_robot, joint_names, load_robot
from ._trajectory import SinusoidTrajectory, random_trajectory

__all__ = ["generate_log", "DEFAULT_N_SAMPLES", "DEFAULT_RATES", "DEFAULT_RATE"]

#: samples of a simulated log at the control rate (`generate_log`, ``torchjfa simulate``)
DEFAULT_N_SAMPLES = 50_000
DEFAULT_RATES = {"head": 420.0, "arm": 480.0}
#: the control and sampling rate of any other robot (a description compiled for simulation), Hz
DEFAULT_RATE = 500.0
_PAD_SECONDS = 0.5


def _int(value, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class _Clock:
    """The run's control steps: ``settle`` periods before the record, a lead-in and a tail.

    Attributes:
        rate: control (and sampling) rate, Hz; h: its step, s.
        period: samples per period of the reference.
        lead: recorded samples before the first returned one (the filter's lead-in).
        pad: recorded samples after the last returned one.
        start: the first recorded control step; n_rec: steps recorded; n_total: steps run.
    """

    rate: float
    h: float
    period: int
    lead: int
    pad: int
    start: int
    n_rec: int
    n_total: int

    @classmethod
    def of(cls, rate: float, period: int, settle_periods: int, n_samples: int) -> _Clock:
        pad = int(np.ceil(_PAD_SECONDS * rate))
        lead = min(pad, settle_periods * period)
        start = settle_periods * period - lead
        n_rec = lead + n_samples + pad
        return cls(rate, 1.0 / rate, period, lead, pad, start, n_rec, start + n_rec)


@dataclass(frozen=True)
class _TrackingLaw:
    """``qdd_cmd = const[k % period] - kp q - kd qd``: the PD law on one period of reference.

    Attributes:
        q0, qd0: ``(n_dof,)`` the reference at t = 0 (the initial state).
        const: ``(period, n_dof)`` ``qdd_ref + kp q_ref + kd qd_ref``.
        kp, kd: acceleration gains, 1/s^2 and 1/s.
    """

    q0: np.ndarray
    qd0: np.ndarray
    const: np.ndarray
    kp: float
    kd: float

    @classmethod
    def of(cls, trajectory: SinusoidTrajectory, clock: _Clock, bandwidth_hz, damping_ratio):
        q_ref, qd_ref, qdd_ref = trajectory.evaluate_numpy(np.arange(clock.period) * clock.h)
        if not bandwidth_hz > 0 or not damping_ratio > 0:
            raise ValueError("bandwidth_hz and damping_ratio must be positive")
        w = 2.0 * np.pi * bandwidth_hz
        kp, kd = w * w, 2.0 * damping_ratio * w
        return cls(q_ref[0], qd_ref[0], qdd_ref + kp * q_ref + kd * qd_ref, kp, kd)


def _period_samples(trajectory: SinusoidTrajectory, rate: float) -> int:
    """The reference's period in control steps; ValueError unless it is a whole number >= 2."""
    period_f = rate * trajectory.period
    period = int(round(period_f))
    if abs(period_f - period) > 1e-6 * period_f or period < 2:
        raise ValueError(
            f"the trajectory's period ({trajectory.period} s) times the control rate ({rate} Hz) "
            f"must be a whole number of samples, got {period_f}"
        )
    return period


def _sensor_noise(stds, seed, n_rec: int) -> list[np.ndarray]:
    """Gaussian sensor noise of q, qd and tau, ``(n_rec, n_dof)`` each (drawn in that order).

    Args:
        stds: the three ``(n_dof,)`` standard deviations (`SensorNoise.per_joint`).
        seed: a numpy seed (a `SeedSequence`).
    """
    rng = np.random.default_rng(seed)
    return [rng.standard_normal((n_rec, len(std))) * std for std in stds]


def _simulate(
    model, law: _TrackingLaw, clock: _Clock, substeps: int, *, feedback_noise, name, progress
):
    """Run the computed-torque loop and record the true state, acceleration and torque.

    The torque ``ID_mj(q, qd, qdd_cmd)`` (`mujoco.mj_inverse` at the true state) is held for
    ``substeps`` physics steps; ``feedback_noise`` ``(n_q, n_qd)`` (or None) is added to the
    state the PD errors see.

    Returns:
        ``Q, QD, QDD, TAU, SENSED``, ``(clock.n_rec, n_dof)`` each, from step ``clock.start``
        on: the state at each control instant, ``qacc`` right after it and the command held
        over the next step (exact with each other: `mujoco.mj_inverse`), and the torque a
        sensor sampled with the state reads, the mean of the applied torque over the sampling
        interval centred on the instant (half the sum of the previous and the current
        command).

    Raises:
        RuntimeError: if the simulation diverges.
    """
    n_rec, n_dof, start, period = clock.n_rec, model.njnt, clock.start, clock.period
    kp, kd, const = law.kp, law.kd, law.const
    Q = np.empty((n_rec, n_dof))
    QD = np.empty((n_rec, n_dof))
    QDD = np.empty((n_rec, n_dof))
    TAU = np.empty((n_rec, n_dof))
    before = np.zeros(n_dof)  # the command over the step before the first recorded one (none
    # before the first step: MjData starts with ctrl = 0)
    data = mujoco.MjData(model)
    data.qpos[:] = law.q0
    data.qvel[:] = law.qd0
    mujoco.mj_forward(model, data)
    qpos, qvel, qacc, ctrl = data.qpos, data.qvel, data.qacc, data.ctrl
    qfrc_inverse = data.qfrc_inverse
    tmp_p = np.empty(n_dof)
    tmp_v = np.empty(n_dof)
    step, inverse = mujoco.mj_step, mujoco.mj_inverse
    more = substeps - 1
    block = 1000
    n_total = clock.n_total
    with progress_bar(total=n_total, desc=f"simulate {name}", enabled=progress, unit="step") as bar:
        for k in range(n_total):
            i = k % period
            r = k - start
            if r >= 0:
                Q[r] = qpos
                QD[r] = qvel
            if feedback_noise is not None and r >= 0:
                np.add(qpos, feedback_noise[0][r], out=tmp_p)
                np.add(qvel, feedback_noise[1][r], out=tmp_v)
                tmp_p *= kp
                tmp_v *= kd
            else:
                np.multiply(kp, qpos, out=tmp_p)
                np.multiply(kd, qvel, out=tmp_v)
            np.subtract(const[i], tmp_p, out=qacc)
            qacc -= tmp_v
            inverse(model, data)  # M(q), bias and passive terms at the true state
            ctrl[:] = qfrc_inverse
            if r >= 0:  # the acceleration the command gives at the state (RK4's step
                QDD[r] = qacc  # leaves another stage's qacc behind)
                TAU[r] = ctrl
            elif r == -1:
                before[:] = ctrl
            step(model, data)
            if more:
                step(model, data, more)
            if (k + 1) % block == 0:
                if not np.isfinite(qacc).all():
                    raise RuntimeError(f"the simulation of {name} diverged at step {k}")
                bar.update(block)
        bar.update(n_total % block)
    for arr, what in ((Q, "q"), (QD, "qd"), (QDD, "qdd"), (TAU, "tau")):
        if not np.isfinite(arr).all():
            raise RuntimeError(f"the simulation of {name} diverged ({what} is not finite)")
    sensed = 0.5 * (np.vstack((before, TAU[:-1])) + TAU)
    return Q, QD, QDD, TAU, sensed


def _derivatives(t, q_meas, qd_meas, velocity_source: str, **kw) -> tuple[np.ndarray, np.ndarray]:
    """The logged qd and qdd: the velocity sensor and its derivative, or q's two derivatives.

    Args:
        t: ``(n,)`` s; q_meas, qd_meas: ``(n, n_dof)`` measured signals.
        kw: ``method`` and ``cutoff_hz`` of `torchjfa.data.differentiate`.
    """
    tt = torch.as_tensor(t, dtype=torch.float64)
    if velocity_source == "sensor":
        return qd_meas, differentiate(tt, qd_meas, **kw).first.numpy()
    der = differentiate(tt, q_meas, **kw)
    return der.first.numpy(), der.second.numpy()


def _robot_model(robot, unmodeled, name: str | None) -> tuple[mujoco.MjModel, str, float]:
    """The model to simulate (a shipped robot compiled, or a copy of the one given), its name
    and its default control rate, Hz."""
    if isinstance(robot, mujoco.MjModel):
        if unmodeled is not True:
            raise ValueError(
                "unmodeled applies to a shipped robot's name; set the joint effects on the "
                "MjModel itself (torchjfa.sim.set_effects)"
            )
        return copy.copy(robot), "robot" if name is None else str(name), DEFAULT_RATE
    model = load_robot(robot, unmodeled=unmodeled)
    return model, robot if name is None else str(name), DEFAULT_RATES[robot]


def generate_log(
    robot: str | mujoco.MjModel,
    *,
    n_samples: int = DEFAULT_N_SAMPLES,
    unmodeled: bool | Mapping[str, object] = True,
    trajectory: SinusoidTrajectory | None = None,
    control_rate: float | None = None,
    substeps: int = 4,
    noise: SensorNoise | None = None,
    velocity_source: str = "sensor",
    diff_method: str = "butterworth",
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    bandwidth_hz: float = 8.0,
    damping_ratio: float = 1.0,
    settle_periods: int = 1,
    noisy_feedback: bool = False,
    seed: int | None = 0,
    progress: bool = False,
    name: str | None = None,
) -> SimulatedLog:
    """Simulate a robot tracking a periodic excitation and record a noisy log.

    Args:
        robot: ``"head"`` or ``"arm"`` (see `load_robot`), or a compiled ``mujoco.MjModel``
            of a fixed-base robot with hinge and slide joints and one gear-1 torque motor per
            joint in joint order (e.g. `load_description`'s ``model``), simulated with the
            joint effects it has; it is copied, not modified.
        n_samples: samples to record (at the control rate); the first sample starts a period.
        unmodeled: which joint effects a shipped robot has, as in `load_robot` (leave it at
            True with an ``MjModel``).
        trajectory: the reference; default ``random_trajectory(model, seed=...)`` (a 4 s
            period). Its period times the control rate must be a whole number of samples.
        control_rate: control and sampling rate, Hz; default 420 (head), 480 (arm) or
            `DEFAULT_RATE` (500, an ``MjModel``).
        substeps: physics steps per control step (the timestep is their ratio).
        noise: `SensorNoise` (default ``SensorNoise()``; ``SensorNoise.zero()`` for none).
        velocity_source: ``"sensor"`` (qd is the noisy velocity sensor, qdd its derivative)
            or ``"differentiate"`` (qd and qdd are derivatives of the noisy position).
        diff_method: passed to `torchjfa.data.differentiate`.
        cutoff_hz: passed to `torchjfa.data.differentiate`.
        bandwidth_hz: the PD loop's bandwidth (see the module).
        damping_ratio: the PD loop's damping ratio.
        settle_periods: whole periods simulated before recording (at least 1: the filter's
            lead-in comes from the last of them).
        noisy_feedback: the controller's errors use the measured state (its model terms
            stay at the true state).
        seed: seeds the trajectory (when not given) and the noise (numpy Generators).
        progress: show a progress bar.
        name: the robot's name in the log and the progress bar (default: ``robot`` itself, or
            ``"robot"`` for an ``MjModel``).

    Returns:
        A `SimulatedLog` of ``n_samples`` samples.

    Raises:
        ValueError: on bad arguments, a period that is not a whole number of samples, or a
            trajectory with the wrong number of joints.
        RuntimeError: if the simulation diverges.
    """
    model, name, default_rate = _robot_model(robot, unmodeled, name)
    check_hinge_robot(model)
    n_dof = model.njnt
    n_samples = _int(n_samples, "n_samples", 2)
    substeps = _int(substeps, "substeps", 1)
    settle_periods = _int(settle_periods, "settle_periods", 1)
    if velocity_source not in ("sensor", "differentiate"):
        raise ValueError(
            f"velocity_source must be 'sensor' or 'differentiate', got {velocity_source!r}"
        )
    rate = default_rate if control_rate is None else float(control_rate)
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"control_rate must be positive, got {control_rate}")
    noise = SensorNoise() if noise is None else noise
    if not isinstance(noise, SensorNoise):
        raise TypeError(f"noise must be a SensorNoise, got {type(noise)}")
    stds = noise.per_joint(n_dof)
    traj_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
    if trajectory is None:
        trajectory = random_trajectory(model, seed=traj_seed)
    if trajectory.n_dof != n_dof:
        raise ValueError(f"trajectory has {trajectory.n_dof} joints, the robot has {n_dof}")
    clock = _Clock.of(rate, _period_samples(trajectory, rate), settle_periods, n_samples)
    model.opt.timestep = clock.h / substeps
    law = _TrackingLaw.of(trajectory, clock, bandwidth_hz, damping_ratio)
    n_q, n_qd, n_tau = _sensor_noise(stds, noise_seed, clock.n_rec)
    Q, QD, QDD, TAU, SENSED = _simulate(
        model,
        law,
        clock,
        substeps,
        feedback_noise=(n_q, n_qd) if noisy_feedback else None,
        name=name,
        progress=progress,
    )
    t_rec = (clock.start + np.arange(clock.n_rec)) * clock.h
    q_meas = Q + n_q
    qd_meas = QD + n_qd
    tau_meas = SENSED + n_tau
    qd_log, qdd_log = _derivatives(
        t_rec, q_meas, qd_meas, velocity_source, method=diff_method, cutoff_hz=cutoff_hz
    )
    keep = slice(clock.lead, clock.lead + n_samples)

    def out(a):
        return torch.as_tensor(np.ascontiguousarray(a[keep]), dtype=torch.float64)

    fields = _fields(model)
    return SimulatedLog(
        robot=name,
        joint_names=joint_names(model),
        t=out(t_rec),
        q=out(q_meas),
        qd=out(qd_log),
        qdd=out(qdd_log),
        tau=out(tau_meas),
        q_true=out(Q),
        qd_true=out(QD),
        qdd_true=out(QDD),
        tau_true=out(TAU),
        period_samples=clock.period,
        control_rate=rate,
        noise=noise,
        seed=seed,
        effects={k: np.array(v, dtype=np.float64) for k, v in fields.items()},
        trajectory=trajectory,
        velocity_source=velocity_source,
        diff_method=diff_method,
        diff_cutoff_hz=cutoff_hz,
    )
