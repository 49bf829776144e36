"""``torchjfa simulate`` and ``torchjfa evaluate --robot``: any robot description in MuJoCo.

    torchjfa simulate head --out log.csv
    torchjfa simulate robot.urdf --trajectory traj/trajectory.npz --out log.csv
    torchjfa simulate panda_arm --damping 0.5 --armature 0.1 --frictionloss 0.2 --out log.csv
    torchjfa evaluate result/model.npz --robot robot.urdf

The robot is one of the simulated Sarcos-like robots (``head``, ``arm``: their unmodelled
joint effects on unless ``--no-unmodeled``), a shipped description (``panda_arm``, ...) or a
URDF / MJCF path, compiled by `torchjfa.sim.load_description` (its inertials, gravity and
joint ranges; no joint effects unless asked for). ``--damping``, ``--armature``,
``--frictionloss`` and ``--stiffness`` set joint effects on any of them (one number for every
joint, or one per joint in the robot's joint order), so that a log carries effects the
identified model does not. MuJoCo is imported only when a command runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

from .identification._options import IdentificationError as UsageError
from .robots import SIMULATED

__all__ = ["add_simulate", "add_simulation_options", "cmd_simulate", "evaluate_simulated"]

_EFFECT_OPTIONS = {
    "damping": "viscous joint damping, N m s/rad",
    "armature": "armature (reflected rotor inertia), kg m^2",
    "frictionloss": "dry (Coulomb) joint friction, N m",
    "stiffness": "joint spring stiffness (about the spring reference, q = 0 unless the "
    "description sets one), N m/rad",
}
_SPEED_MARGIN = 0.9  # a random excitation's speed bound, x the description's velocity limit
_RANGE_TOLERANCE = 1e-6  # rad (m): how far a given trajectory may pass a joint's range


def _numbers(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a number or comma-separated numbers, got {text!r}"
        ) from None
    return values


def add_simulation_options(p: argparse.ArgumentParser, *, no_unmodeled: bool = False) -> None:
    """The options that choose the simulated robot's joint effects and rate (simulate and
    evaluate share them; ``no_unmodeled``: the parser has ``--no-unmodeled``)."""
    g = p.add_argument_group(
        "simulated joint effects",
        "Each takes one number (every joint) or one per joint in the robot's joint order, "
        "comma-separated (slide joints in N and m), and replaces the robot's value. A "
        "description has none of them unless given (or --description-effects); head and arm "
        "have their own" + (" unless --no-unmodeled." if no_unmodeled else "."),
    )
    for name, what in _EFFECT_OPTIONS.items():
        g.add_argument(f"--{name}", type=_numbers, default=None, metavar="X[,X...]", help=what)
    g.add_argument(
        "--description-effects",
        action="store_true",
        help="simulate the joint effects the description writes (a URDF's <dynamics damping "
        "friction>, an MJCF's damping, armature, frictionloss, stiffness)",
    )
    p.add_argument(
        "--rate",
        type=float,
        default=None,
        metavar="HZ",
        help="control and sampling rate, Hz (default: 420 for head, 480 for arm, 500 for a "
        "description); a trajectory's period must be a whole number of samples",
    )


def add_simulate(sub) -> argparse.ArgumentParser:
    """The ``simulate`` sub-command's parser (runs `cmd_simulate`)."""
    p = sub.add_parser(
        "simulate",
        help="simulate a robot tracking an excitation and write its log",
        description="Simulate a robot in MuJoCo tracking a trajectory under computed-torque "
        "control, with sensor noise, and write a log as a real robot would give it: t, "
        "q_<joint>, qd_<joint>, tau_<joint> (no accelerations). The robot is the Sarcos-like "
        "head (7 DoF) or arm (10 DoF), a shipped description (panda_arm, ...) or a URDF or "
        "MJCF file: its inertials, gravity and joint ranges, its meshes and contacts ignored, "
        "one torque motor per joint, and no joint friction, damping or armature unless set "
        "below. Without --trajectory it tracks a random periodic excitation within 60 % of "
        "each joint range (and 90 % of a URDF's velocity limits).",
    )
    p.add_argument(
        "robot",
        metavar="ROBOT",
        help=f"a URDF or MJCF file, a shipped description or {'|'.join(SIMULATED)}",
    )
    p.add_argument("--out", required=True, help="output: .csv, .npz or .parquet")
    p.add_argument("--n-samples", type=int, default=50_000, help="samples at the control rate")
    p.add_argument("--seed", type=int, default=0, help="seed of the excitation and the noise")
    p.add_argument(
        "--noise-scale",
        type=float,
        default=1.0,
        help="x the default sensor noise (1e-3 rad, 0.02 rad/s, 0.02 N m); 0 for none",
    )
    p.add_argument(
        "--no-unmodeled",
        action="store_true",
        help="no armature, dry friction or joint spring (the damping stays: it is modelled)",
    )
    p.add_argument("--no-velocity", action="store_true", help="leave out the velocity columns")
    p.add_argument(
        "--full",
        action="store_true",
        help="with .npz: the whole SimulatedLog, ground truth included",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--trajectory",
        default=None,
        metavar="PATH",
        help="track this trajectory.npz from torchjfa excite, its joints matched by name "
        "(default: a random excitation)",
    )
    add_simulation_options(p, no_unmodeled=True)
    p.set_defaults(func=cmd_simulate)
    return p


@dataclass(frozen=True)
class _Robot:
    """The robot to simulate.

    Attributes:
        model: the ``mujoco.MjModel`` with its joint effects set.
        name: as the user gave it.
        rate: control and sampling rate, Hz.
        description: the `torchjfa.sim.Description` (None for head and arm).
    """

    model: object
    name: str
    rate: float
    description: object = None

    @property
    def joint_names(self) -> tuple[str, ...]:
        from .sim._robots import joint_names

        return joint_names(self.model)

    @property
    def velocity_limit(self):
        return None if self.description is None else self.description.velocity_limit


def _effects(args, names: tuple[str, ...]) -> dict[str, object]:
    """The effect options given, each a float or an ``(n_dof,)`` tuple."""
    out: dict[str, object] = {}
    for name in _EFFECT_OPTIONS:
        values = getattr(args, name, None)
        if values is None:
            continue
        if len(values) not in (1, len(names)):
            raise UsageError(
                f"--{name} takes 1 or {len(names)} numbers (one per joint, in the order "
                f"{', '.join(names)}), got {len(values)}"
            )
        if any(not v >= 0 or v == float("inf") for v in values):
            raise UsageError(f"--{name} must be finite and non-negative, got {list(values)}")
        out[name] = values[0] if len(values) == 1 else values
    return out


def simulated_robot(args, *, unmodeled: bool = True) -> _Robot:
    """The robot of ``args.robot`` with the effect options of ``args`` (`add_simulation_options`).

    Args:
        unmodeled: head and arm keep their armature, dry friction and spring (the damping
            always stays); a description's own effects are kept with ``--description-effects``.

    Raises:
        UsageError: on a description that cannot be simulated or bad effect values.
    """
    from .sim import DEFAULT_RATE, DEFAULT_RATES, load_description, load_robot, set_effects
    from .sim._robots import joint_names

    rate = args.rate
    if rate is not None and not (rate > 0 and rate < float("inf")):
        raise UsageError(f"--rate must be a positive number of Hz, got {rate:g}")
    if args.robot in SIMULATED:
        if args.description_effects:
            raise UsageError("--description-effects is for a description, not head or arm")
        model = load_robot(args.robot, unmodeled=unmodeled)
        set_effects(model, _effects(args, joint_names(model)))
        return _Robot(model, args.robot, rate or DEFAULT_RATES[args.robot])
    try:
        desc = load_description(args.robot, own_effects=args.description_effects)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not unmodeled:
        set_effects(desc.model, dict.fromkeys(("armature", "frictionloss", "stiffness"), 0.0))
    set_effects(desc.model, _effects(args, desc.joint_names))
    return _Robot(desc.model, args.robot, rate or DEFAULT_RATE, desc)


def reference(path, robot: _Robot):
    """The trajectory written by ``torchjfa excite`` (``trajectory.npz``) as the simulator's
    reference: a `torchjfa.sim.SinusoidTrajectory` in the robot's joint order.

    Raises:
        UsageError: if the file is missing or holds no trajectory, its joints are not the
            robot's, or it leaves a joint's range.
    """
    from .data._joints import permutation
    from .excitation._fourier import FourierTrajectory

    if not Path(path).is_file():
        raise UsageError(f"no trajectory file {str(path)!r}")
    try:
        traj = FourierTrajectory.load(path)
    except (ValueError, OSError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        why = str(exc) if "torchjfa excite" in str(exc) else "not an .npz file of torchjfa excite"
        raise UsageError(f"cannot read the trajectory {str(path)!r}: {why}") from None
    names = robot.joint_names
    try:
        perm = permutation(
            traj.joint_names,
            names,
            have_name="the trajectory",
            want_name=f"the simulated {robot.name}",
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    ordered = type(traj)(traj.base_frequency, traj.posture[perm], traj.a[perm], traj.b[perm], names)
    sinusoid = ordered.to_sinusoid()
    _check_range(sinusoid, robot, path)
    return sinusoid


def _check_range(trajectory, robot: _Robot, path) -> None:
    """UsageError if the reference leaves a limited joint's range (checked at 20 points per
    period of its highest harmonic)."""
    import numpy as np

    n = max(64, 20 * int(trajectory.harmonic.max()))
    q = trajectory.evaluate_numpy(np.arange(n) * (trajectory.period / n))[0]
    limited = np.asarray(robot.model.jnt_limited, dtype=bool)
    lo, hi = np.asarray(robot.model.jnt_range, dtype=np.float64).T
    below = (q.min(axis=0) < lo - _RANGE_TOLERANCE) & limited
    above = (q.max(axis=0) > hi + _RANGE_TOLERANCE) & limited
    bad = np.flatnonzero(below | above)
    if bad.size:
        j = int(bad[0])
        raise UsageError(
            f"the trajectory {str(path)!r} leaves the range [{lo[j]:.4g}, {hi[j]:.4g}] of "
            f"joint {robot.joint_names[j]!r} (it reaches {q[:, j].min():.4g} .. "
            f"{q[:, j].max():.4g})"
        )


def random_reference(robot: _Robot, seed):
    """A random excitation for a description (within 60 % of each joint range and 90 % of its
    velocity limits); None for head and arm (`generate_log` draws their own from the seed)."""
    if robot.description is None:
        return None
    import numpy as np

    from .sim import random_trajectory

    limit = robot.velocity_limit * _SPEED_MARGIN
    traj_seed = np.random.SeedSequence(seed).spawn(2)[0] if isinstance(seed, int) else seed
    return random_trajectory(robot.model, seed=traj_seed, velocity_limit=limit)


def _generate(robot: _Robot, **kw):
    from .sim import generate_log

    try:
        return generate_log(robot.model, name=robot.name, control_rate=robot.rate, **kw)
    except (ValueError, RuntimeError) as exc:
        raise UsageError(" ".join(str(exc).split())) from None


def cmd_simulate(args) -> int:
    """Run ``torchjfa simulate`` (see `add_simulate`)."""
    from .data import JointLog, write_log
    from .sim import SensorNoise

    if not args.noise_scale >= 0:
        raise UsageError(f"--noise-scale must be non-negative, got {args.noise_scale:g}")
    robot = simulated_robot(args, unmodeled=not args.no_unmodeled)
    if args.trajectory:
        trajectory = reference(args.trajectory, robot)
    else:
        trajectory = random_reference(robot, args.seed)
    log = _generate(
        robot,
        n_samples=args.n_samples,
        noise=SensorNoise().scaled(args.noise_scale),
        seed=args.seed,
        progress=not args.quiet,
        trajectory=trajectory,
    )
    out = Path(args.out)
    if out.suffix.lower() == ".npz" and args.full:
        log.save(out)
    else:
        kept = JointLog(
            t=log.t,
            q=log.q,
            qd=None if args.no_velocity else log.qd,
            tau=log.tau,
            joint_names=log.joint_names,
        )
        write_log(kept, out)
    for line in _limit_warnings(robot, log):
        print(f"warning: {line}", file=sys.stderr)
    on = [k for k, v in log.effects.items() if any(float(x) != 0.0 for x in v)]
    print(
        f"wrote {log.n_samples} samples ({log.n_samples / log.control_rate:.1f} s at "
        f"{log.control_rate:g} Hz) of the simulated {robot.name} to {out} (joint effects: "
        f"{', '.join(on) or 'none'}); identify with:\n"
        f"  torchjfa identify {shlex.quote(robot.name)} {shlex.quote(str(out))} --out result/"
    )
    return 0


def _limit_warnings(robot: _Robot, log) -> list[str]:
    """Where the logged motion passes the description's velocity or effort limits (which the
    simulation does not enforce)."""
    if robot.description is None:
        return []
    import numpy as np

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


def evaluate_simulated(args) -> int:
    """``torchjfa evaluate MODEL --robot ROBOT``: the torques of a fresh noiseless trajectory
    of the simulated robot, and computed-torque control with the model in MuJoCo."""
    from .io import read_identified
    from .report import predicted_torques, torque_errors

    if not os.path.isfile(args.model):
        raise UsageError(f"no model file {args.model!r}")
    try:
        ident = read_identified(args.model)
    except ValueError as exc:  # not a model file, or a damaged one: the message says which
        raise UsageError(str(exc)) from None
    model, theta = ident.model, ident.theta
    robot = simulated_robot(args)
    if sorted(model.joint_names) != sorted(robot.joint_names):
        raise UsageError(
            f"the model's joints {model.joint_names} are not the simulated {robot.name}'s "
            f"{robot.joint_names}"
        )
    log = _generate(
        robot,
        n_samples=args.n_samples,
        seed=args.seed,
        progress=not args.quiet,
        trajectory=random_reference(robot, args.seed),
    ).reorder(model.joint_names)
    q, qd, qdd, tau = (getattr(log, k + "_true") for k in ("q", "qd", "qdd", "tau"))
    pred = predicted_torques(model, theta, q, qd, qdd, tau)
    nmse, rms = torque_errors(tau, pred)
    print(f"{robot.name}: torque prediction on a fresh noiseless trajectory (seed {args.seed})")
    w = max(16, *map(len, model.joint_names))
    print(f"{'joint':<{w}} {'nMSE':>10} {'RMS [N m]':>10}")
    for j, name in enumerate(model.joint_names):
        print(f"{name:<{w}} {float(nmse[j]):>10.4g} {float(rms[j]):>10.4g}")
    print(f"{'mean':<{w}} {float(nmse.mean()):>10.4g} {float(rms.pow(2).mean().sqrt()):>10.4g}")
    out = {"nmse": nmse.tolist(), "rms": rms.tolist()}
    if not args.no_control:
        out["control"] = _control(args, robot, model, theta)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


def _control(args, robot: _Robot, model, theta) -> dict:
    """Computed-torque control of the robot with the identified model on a held-out random
    excitation (seed + 1); prints the outcome and returns it for the JSON."""
    from .sim import evaluate_control, random_trajectory

    traj = random_reference(robot, args.seed + 1)
    if traj is None:
        traj = random_trajectory(robot.model, seed=args.seed + 1)
    res = evaluate_control(
        robot.model,
        model,
        {"identified": theta},
        traj,
        duration=args.control_seconds,
        control_rate=robot.rate,
    )["identified"]
    if res.success:
        print(
            f"computed-torque control for {args.control_seconds:g} s: RMS position error "
            f"{res.mean_rms_position:.4g} rad, RMS feedback {res.mean_rms_feedback:.4g} N m"
        )
    else:
        print(f"computed-torque control FAILED: {res.reason}")
    return {
        "success": res.success,
        "reason": res.reason,
        "rms_position": None if not res.success else res.mean_rms_position,
    }
