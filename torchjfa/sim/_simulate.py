"""Any robot in MuJoCo, as ``torchjfa simulate`` and ``torchjfa evaluate --robot`` run it.

`simulated_robot` compiles the robot to simulate: one of the Sarcos-like robots (``head``,
``arm``, their unmodelled joint effects on unless asked otherwise), a shipped description or a
URDF / MJCF file (`load_description`: its inertials, gravity and joint ranges; no joint effects
unless asked for), with joint effects set on any of them, so that a log carries effects the
identified model does not. `simulate` records its noisy log tracking a trajectory (a random
excitation by default); `limit_warnings` says where that motion passed the description's
velocity and effort limits, which the simulation does not enforce; `evaluate_simulated` judges
an identified model on a fresh noiseless trajectory of the robot and in computed-torque
control.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch

from ..report import predicted_torques, torque_errors
from ..robots import SIMULATED
from ._control import evaluate_control
from ._description import Description, load_description
from ._generate import DEFAULT_N_SAMPLES, DEFAULT_RATE, DEFAULT_RATES, generate_log
from ._log import SensorNoise, SimulatedLog
from ._robots import joint_names, load_robot, set_effects
from ._trajectory import SinusoidTrajectory, random_trajectory

__all__ = [
    "SimulatedEvaluation",
    "SimulatedRobot",
    "check_trajectory",
    "evaluate_simulated",
    "limit_warnings",
    "simulate",
    "simulated_robot",
]

#: a random excitation's speed bound, x the description's velocity limit
SPEED_MARGIN = 0.9
#: rad (m): how far a given trajectory may pass a joint's range
RANGE_TOLERANCE = 1e-6
#: samples of `evaluate_simulated`'s test trajectory at the control rate
DEFAULT_TEST_SAMPLES = 8400
#: the unmodelled joint effects a description drops with ``unmodeled=False`` (damping stays)
_UNMODELED = ("armature", "frictionloss", "stiffness")


@dataclass(frozen=True)
class SimulatedRobot:
    """A robot ready to simulate.

    Attributes:
        model: the ``mujoco.MjModel`` with its joint effects set.
        name: as the user gave it.
        rate: control and sampling rate, Hz.
        description: the `Description` of a URDF or MJCF robot (None for head and arm).
    """

    model: mujoco.MjModel
    name: str
    rate: float
    description: Description | None = None

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The joints, in MuJoCo's order."""
        return joint_names(self.model)

    @property
    def velocity_limit(self) -> np.ndarray | None:
        """``(n_dof,)`` the description's velocity limits, rad/s (None for head and arm)."""
        return None if self.description is None else self.description.velocity_limit


def simulated_robot(
    robot: str,
    *,
    effects: Mapping[str, object] | None = None,
    rate: float | None = None,
    unmodeled: bool = True,
    description_effects: bool = False,
) -> SimulatedRobot:
    """Compile a robot for simulation.

    Args:
        robot: ``"head"`` or ``"arm"``, a shipped description's name or a URDF or MJCF path.
        effects: joint effects (`torchjfa.sim.EFFECTS`: damping, armature, frictionloss,
            stiffness) -> one float for every joint or one per joint in the robot's joint
            order; they replace the robot's own (units as `set_effects`).
        rate: control and sampling rate, Hz; default 420 for head, 480 for arm, `DEFAULT_RATE`
            (500) for a description.
        unmodeled: head and arm keep their armature, dry friction and spring (the damping,
            which the identified model has, always stays); False drops them from a
            description's effects too.
        description_effects: keep the joint effects the description writes (a URDF's
            ``<dynamics damping friction>``, an MJCF's damping, armature, frictionloss,
            stiffness); for descriptions only.

    Returns:
        The `SimulatedRobot`.

    Raises:
        ValueError: on a description MuJoCo cannot simulate (`DescriptionError`), bad effect
            values or a rate that is not a positive number.
    """
    if rate is not None and not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"the rate must be a positive number of Hz, got {rate:g}")
    effects = dict(effects or {})
    if robot in SIMULATED:
        if description_effects:
            raise ValueError("description effects are for a description, not head or arm")
        model = load_robot(robot, unmodeled=unmodeled)
        set_effects(model, effects)
        return SimulatedRobot(model, robot, rate or DEFAULT_RATES[robot])
    desc = load_description(robot, own_effects=description_effects)
    if not unmodeled:
        set_effects(desc.model, dict.fromkeys(_UNMODELED, 0.0))
    set_effects(desc.model, effects)
    return SimulatedRobot(desc.model, robot, rate or DEFAULT_RATE, desc)


def check_trajectory(
    trajectory: SinusoidTrajectory, robot: SimulatedRobot, *, name: str = ""
) -> None:
    """Raise if the trajectory leaves a limited joint's range (checked at 20 points per period
    of its highest harmonic, to `RANGE_TOLERANCE`).

    Args:
        trajectory: the reference, in the robot's joint order.
        robot: the robot.
        name: the trajectory's name for the message (a file name).

    Raises:
        ValueError: naming the first joint whose range the trajectory leaves.
    """
    what = f"the trajectory {name!r}" if name else "the trajectory"
    n = max(64, 20 * int(trajectory.harmonic.max()))
    q = trajectory.evaluate_numpy(np.arange(n) * (trajectory.period / n))[0]
    if q.shape[1] != robot.model.njnt:
        raise ValueError(
            f"{what} moves {q.shape[1]} joints; the simulated {robot.name} has {robot.model.njnt}"
        )
    limited = np.asarray(robot.model.jnt_limited, dtype=bool)
    lo, hi = np.asarray(robot.model.jnt_range, dtype=np.float64).T
    below = (q.min(axis=0) < lo - RANGE_TOLERANCE) & limited
    above = (q.max(axis=0) > hi + RANGE_TOLERANCE) & limited
    bad = np.flatnonzero(below | above)
    if bad.size:
        j = int(bad[0])
        raise ValueError(
            f"{what} leaves the range [{lo[j]:.4g}, {hi[j]:.4g}] of joint "
            f"{robot.joint_names[j]!r} (it reaches {q[:, j].min():.4g} .. {q[:, j].max():.4g})"
        )


def default_trajectory(robot: SimulatedRobot, seed) -> SinusoidTrajectory | None:
    """The random excitation `simulate` tracks when given none: for a description within 60 %
    of each joint range and `SPEED_MARGIN` of its velocity limits; None for head and arm
    (`generate_log` draws their own from the seed)."""
    if robot.description is None:
        return None
    limit = robot.velocity_limit * SPEED_MARGIN
    traj_seed = np.random.SeedSequence(seed).spawn(2)[0] if isinstance(seed, int) else seed
    return random_trajectory(robot.model, seed=traj_seed, velocity_limit=limit)


def simulate(
    robot: SimulatedRobot | str,
    *,
    trajectory: SinusoidTrajectory | None = None,
    n_samples: int = DEFAULT_N_SAMPLES,
    noise_scale: float = 1.0,
    seed: int = 0,
    progress: bool = False,
) -> SimulatedLog:
    """Simulate a robot tracking a trajectory under computed-torque control, with sensor noise.

    Args:
        robot: a `SimulatedRobot` or a name or path for `simulated_robot` (default effects).
        trajectory: the reference in the robot's joint order (a `SinusoidTrajectory`;
            ``torchjfa.excitation.FourierTrajectory.to_sinusoid`` gives one); checked against
            the joint ranges; default `default_trajectory` of the seed.
        n_samples: samples to record at the control rate.
        noise_scale: times the default sensor noise (`SensorNoise`: 1e-3 rad, 0.02 rad/s,
            0.02 N m); 0 for none.
        seed: seed of the excitation and the noise.
        progress: show a progress bar.

    Returns:
        The `SimulatedLog` (noisy measurements and the ground truth).

    Raises:
        ValueError: on a trajectory that leaves a joint's range, a negative noise scale, or a
            simulation that cannot run (a trajectory period that is no whole number of samples,
            an unstable simulation).
    """
    if not noise_scale >= 0:
        raise ValueError(f"the noise scale must be non-negative, got {noise_scale:g}")
    if not isinstance(robot, SimulatedRobot):
        robot = simulated_robot(robot)
    if trajectory is None:
        trajectory = default_trajectory(robot, seed)
    else:
        check_trajectory(trajectory, robot)
    try:
        return generate_log(
            robot.model,
            name=robot.name,
            control_rate=robot.rate,
            n_samples=n_samples,
            noise=SensorNoise().scaled(noise_scale),
            seed=seed,
            progress=progress,
            trajectory=trajectory,
        )
    except RuntimeError as exc:  # an unstable simulation: MuJoCo's words
        raise ValueError(" ".join(str(exc).split())) from None


def limit_warnings(robot: SimulatedRobot, log: SimulatedLog) -> list[str]:
    """Where the logged motion passes the description's velocity or effort limits (which the
    simulation does not enforce); none for head and arm."""
    if robot.description is None:
        return []
    desc = robot.description
    out = []
    for what, values, limit, unit in (
        ("speed", log.qd_true, desc.velocity_limit, "rad/s"),
        ("torque", log.tau_true, desc.effort_limit, "N m"),
    ):
        peak = np.abs(values.numpy()).max(axis=0)
        for j in np.flatnonzero(peak > limit):
            out.append(
                f"joint {log.joint_names[j]!r} reaches a {what} of {peak[j]:.4g} {unit}, over "
                f"the description's limit {limit[j]:.4g} (the simulation does not enforce it)"
            )
    return out


@dataclass(frozen=True)
class SimulatedEvaluation:
    """An identified model judged on a simulated robot (`evaluate_simulated`).

    Attributes:
        robot: the robot's name.
        joint_names: ``(n_dof,)`` the model's joints.
        nmse: ``(n_dof,)`` torque nMSE on the fresh noiseless trajectory.
        rms: ``(n_dof,)`` torque RMS error, N m.
        seed: the test trajectory's seed.
        control: computed-torque control with the model (``success``, ``reason``,
            ``rms_position`` in rad, ``rms_feedback`` in N m, ``seconds``), or None.
    """

    robot: str
    joint_names: tuple[str, ...]
    nmse: torch.Tensor
    rms: torch.Tensor
    seed: int
    control: dict | None = field(default=None)

    def lines(self) -> list[str]:
        """The result as a table to print."""
        out = [
            f"{self.robot}: torque prediction on a fresh noiseless trajectory (seed {self.seed})"
        ]
        w = max(16, *map(len, self.joint_names))
        out.append(f"{'joint':<{w}} {'nMSE':>10} {'RMS [N m]':>10}")
        for j, name in enumerate(self.joint_names):
            out.append(f"{name:<{w}} {float(self.nmse[j]):>10.4g} {float(self.rms[j]):>10.4g}")
        mean_rms = float(self.rms.pow(2).mean().sqrt())
        out.append(f"{'mean':<{w}} {float(self.nmse.mean()):>10.4g} {mean_rms:>10.4g}")
        c = self.control
        if c is not None and c["success"]:
            out.append(
                f"computed-torque control for {c['seconds']:g} s: RMS position error "
                f"{c['rms_position']:.4g} rad, RMS feedback {c['rms_feedback']:.4g} N m"
            )
        elif c is not None:
            out.append(f"computed-torque control FAILED: {c['reason']}")
        return out

    def summary(self) -> dict:
        """The numbers as JSON-ready values."""
        out = {"nmse": self.nmse.tolist(), "rms": self.rms.tolist()}
        if self.control is not None:
            out["control"] = {k: self.control[k] for k in ("success", "reason", "rms_position")}
        return out


def evaluate_simulated(
    model,
    theta: torch.Tensor,
    robot: SimulatedRobot | str,
    *,
    n_samples: int = DEFAULT_TEST_SAMPLES,
    seed: int = 100,
    control_seconds: float | None = 4.0,
    progress: bool = False,
) -> SimulatedEvaluation:
    """Judge identified parameters on a simulated robot: the torques of a fresh noiseless
    trajectory, and computed-torque control with the model in MuJoCo.

    Args:
        model: the identified `torchjfa.dynamics.RigidBodyModel` (its joints the robot's, in
            any order).
        theta: ``(n_params,)`` its parameters.
        robot: a `SimulatedRobot`, or a name or path for `simulated_robot`.
        n_samples: samples of the test trajectory at the control rate.
        seed: seed of the test trajectory (the control run's excitation takes ``seed + 1``).
        control_seconds: duration of the control run, s; None for no control run.
        progress: show a progress bar.

    Returns:
        The `SimulatedEvaluation`.

    Raises:
        ValueError: if the model's joints are not the robot's.
    """
    if not isinstance(robot, SimulatedRobot):
        robot = simulated_robot(robot)
    if sorted(model.joint_names) != sorted(robot.joint_names):
        raise ValueError(
            f"the model's joints {model.joint_names} are not the simulated {robot.name}'s "
            f"{robot.joint_names}"
        )
    log = simulate(robot, n_samples=n_samples, seed=seed, progress=progress)
    log = log.reorder(model.joint_names)
    q, qd, qdd, tau = (getattr(log, k + "_true") for k in ("q", "qd", "qdd", "tau"))
    theta = torch.as_tensor(theta, dtype=torch.float64)
    nmse, rms = torque_errors(tau, predicted_torques(model, theta, q, qd, qdd, tau))
    control = None
    if control_seconds is not None:
        traj = default_trajectory(robot, seed + 1)
        if traj is None:
            traj = random_trajectory(robot.model, seed=seed + 1)
        res = evaluate_control(
            robot.model,
            model,
            {"identified": theta},
            traj,
            duration=control_seconds,
            control_rate=robot.rate,
        )["identified"]
        control = {
            "success": res.success,
            "reason": res.reason,
            "rms_position": res.mean_rms_position if res.success else None,
            "rms_feedback": res.mean_rms_feedback if res.success else None,
            "seconds": control_seconds,
        }
    return SimulatedEvaluation(
        robot=robot.name,
        joint_names=tuple(model.joint_names),
        nmse=nmse,
        rms=rms,
        seed=seed,
        control=control,
    )
