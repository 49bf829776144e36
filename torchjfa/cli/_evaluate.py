"""``torchjfa evaluate``: an identified model judged on logs it was not identified from
(`torchjfa.identification.evaluate`), or on a simulated robot (`torchjfa.sim.evaluate_simulated`).

    torchjfa evaluate result/model.npz run3.csv --out evaluation/
    torchjfa evaluate result/model.npz --robot head
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ._common import (
    COMMANDS,
    UsageError,
    add_output,
    add_reading,
    default_of,
    reading,
    usage,
    written_as,
)
from ._simulate import add_simulation_options, simulated_robot

__all__ = ["add_evaluate", "cmd_evaluate"]


def add_evaluate(sub) -> argparse.ArgumentParser:
    """The ``evaluate`` sub-command's parser (runs `cmd_evaluate`)."""
    from ..sim import evaluate_simulated

    p = sub.add_parser(
        "evaluate",
        help=COMMANDS["evaluate"],
        description="Judge an identified model on logs it was not identified from: each log "
        "read as identify reads it, its rest at the ends dropped, prepared at the model's own "
        "cut-off (or --cutoff), and the predicted torques compared with the measured, "
        "unfiltered torques; per-joint RMS and nMSE beside the description's, a figure per "
        "log and evaluation.json. With --robot ROBOT instead (head, arm, a shipped "
        "description or a URDF or MJCF file, simulated as torchjfa simulate does): the "
        "torques of a fresh noiseless trajectory of the simulated robot and computed-torque "
        "control with the model in MuJoCo.",
    )
    p.add_argument("model", help="model.npz written by identify")
    p.add_argument(
        "logs", nargs="*", metavar="LOG", help="logs to judge the model on (as identify reads)"
    )
    add_output(p, default="evaluation", what="with logs: the errors and figures")
    p.add_argument(
        "--cutoff",
        type=float,
        default=None,
        metavar="HZ",
        help="prepare the logs at this cut-off (default: the model's own)",
    )
    p.add_argument("--no-plots", action="store_true", help="write no figures (with logs)")
    p.add_argument(
        "--rollouts",
        action="store_true",
        help="with logs: also roll the identified model (its MJCF) and the description out in "
        "MuJoCo from measured states under the measured torques, open loop, over 50, 200 and "
        "500 ms, and compare positions and velocities with the log's",
    )
    add_reading(p)
    p.add_argument(
        "--robot",
        default=None,
        metavar="ROBOT",
        help="evaluate in simulation instead of on logs: head, arm, a shipped description "
        "or a URDF or MJCF file",
    )
    p.add_argument("--n-samples", type=int, default=default_of(evaluate_simulated, "n_samples"),
                   help="samples of the test trajectory")  # fmt: skip
    p.add_argument("--seed", type=int, default=default_of(evaluate_simulated, "seed"),
                   help="seed of the test trajectory")  # fmt: skip
    p.add_argument("--no-control", action="store_true", help="skip the control run")
    p.add_argument(
        "--control-seconds",
        type=float,
        default=default_of(evaluate_simulated, "control_seconds"),
        help="duration of the control run, s",
    )
    p.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_simulation_options(p)
    p.set_defaults(func=cmd_evaluate)
    return p


def cmd_evaluate(args) -> int:
    """Run ``torchjfa evaluate`` (see `add_evaluate`)."""
    if args.logs:
        if args.robot is not None:
            raise UsageError("give logs or --robot (a simulated robot), not both")
        return _evaluate_logs(args)
    if args.robot is None:
        raise UsageError(
            "give the logs to evaluate on, or --robot ROBOT (head, arm, or a URDF or MJCF "
            "description) to evaluate the model in simulation"
        )
    return _evaluate_simulated(args)


def _evaluate_logs(args) -> int:
    """``torchjfa evaluate MODEL LOG ...``: the model judged on real logs."""
    from ..dynamics import FloatingBaseModel
    from ..identification import evaluate
    from ..identification._prepare import identified_model

    ident = identified_model(args.model)
    if isinstance(ident.model, FloatingBaseModel):
        return _evaluate_legged(args, ident)

    ev = evaluate(
        args.model, args.logs, reading(args), cutoff_hz=args.cutoff, rollouts=args.rollouts
    )
    for line in ev.lines():
        print(line)
    paths = ev.write(
        args.out,
        plots=not args.no_plots,
        **written_as(args, args.model, *args.logs),
    )
    print(
        f"{len(ev.logs)} log(s), prepared at {ev.cutoff_hz:g} Hz, judged against the measured "
        f"torque (unfiltered); written: {paths['json']}"
    )
    return 0


def _evaluate_legged(args, ident) -> int:
    """``torchjfa evaluate MODEL LOG ...`` of a floating-base model on legged logs."""
    from ..identification import evaluate_legged

    if args.rollouts:
        raise UsageError("--rollouts is for fixed-base robots")
    ev = evaluate_legged(ident, args.logs, reading(args), cutoff_hz=args.cutoff)
    for line in ev.lines():
        print(line)
    paths = ev.write(args.out, **written_as(args, args.model, *args.logs))
    print(f"{len(ev.logs)} log(s), prepared at {ev.cutoff_hz:g} Hz; written: {paths['json']}")
    return 0


def _evaluate_simulated(args) -> int:
    """``torchjfa evaluate MODEL --robot ROBOT``: the torques of a fresh noiseless trajectory
    of the simulated robot, and computed-torque control with the model in MuJoCo."""
    from ..identification._prepare import identified_model
    from ..sim import evaluate_simulated

    ident = identified_model(args.model)
    robot = simulated_robot(args)
    try:
        found = evaluate_simulated(
            ident.model,
            ident.theta,
            robot,
            n_samples=args.n_samples,
            seed=args.seed,
            control_seconds=None if args.no_control else args.control_seconds,
            progress=not args.quiet,
        )
    except ValueError as exc:
        raise usage(exc) from None
    for line in found.lines():
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(found.summary(), indent=1))
    return 0
