"""``torchjfa simulate``: any robot description in MuJoCo, tracking an excitation, written as a
log (`torchjfa.sim.simulated_robot`, `torchjfa.sim.simulate`).

    torchjfa simulate head --out log.csv
    torchjfa simulate robot.urdf --trajectory traj/trajectory.npz --out log.csv
    torchjfa simulate panda_arm --damping 0.5 --armature 0.1 --frictionloss 0.2 --out log.csv
"""

from __future__ import annotations

import argparse
import shlex
import sys
import zipfile
from pathlib import Path

from ..robots import SIMULATED
from ._common import COMMANDS, UsageError, default_of, numbers, usage

__all__ = ["add_simulate", "add_simulation_options", "cmd_simulate", "simulated_robot"]

_EFFECT_OPTIONS = {
    "damping": "viscous joint damping, N m s/rad",
    "armature": "armature (reflected rotor inertia), kg m^2",
    "frictionloss": "dry (Coulomb) joint friction, N m",
    "stiffness": "joint spring stiffness (about the spring reference, q = 0 unless the "
    "description sets one), N m/rad",
}


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
        g.add_argument(f"--{name}", type=numbers, default=None, metavar="X[,X...]", help=what)
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
    from ..sim import simulate

    p = sub.add_parser(
        "simulate",
        help=COMMANDS["simulate"],
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
    p.add_argument(
        "--out", required=True, help="output: .csv, .npz or .parquet (written whole, or not at all)"
    )
    p.set_defaults(output="file")
    p.add_argument("--n-samples", type=int, default=default_of(simulate, "n_samples"),
                   help="samples at the control rate")  # fmt: skip
    p.add_argument("--seed", type=int, default=default_of(simulate, "seed"),
                   help="seed of the excitation and the noise")  # fmt: skip
    p.add_argument(
        "--noise-scale",
        type=float,
        default=default_of(simulate, "noise_scale"),
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
    _add_legged(p)
    p.set_defaults(func=cmd_simulate)
    return p


def _add_legged(p: argparse.ArgumentParser) -> None:
    """The options of a floating-base robot's simulation (`torchjfa.sim.simulate_legged`)."""
    from ..sim import simulate_legged
    from ..sim._legged import STEP_SWAY, SWAY

    g = p.add_argument_group(
        "a floating-base robot (legged robot, humanoid)",
        "With --feet, ROBOT is a floating-base URDF (its root link the base) simulated "
        "standing on a floor and swaying its body under joint PD control (with --step, "
        "stepping in place); the log holds "
        "the base pose, joint positions and torques, contact_<foot> flags and the ground's "
        "forces and moments on each foot (f_<foot>_x.., m_<foot>_x..), with sensor noise.",
    )
    g.add_argument("--feet", type=_names, default=None, metavar="F1,F2",
                   help="the links that touch the ground (a sphere at each)")  # fmt: skip
    g.add_argument(
        "--stance",
        type=_stance,
        default={},
        metavar="J=RAD,...",
        help="the standing pose: joint=position, rad (joints not named stay at 0)",
    )
    g.add_argument("--seconds", type=float, default=default_of(simulate_legged, "seconds"),
                   help="recorded time, s")  # fmt: skip
    g.add_argument(
        "--perturb",
        type=float,
        default=default_of(simulate_legged, "perturb"),
        help="the simulated bodies differ from the description by up to this fraction "
        "(masses, inertias; centres of mass by this times 5 cm)",
    )
    g.add_argument(
        "--amplitude",
        type=_amplitude,
        default=default_of(simulate_legged, "amplitude"),
        metavar="RAD|J=RAD,...",
        help="each joint's sway about the stance, rad (hips 40 %% of it; default "
        f"{SWAY:g}), or joint=rad for the joints that move (the others hold the stance: a "
        "humanoid's legs)",
    )
    g.add_argument("--step", type=float, default=0.0, metavar="M",
                   help="step in place (point feet): lift each foot in turn by M metres while "
                   "the body leans away from it; the sway's default drops to "
                   f"{STEP_SWAY:g} rad")  # fmt: skip
    g.add_argument("--foot-size", type=numbers, default=None, metavar="L,W",
                   help="flat feet: a sphere at each corner of an L x W m rectangle about each "
                   "foot frame (a humanoid's soles); default point feet")  # fmt: skip
    g.add_argument("--gains", type=numbers, default=default_of(simulate_legged, "gains"),
                   metavar="KP,KD", help="the joints' PD gains (raise them for a heavy robot)")  # fmt: skip
    g.add_argument("--truth-seed", type=int, default=0, help="seed of the perturbation")
    g.add_argument("--no-forces", action="store_true",
                   help="write contact flags only, no forces (no force sensors)")  # fmt: skip
    g.add_argument("--imu", default=None, metavar="LINK",
                   help="an IMU on this link (fixed to the base): write its gyroscope and "
                   "accelerometer (imu_wx.., imu_ax..); identify with --imu-frame LINK")  # fmt: skip


def _names(text: str) -> tuple[str, ...]:
    names = tuple(s.strip() for s in text.split(",") if s.strip())
    if not names:
        raise argparse.ArgumentTypeError("give one or more link names, comma separated")
    return names


def _amplitude(text: str) -> float | dict[str, float]:
    try:
        return float(text)
    except ValueError:
        return _stance(text)


def _stance(text: str) -> dict[str, float]:
    out = {}
    for item in (s.strip() for s in text.split(",") if s.strip()):
        name, eq, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            eq = ""
        if not eq or not name.strip():
            raise argparse.ArgumentTypeError(f"expected joint=radians, got {item!r}")
    return out


def _pair(values, flag: str) -> tuple[float, float] | None:
    if values is None:
        return None
    if len(values) != 2 or not all(0 < v < float("inf") for v in values):
        raise UsageError(f"{flag} takes two positive numbers, got {list(values)}")
    return (float(values[0]), float(values[1]))


def _simulate_legged(args) -> int:
    """``torchjfa simulate ROBOT --feet ...``: a floating-base robot standing and swaying."""
    from dataclasses import replace

    from ..sim import simulate_legged

    given = [a.split("=")[0] for a in args.argv if a.startswith("--")]
    arm_only = sorted({"--n-samples", "--trajectory", "--full", "--no-velocity",
                       "--no-unmodeled", "--description-effects", *(f"--{k}" for k in
                       _EFFECT_OPTIONS)} & set(given))  # fmt: skip
    if arm_only:
        raise UsageError(f"{', '.join(arm_only)}: not for a floating-base robot (--feet)")
    if not args.noise_scale >= 0:
        raise UsageError(f"--noise-scale must be non-negative, got {args.noise_scale:g}")
    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".npz"):
        raise UsageError(f"a legged log is written as .csv or .npz, got {args.out!r}")
    try:
        log = simulate_legged(
            args.robot, args.feet, args.stance, seconds=args.seconds,
            rate=args.rate or 200.0, perturb=args.perturb, truth_seed=args.truth_seed,
            seed=args.seed, progress=not args.quiet, amplitude=args.amplitude,
            foot_size=_pair(args.foot_size, "--foot-size"), gains=_pair(args.gains, "--gains"),
            imu=args.imu, step=args.step,
        )  # fmt: skip
    except (ValueError, OSError) as exc:
        raise usage(exc) from None
    written = log.noisy(args.noise_scale, seed=args.seed + 1)
    if args.no_forces:
        written = replace(written, wrench={})
    written.save(out)
    mass = float(log.theta.reshape(-1, 10)[:, 0].sum())
    print(
        f"wrote {len(log.t)} samples ({args.seconds:g} s) of the simulated {Path(args.robot).name} "
        f"(total mass {mass:.4g} kg) to {out}; identify with:\n"
        f"  torchjfa identify {shlex.quote(args.robot)} {shlex.quote(str(out))} --out result/"
        + (f" --imu-frame {shlex.quote(args.imu)}" if args.imu else "")
    )
    return 0


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


def simulated_robot(args, *, unmodeled: bool = True):
    """The `torchjfa.sim.SimulatedRobot` of ``args.robot`` with the effect options of ``args``
    (`add_simulation_options`).

    Raises:
        UsageError: on a description that cannot be simulated or bad effect values.
    """
    from ..sim import set_effects
    from ..sim import simulated_robot as compile_robot

    if args.rate is not None and not args.rate > 0:
        raise UsageError(f"--rate must be a positive number of Hz, got {args.rate:g}")
    if args.description_effects and args.robot in SIMULATED:
        raise UsageError("--description-effects is for a description, not head or arm")
    try:
        robot = compile_robot(
            args.robot, rate=args.rate, unmodeled=unmodeled,
            description_effects=args.description_effects,
        )  # fmt: skip
        set_effects(robot.model, _effects(args, robot.joint_names))
    except ValueError as exc:
        raise usage(exc) from None
    return robot


def trajectory_file(path, robot):
    """The trajectory written by ``torchjfa excite`` (``trajectory.npz``) as the simulator's
    reference, in the robot's joint order.

    Raises:
        UsageError: if the file is missing or holds no trajectory, its joints are not the
            robot's, or it leaves a joint's range.
    """
    from ..excitation import FourierTrajectory
    from ..sim import check_trajectory

    if not Path(path).is_file():
        raise UsageError(f"no trajectory file {str(path)!r}")
    try:
        traj = FourierTrajectory.load(path)
    except (ValueError, OSError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        why = str(exc) if "torchjfa excite" in str(exc) else "not an .npz file of torchjfa excite"
        raise UsageError(f"cannot read the trajectory {str(path)!r}: {why}") from None
    try:
        sinusoid = traj.reorder(
            robot.joint_names, owner=f"the simulated {robot.name}"
        ).to_sinusoid()
        check_trajectory(sinusoid, robot, name=str(path))
    except ValueError as exc:
        raise usage(exc) from None
    return sinusoid


def cmd_simulate(args) -> int:
    """Run ``torchjfa simulate`` (see `add_simulate`)."""
    from ..data import JointLog, write_log
    from ..sim import limit_warnings, simulate

    if args.feet:
        return _simulate_legged(args)
    if not args.noise_scale >= 0:
        raise UsageError(f"--noise-scale must be non-negative, got {args.noise_scale:g}")
    robot = simulated_robot(args, unmodeled=not args.no_unmodeled)
    trajectory = trajectory_file(args.trajectory, robot) if args.trajectory else None
    try:
        log = simulate(
            robot,
            trajectory=trajectory,
            n_samples=args.n_samples,
            noise_scale=args.noise_scale,
            seed=args.seed,
            progress=not args.quiet,
        )
    except ValueError as exc:
        raise usage(exc) from None
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
    for line in limit_warnings(robot, log):
        print(f"warning: {line}", file=sys.stderr)
    on = [k for k, v in log.effects.items() if any(float(x) != 0.0 for x in v)]
    print(
        f"wrote {log.n_samples} samples ({log.n_samples / log.control_rate:.1f} s at "
        f"{log.control_rate:g} Hz) of the simulated {robot.name} to {out} (joint effects: "
        f"{', '.join(on) or 'none'}); identify with:\n"
        f"  torchjfa identify {shlex.quote(robot.name)} {shlex.quote(str(out))} --out result/"
    )
    return 0
