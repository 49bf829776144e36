"""``torchjfa excite``: design an optimal excitation and write it, its report and its plots.

    torchjfa excite ROBOT --duration 10 --base-freq 0.1 --harmonics 5 --out traj/
    torchjfa simulate head --trajectory traj/trajectory.npz --out log.csv

`add_parser` registers the subcommand on the ``torchjfa`` parser, `run` runs it with the
robot's `RigidBodyModel`; ``torchjfa simulate --trajectory`` tracks what it writes.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
from pathlib import Path

import numpy as np

from .._cli_identify import friction_terms
from ._geometry import DEFAULT_CAPSULE_RADIUS, DEFAULT_CLEARANCE
from ._information import CRITERIA
from ._limits import DEFAULT_ACCELERATION_TIME, DEFAULT_VELOCITY_MARGIN

__all__ = ["add_parser", "run"]

_DEFAULT_RATE = 200.0


def _numbers(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}"
        ) from None


def _box(text: str):
    from ._limits import WorkspaceBox

    parts = text.split(":")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected FRAME:xlo,ylo,zlo:xhi,yhi,zhi, got {text!r}")
    try:
        return WorkspaceBox(parts[0], _numbers(parts[1]), _numbers(parts[2]))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``excite`` subcommand to ``torchjfa``'s subparsers; returns its parser."""
    p = subparsers.add_parser(
        "excite",
        help="design an optimal excitation trajectory for identification",
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
    if p.formatter_class is argparse.HelpFormatter:  # keep a formatter the parent gives
        p.formatter_class = argparse.ArgumentDefaultsHelpFormatter  # show the defaults
    p.add_argument(
        "robot", help="URDF or MJCF file, or a shipped robot: panda, panda_arm, head, arm, ..."
    )
    p.add_argument("--out", default="traj", help="output folder")
    p.add_argument("--duration", type=float, default=10.0, help="s; whole periods of 1/base-freq")
    p.add_argument("--base-freq", type=float, default=0.1, help="base frequency f0, Hz")
    p.add_argument("--harmonics", type=int, default=5, help="harmonics per joint (>= 2)")
    p.add_argument(
        "--criterion", choices=CRITERIA, default="d+condition",
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
        help="output rate, Hz; when not given 420 for head, 480 for arm, else 200; the limits are "
        "checked at 10x",
    )  # fmt: skip
    p.add_argument(
        "--posture",
        type=_numbers,
        default=None,
        help="q0 per joint, rad (m); when not given the middle of the limits, moved to the "
        "nearest posture that keeps the arm 5 cm beyond --clearance from the floor",
    )
    _add_limits(p)
    p.add_argument("--starts", type=int, default=3, help="random starts")
    p.add_argument("--optimizer", choices=("lbfgs", "adam"), default="lbfgs", help="optimiser")
    p.add_argument(
        "--max-iter", type=int, default=50,
        help="iterations per start (and per exponent for --criterion condition)",
    )  # fmt: skip
    p.add_argument(
        "--polish-iter", type=int, default=200,
        help="d+condition: iterations per exponent of the condition number's polish",
    )  # fmt: skip
    p.add_argument(
        "--polish-starts", type=int, default=2,
        help="d+condition: how many of the best D-optimal starts are polished (each: one polish)",
    )  # fmt: skip
    p.add_argument("--grid", type=int, default=200, help="coarse grid points per period")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _add_limits(p: argparse.ArgumentParser) -> None:
    """The limits' and the safety checks' options of ``excite``."""
    p.add_argument("--position-margin", type=float, default=0.05, help="fraction of each range")
    p.add_argument(
        "--velocity-limit",
        type=_numbers,
        default=None,
        help="rad/s, one or per joint, used as given; when not given the description's less "
        "--velocity-margin",
    )
    p.add_argument(
        "--velocity-margin", type=float, default=DEFAULT_VELOCITY_MARGIN,
        help="fraction of the description's velocity limits kept free",
    )  # fmt: skip
    p.add_argument(
        "--acceleration-limit", type=_numbers, default=None,
        help="rad/s^2, one or per joint; when not given the velocity limit (with its margin) "
        f"reached from rest in {DEFAULT_ACCELERATION_TIME:g} s, e.g. 5.4 rad/s^2 for 3.15 rad/s "
        "(robot descriptions carry no acceleration limit)",
    )  # fmt: skip
    p.add_argument("--torque-limit", type=_numbers, default=None, help="N m (nominal model)")
    p.add_argument(
        "--workspace", type=_box, action="append", default=None,
        help="FRAME:xlo,ylo,zlo:xhi,yhi,zhi box for a frame's origin (repeatable)",
    )  # fmt: skip
    p.add_argument(
        "--floor", type=float, default=0.0,
        help="m: height, in the root frame, of the plane the robot is mounted on; no part of "
        "the arm comes within --clearance of it (the base and what only turns on a vertical "
        "first axis are not checked)",
    )  # fmt: skip
    p.add_argument("--no-floor", action="store_true", help="no mounting plane")
    p.add_argument(
        "--clearance", type=float, default=DEFAULT_CLEARANCE,
        help="m kept to the floor and between links that are not adjacent",
    )  # fmt: skip
    p.add_argument(
        "--capsule-radius", type=float, default=DEFAULT_CAPSULE_RADIUS,
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


def _table(model, traj, rate: float, duration: float) -> tuple[np.ndarray, dict]:
    t = np.arange(int(round(duration * rate))) / rate
    q, qd, qdd = traj.evaluate_numpy(t)
    return t, {"q": q, "qd": qd, "qdd": qdd}


def run(args, model) -> int:
    """Run ``torchjfa excite`` on ``model`` (the robot's `RigidBodyModel`).

    Raises:
        ValueError: on bad options or limits that cannot be met.
    """
    from ..sim import DEFAULT_RATES
    from ._limits import limits_from_model

    n = model.n_dof
    rate = args.rate if args.rate is not None else DEFAULT_RATES.get(args.robot, _DEFAULT_RATE)
    if not rate > 0:
        raise ValueError(f"--rate must be positive, got {rate}")
    posture = None
    if args.posture is not None:
        if len(args.posture) != n:
            raise ValueError(f"--posture takes {n} numbers (joints {model.joint_names})")
        posture = args.posture
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
    res, rnd, rnd_margins, info = _design(args, model, limits, rate, posture)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _write_trajectory(out, model, res.trajectory, rate, args.duration)
    summary = _summary(args, model, res, rnd_margins, info, rate)
    (out / "report.json").write_text(json.dumps(summary, indent=1))
    (out / "report.md").write_text(_markdown(summary, limits))
    if not args.no_plots:
        _plots(out, model, limits, res.trajectory, rnd, info, rate, args.duration)
    o, r = info["optimised"], info["random"]
    print(
        f"optimised a {args.duration:g} s excitation of {model.n_dof} joints in "
        f"{res.seconds:.1f} s: criterion {res.criterion} {o[res.criterion]:.4g} (random "
        f"{r[res.criterion]:.4g}), condition number {o['condition_number']:.4g} (random "
        f"{r['condition_number']:.4g}, {r['condition_number'] / o['condition_number']:.2f}x)"
    )
    print(f"wrote {out}/trajectory.npz, trajectory.csv, coefficients.json, report.md")
    return 0


def _design(args, model, limits, rate: float, posture):
    """``(res, rnd, rnd_margins, info)``: the optimised excitation (`optimize_excitation`'s
    result), a random one of the same band about the same posture for comparison, the random
    one's margins to the limits (``{"fraction": check_limits's, "physical":
    physical_margins'}``), and both trajectories' information (`trajectory_information`,
    name -> dict)."""
    from ._check import check_limits, physical_margins, trajectory_geometry
    from ._design import optimize_excitation, random_excitation, trajectory_information

    res = optimize_excitation(
        model,
        limits,
        duration=args.duration,
        base_frequency=args.base_freq,
        harmonics=args.harmonics,
        posture=posture,
        criterion=args.criterion,
        rate=rate,
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
    rnd = random_excitation(
        model, limits, base_frequency=args.base_freq, harmonics=args.harmonics, rate=rate,
        seed=args.seed, posture=res.trajectory.posture,
    )  # fmt: skip
    geometry = trajectory_geometry(model, rnd, limits)
    rnd_margins = {
        "fraction": check_limits(model, rnd, limits, rate=rate, raise_error=False,
                                 geometry=geometry),
        "physical": physical_margins(model, rnd, limits, rate=rate, geometry=geometry),
    }  # fmt: skip
    n_info = max(args.grid, 1000)
    info = {
        "optimised": trajectory_information(model, res.trajectory, res.basis, n_grid=n_info),
        "random": trajectory_information(model, rnd, res.basis, n_grid=n_info),
    }
    return res, rnd, rnd_margins, info


def _write_trajectory(out: Path, model, traj, rate: float, duration: float) -> None:
    """``trajectory.npz`` (the `FourierTrajectory` and its samples), ``trajectory.csv`` (t, q,
    qd, qdd at ``rate`` Hz over ``duration`` s) and ``coefficients.json`` into ``out``."""
    t, sig = _table(model, traj, rate, duration)
    names = model.joint_names
    traj.save(out / "trajectory.npz", t=t, joint_names=np.array(names), rate=rate, **sig)
    header = ["t"] + [f"{k}_{j}" for k in ("q", "qd", "qdd") for j in names]
    cols = np.column_stack([t] + [sig[k] for k in ("q", "qd", "qdd")])
    np.savetxt(out / "trajectory.csv", cols, delimiter=",", header=",".join(header), comments="")
    coef = {
        "form": "q_j(t) = q0_j + sum_k b_jk/(w k) + a_jk/(w k) sin(w k t) - b_jk/(w k) cos(w k t), "
        "w = 2 pi base_frequency",
        "base_frequency_hz": traj.base_frequency,
        "joint_names": list(names),
        "posture": traj.posture.tolist(),
        "a": traj.a.tolist(),
        "b": traj.b.tolist(),
    }
    (out / "coefficients.json").write_text(json.dumps(coef, indent=1))


def _summary(args, model, res, rnd_margins, info, rate: float) -> dict:
    """``report.json``'s content: the command, the design's settings and both trajectories'
    numbers (their singular values left out)."""
    return {
        "robot": args.robot,
        "command": "torchjfa " + " ".join(shlex.quote(a) for a in getattr(args, "argv", [])),
        "payload": args.payload,
        "criterion": res.criterion,
        "duration_s": args.duration,
        "base_frequency_hz": args.base_freq,
        "harmonics": args.harmonics,
        "rate_hz": rate,
        "identifiable_directions": int(res.basis.shape[1]),
        "n_params": model.n_params,
        "optimisation_seconds": res.seconds,
        "start_values": res.start_values,
        "shrink": res.shrink,
        "margins": {"optimised": res.margins, "random": rnd_margins["fraction"]},
        "physical_margins": {
            "optimised": res.physical_margins,
            "random": rnd_margins["physical"],
        },  # fmt: skip
        "geometry": res.geometry,
        "posture": res.trajectory.posture.tolist(),
        "posture_moved": res.posture_moved,
        "optimised": {k: v for k, v in info["optimised"].items() if k != "singular_values"},
        "random": {k: v for k, v in info["random"].items() if k != "singular_values"},
    }


def _markdown(s: dict, limits) -> str:
    o, r = s["optimised"], s["random"]
    lines = [
        f"# Excitation for {s['robot']}",
        "",
        f"`{s['command']}`",
        "",
        f"{s['duration_s']:g} s, base frequency {s['base_frequency_hz']:g} Hz, "
        f"{s['harmonics']} harmonics, output at {s['rate_hz']:g} Hz (limits checked at "
        f"{10 * s['rate_hz']:g} Hz); {s['identifiable_directions']} identifiable directions of "
        f"{s['n_params']} parameters; optimised in {s['optimisation_seconds']:.1f} s "
        f"(starts reached {', '.join(f'{v:.4g}' for v in s['start_values'])}; shrunk x"
        f"{s['shrink']:.3f} to hold the limits on the fine grid).",
        "",
        "| | optimised | random sum of sinusoids | ratio |",
        "| --- | ---: | ---: | ---: |",
        f"| condition number of Y V | {o['condition_number']:.4g} | "
        f"{r['condition_number']:.4g} | {r['condition_number'] / o['condition_number']:.2f} |",
    ]
    for k, label in (("d", "-log det M / r"), ("condition", "log cond"), ("e", "-log lambda_min")):
        lines.append(f"| {label} (`{k}`) | {o[k]:.4g} | {r[k]:.4g} | |")
    lines += _margin_lines(s, limits)
    return "\n".join(lines) + "\n"


def _margin_lines(s: dict, limits) -> list[str]:
    """The report's margins: per limit in physical units, per joint the peaks, the geometry."""
    phys, rnd = s["physical_margins"]["optimised"], s["physical_margins"]["random"]
    lines = ["", f"Smallest margin to each limit on the {10 * s['rate_hz']:g} Hz grid (position: "
             "to the limits with their margin; floor and collision: beyond the distance "
             "required there):", "", "| limit | margin | where | t [s] | random |",
             "| --- | ---: | --- | ---: | ---: |"]  # fmt: skip
    for kind in s["margins"]["optimised"]:
        e, r = phys.get(kind, {}), rnd.get(kind, {})
        margin = f"{e.get('margin', math.nan):.3g} {e.get('unit', '')}"
        if "required" in e:
            apart = (">= " if e.get("at_least") else "") + f"{e['distance']:.3g} m"
            margin += f" (apart {apart}, {e['required']:.3g} m required)"
        lines.append(f"| {kind} | {margin} | {e.get('where', '')} | {e.get('t', math.nan):.3f} | "
                     f"{r.get('margin', math.nan):.3g} {r.get('unit', '')} |")  # fmt: skip
    lines += ["", "Limits (position with the margin) and the optimised motion's peaks:", "",
              "| joint | low | high | peak / limit velocity | peak / limit acceleration | "
              "peak / limit torque |", "| --- | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for j, name in enumerate(limits.joint_names):
        pk = phys["joints"][name]
        torque = f"{pk['torque']:.4g} / " if "torque" in pk else ""
        lines.append(
            f"| {name} | {limits.position_low[j]:.4g} | {limits.position_high[j]:.4g} | "
            f"{pk['velocity']:.4g} / {limits.velocity[j]:.4g} | {pk['acceleration']:.4g} / "
            f"{limits.acceleration[j]:.4g} | {torque}{limits.torque[j]:.4g} |"
        )
    units = "units: rad, rad/s, rad/s^2, N m (prismatic joints: m, m/s, m/s^2, N)"
    lines += ["", units]
    if s["geometry"]:
        moved = (
            " (the middle of the limits, moved clear of the floor)" if s["posture_moved"] else ""
        )
        lines += ["", f"Posture{moved}: {', '.join(f'{v:.4g}' for v in s['posture'])}", ""]
        lines += [f"- {line}" for line in s["geometry"]]
    return lines


def _plots(out, model, limits, traj, rnd, info, rate, duration) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(int(round(duration * rate))) / rate
    qo, qdo, _ = traj.evaluate_numpy(t)
    qr, qdr, _ = rnd.evaluate_numpy(np.mod(t, rnd.period))
    n = model.n_dof
    fig, axes = plt.subplots(n, 2, figsize=(11, 1.6 * n + 1), sharex=True, squeeze=False)
    for j in range(n):
        ax = axes[j, 0]
        ax.plot(t, qo[:, j], "C0", lw=1.2, label="optimised")
        ax.plot(t, qr[:, j], "C1--", lw=1.0, label="random")
        for v in (limits.position_low[j], limits.position_high[j]):
            ax.axhline(v, color="k", lw=0.8, ls=":")
        ax.set_ylabel(model.joint_names[j], fontsize=7)
        ax = axes[j, 1]
        ax.plot(t, qdo[:, j], "C0", lw=1.2)
        ax.plot(t, qdr[:, j], "C1--", lw=1.0)
        if np.isfinite(limits.velocity[j]):
            for v in (-limits.velocity[j], limits.velocity[j]):
                ax.axhline(v, color="k", lw=0.8, ls=":")
    axes[0, 0].set_title("position (dotted: limits with the margin)")
    axes[0, 1].set_title("velocity (dotted: limits)")
    axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "trajectory.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    for key, style in (("optimised", "C0o-"), ("random", "C1s--")):
        sv = info[key]["singular_values"]
        ax.semilogy(np.arange(1, sv.size + 1), sv, style, ms=3,
                    label=f"{key} (cond {info[key]['condition_number']:.3g})")  # fmt: skip
    ax.set_xlabel("index")
    ax.set_ylabel("singular value of Y V / sqrt(N)")
    ax.set_title("base regressor")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "singular_values.png", dpi=110)
    plt.close(fig)
