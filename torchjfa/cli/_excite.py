"""``torchjfa excite``: design an optimal excitation and write it, its report and its plots
(`torchjfa.excitation.limits_from_model`, `torchjfa.excitation.design_excitation`).

    torchjfa excite ROBOT --duration 10 --base-freq 0.1 --harmonics 5 --out traj/
    torchjfa simulate head --trajectory traj/trajectory.npz --out log.csv
"""

from __future__ import annotations

import argparse
import functools

from ._common import (
    COMMANDS,
    add_output,
    default_of,
    friction_terms,
    load_model,
    numbers,
    usage,
    written_as,
)

__all__ = ["add_excite", "cmd_excite"]


def _box(text: str):
    from ..excitation import WorkspaceBox

    parts = text.split(":")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected FRAME:xlo,ylo,zlo:xhi,yhi,zhi, got {text!r}")
    try:
        return WorkspaceBox(parts[0], numbers(parts[1]), numbers(parts[2]))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_excite(subparsers) -> argparse.ArgumentParser:
    """Add the ``excite`` subcommand to ``torchjfa``'s subparsers; returns its parser (which
    runs `cmd_excite`)."""
    from ..excitation import CRITERIA, DEFAULT_RATE, limits_from_model, optimize_excitation

    design = functools.partial(default_of, optimize_excitation)
    limit = functools.partial(default_of, limits_from_model)
    p = subparsers.add_parser(
        "excite",
        help=COMMANDS["excite"],
        description="Optimise a periodic Fourier-series trajectory (at rest at a posture at the "
        "start of every period) for the identification of a robot: D-optimality (or the "
        "condition number, or E-optimality) of the base-parameter information matrix, through "
        "the batched regressor with autograd, inside the position, velocity, acceleration, "
        "torque and workspace limits. Safe by default: margins inside the description's "
        "position and velocity limits, an acceleration limit where the description has none, "
        "no part of the arm near or below the plane it is mounted on (z = 0 of the root frame "
        "unless --floor says otherwise), and no self-collision (capsules along the links, and "
        "the description's collision geometry through MuJoCo where it has some). Every "
        "constraint is checked on a grid 10x finer than the output rate; the motion is shrunk "
        "about the posture where it has to be, and when even that cannot hold a constraint "
        "the command ends with an error naming each one. Writes the trajectory (CSV, NPZ), its coefficients, a report "
        "(the margins left to every limit, in physical units) against a random sum of "
        "sinusoids in the same limits, and plots.",
    )
    p.add_argument(
        "robot", help="URDF or MJCF file, or a shipped robot: panda, panda_arm, head, arm, ..."
    )
    add_output(p, default="traj", what="the trajectory, its report and figures")
    p.add_argument(
        "--duration", type=float, default=design("duration"), help="s; whole periods of 1/base-freq"
    )
    p.add_argument(
        "--base-freq", type=float, default=design("base_frequency"), help="base frequency f0, Hz"
    )
    p.add_argument(
        "--harmonics", type=int, default=design("harmonics"), help="harmonics per joint (>= 2)"
    )
    p.add_argument(
        "--criterion", choices=CRITERIA, default=design("criterion"),
        help="d+condition: D-optimal starts, the best polished on the condition number; d: "
        "D-optimality (-log det); condition: log condition number; e: E-optimality "
        "(-log lambda_min)",
    )  # fmt: skip
    p.add_argument(
        "--payload", default=None, metavar="LINK",
        help="design for the parameters of a payload fixed to LINK alone (the robot's model "
        "given, as torchjfa payload uses it) instead of the robot's",
    )  # fmt: skip
    p.add_argument(
        "--friction", type=friction_terms, default=("viscous",),
        help="joint terms in the parameters, comma separated (viscous, coulomb, offset, ...) "
        "or 'none'",
    )  # fmt: skip
    p.add_argument(
        "--rate", type=float, default=None,
        help="output rate, Hz; when not given 420 for head, 480 for arm, else "
        f"{DEFAULT_RATE:g}; the limits are "
        "checked at 10x",
    )  # fmt: skip
    p.add_argument(
        "--posture",
        type=numbers,
        default=None,
        help="q0 per joint, rad (m); when not given the middle of the limits, moved to the "
        "nearest posture that keeps the arm 5 cm beyond --clearance from the floor",
    )
    _add_limits(p, limit)
    p.add_argument("--starts", type=int, default=design("n_starts"), help="random starts")
    p.add_argument(
        "--optimizer", choices=("lbfgs", "adam"), default=design("optimizer"), help="optimiser"
    )
    p.add_argument(
        "--max-iter", type=int, default=design("max_iter"),
        help="iterations per start (and per exponent for --criterion condition)",
    )  # fmt: skip
    p.add_argument(
        "--polish-iter", type=int, default=design("polish_iter"),
        help="d+condition: iterations per exponent of the condition number's polish",
    )  # fmt: skip
    p.add_argument(
        "--polish-starts", type=int, default=design("polish_starts"),
        help="d+condition: how many of the best D-optimal starts are polished (each: one polish)",
    )  # fmt: skip
    p.add_argument(
        "--grid", type=int, default=design("n_grid"), help="coarse grid points per period"
    )
    p.add_argument("--seed", type=int, default=design("seed"), help="seed of the random starts")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_excite)
    return p


def _add_limits(p: argparse.ArgumentParser, limit) -> None:
    """The limits' and the safety checks' options of ``excite`` (``limit(name)``: the default
    of `limits_from_model`'s keyword)."""
    from ..excitation._limits import DEFAULT_ACCELERATION_TIME

    p.add_argument(
        "--position-margin",
        type=float,
        default=limit("position_margin"),
        help="fraction of each range",
    )
    p.add_argument(
        "--velocity-limit",
        type=numbers,
        default=None,
        help="rad/s, one or per joint, used as given; when not given the description's less "
        "--velocity-margin",
    )
    p.add_argument(
        "--velocity-margin", type=float, default=limit("velocity_margin"),
        help="fraction of the description's velocity limits kept free",
    )  # fmt: skip
    p.add_argument(
        "--acceleration-limit", type=numbers, default=None,
        help="rad/s^2, one or per joint; when not given the velocity limit (with its margin) "
        f"reached from rest in {DEFAULT_ACCELERATION_TIME:g} s, e.g. 5.4 rad/s^2 for 3.15 rad/s "
        "(robot descriptions carry no acceleration limit)",
    )  # fmt: skip
    p.add_argument("--torque-limit", type=numbers, default=None, help="N m (nominal model)")
    p.add_argument(
        "--workspace", type=_box, action="append", default=None,
        help="FRAME:xlo,ylo,zlo:xhi,yhi,zhi box for a frame's origin (repeatable)",
    )  # fmt: skip
    p.add_argument(
        "--floor", type=float, default=limit("floor"),
        help="m: height, in the root frame, of the plane the robot is mounted on; no part of "
        "the arm comes within --clearance of it (the base and what only turns on a vertical "
        "first axis are not checked)",
    )  # fmt: skip
    p.add_argument("--no-floor", action="store_true", help="no mounting plane")
    p.add_argument(
        "--clearance", type=float, default=limit("clearance"),
        help="m kept to the floor and between links that are not adjacent",
    )  # fmt: skip
    p.add_argument(
        "--capsule-radius", type=float, default=limit("capsule_radius"),
        help="m: radius of the capsules along links without collision geometry in the "
        "description (links with some get the radius that holds it)",
    )  # fmt: skip
    p.add_argument(
        "--no-self-collision", action="store_true",
        help="do not keep the links apart (only the floor, if any)",
    )  # fmt: skip


def _limit_arg(values, n: int, name: str):
    if values is None:
        return None
    if len(values) not in (1, n):
        raise ValueError(f"--{name} takes 1 or {n} numbers, got {len(values)}")
    return values[0] if len(values) == 1 else values


def cmd_excite(args) -> int:
    """Run ``torchjfa excite`` (see `add_excite`)."""
    model = load_model(args.robot, args.friction)
    try:
        design = _design(args, model)
    except ValueError as exc:  # bad options or limits that cannot be met
        raise usage(exc) from None
    out = args.out
    design.write(out, plots=not args.no_plots, **written_as(args, args.robot))
    print(design.headline())
    print(f"wrote {out}/trajectory.npz, trajectory.csv, coefficients.json, report.md")
    return 0


def _design(args, model):
    """The `torchjfa.excitation.ExcitationDesign` the options ask for.

    Raises:
        ValueError: on bad options or limits that cannot be met.
    """
    from ..excitation import DEFAULT_RATE, design_excitation, limits_from_model
    from ..sim import DEFAULT_RATES

    n = model.n_dof
    rate = args.rate if args.rate is not None else DEFAULT_RATES.get(args.robot, DEFAULT_RATE)
    if not rate > 0:
        raise ValueError(f"--rate must be positive, got {rate}")
    if args.posture is not None and len(args.posture) != n:
        raise ValueError(f"--posture takes {n} numbers (joints {model.joint_names})")
    limits = limits_from_model(
        model,
        position_margin=args.position_margin,
        velocity_margin=args.velocity_margin,
        velocity=_limit_arg(args.velocity_limit, n, "velocity-limit"),
        acceleration=_limit_arg(args.acceleration_limit, n, "acceleration-limit"),
        torque=_limit_arg(args.torque_limit, n, "torque-limit"),
        workspace=args.workspace or (),
        floor=None if args.no_floor else args.floor,
        self_collision=not args.no_self_collision,
        clearance=args.clearance,
        capsule_radius=args.capsule_radius,
    )
    return design_excitation(
        model,
        limits,
        robot=args.robot,
        rate=rate,
        duration=args.duration,
        base_frequency=args.base_freq,
        harmonics=args.harmonics,
        posture=args.posture,
        criterion=args.criterion,
        n_grid=args.grid,
        n_starts=args.starts,
        optimizer=args.optimizer,
        max_iter=args.max_iter,
        polish_iter=args.polish_iter,
        polish_starts=args.polish_starts,
        seed=args.seed,
        progress=not args.quiet,
        payload=args.payload,
    )
