"""The ``torchjfa`` command: identify a robot from its logs, simulate logs, evaluate a model.

    torchjfa simulate head --out log.csv
    torchjfa identify head log.csv --estimator bayes-jfa --friction viscous,coulomb --out result/
    torchjfa identify robot.urdf run1.csv run2.csv --drive-gains 10,10.7,8.5,9,9.5,10.1
    torchjfa evaluate result/model.npz run3.csv --out evaluation/
    torchjfa evaluate result/model.npz --robot head
    torchjfa simulate robot.urdf --trajectory traj/trajectory.npz --frictionloss 0.3 --out log.csv

A thin shell over `torchjfa.identify` (read and prepare the log, moments, estimator,
projection, report), `torchjfa.sim` (simulate, evaluate: these need MuJoCo; their
sub-commands are in `torchjfa._cli_simulate`) and
`torchjfa.excitation` (excite). Bad input
(a missing column, an unknown joint, NaN rows, time going backwards, too few samples, a robot
file that does not parse) ends with one line on stderr and exit status 2, not a traceback;
``--debug`` shows the traceback. The ``identify`` sub-command (its parser and options) is in
`torchjfa._cli_identify`; ``excite``'s in `torchjfa.excitation._cli`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ._cli_identify import add_identify, add_option
from ._cli_identify import identify_options as identify_options
from .estimators import available as _estimators
from .identification._options import IdentificationError

__all__ = ["main", "ESTIMATORS"]

ESTIMATORS = _estimators()  # the library's; a registered one is taken by torchjfa.identify

#: bad input from the user: printed as one line, exit status 2 (the flow's own error)
UsageError = IdentificationError


class _HelpFormatter(argparse.HelpFormatter):
    """``--help`` with every option's default, ``(default: X)``, after its help text (flags,
    which are off unless given, and options without a default, say nothing)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (
            not action.option_strings
            or action.nargs == 0
            or default is None
            or default is argparse.SUPPRESS
            or "%(default)" in text
        ):
            return text
        if isinstance(default, (tuple, list)):
            shown = ",".join(map(str, default)) or "none"
        elif isinstance(default, float):
            shown = f"{default:g}"
        else:
            shown = str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class _Parser(argparse.ArgumentParser):
    """An `argparse.ArgumentParser` whose help shows the defaults; its subcommands' parsers are
    of the same class (``add_subparsers`` makes them so), and so show theirs."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)


# ------------------------------------------------------------------------------ helpers
def load_model(robot: str, friction: tuple[str, ...] | None = None):
    """A `RigidBodyModel` from a URDF/MJCF path, a shipped robot or a simulated robot name
    (`torchjfa.identification.load_model`)."""
    from .identification import load_model as load

    return load(robot, friction)


# ------------------------------------------------------------------------------ simulate
def cmd_simulate(args) -> int:
    """``torchjfa simulate`` (`torchjfa._cli_simulate`)."""
    from ._cli_simulate import cmd_simulate as run

    return run(args)


# ------------------------------------------------------------------------------ excite
def cmd_excite(args) -> int:
    from .excitation._cli import run

    model = load_model(args.robot, args.friction)
    try:
        return run(args, model)
    except ValueError as exc:  # bad options or limits that cannot be met
        raise UsageError(" ".join(str(exc).split())) from None


# ------------------------------------------------------------------------------ evaluate
def cmd_evaluate(args) -> int:
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
    from .identification import evaluate

    ev = evaluate(
        args.model, args.logs, _reading(args), cutoff_hz=args.cutoff, rollouts=args.rollouts
    )
    for line in ev.lines():
        print(line)
    paths = ev.write(args.out, plots=not args.no_plots)
    print(
        f"{len(ev.logs)} log(s), prepared at {ev.cutoff_hz:g} Hz, judged against the measured "
        f"torque (unfiltered); written: {paths['json']}"
    )
    return 0


def _evaluate_simulated(args) -> int:
    """``torchjfa evaluate MODEL --robot ROBOT`` (`torchjfa._cli_simulate`)."""
    from ._cli_simulate import evaluate_simulated

    return evaluate_simulated(args)


# ------------------------------------------------------------------------------ payload
def cmd_payload(args) -> int:
    from .identification._payload import identify_payload

    if args.mass is not None:
        return _drive_gains(args)
    payload = identify_payload(
        args.model, args.loaded, link=args.link, unloaded=args.unloaded, options=_reading(args),
        bounds=args.bounds,
    )  # fmt: skip
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "payload.json").write_text(json.dumps(payload.summary(), indent=1))
    (out / "payload.md").write_text(payload.markdown())
    from .identification._payload import write_with_payload

    described = None
    try:
        described = write_with_payload(args.model, payload, out)
    except (UsageError, ValueError) as exc:
        print(f"warning: the description with the payload was not written: {exc}", file=sys.stderr)
    print(payload.markdown(brief=True))
    print(f"written: {out / 'payload.json'}, {out / 'payload.md'}"
          + (f", {described}" if described is not None else ""))  # fmt: skip
    return 0


def _drive_gains(args) -> int:
    """``torchjfa payload ... --mass KG --unloaded LOG``: the drive gains (drive_gains.json)."""
    from .identification import identify_drive_gains

    if not args.unloaded:
        raise UsageError("--mass identifies the drive gains and needs --unloaded runs too")
    found = identify_drive_gains(
        args.model, args.loaded, args.unloaded, link=args.link, mass=args.mass,
        options=_reading(args),
    )  # fmt: skip
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "drive_gains.json").write_text(json.dumps(found.summary(), indent=1))
    print(f"drive gains from a {args.mass:g} kg payload on {args.link} (spreads: jackknife):")
    print(found.table())
    gains = ",".join(f"{g:.6g}" for g in found.gains.tolist())
    print(f"read logs with them: --drive-gains {gains}; written: {out / 'drive_gains.json'}")
    return 0


# ------------------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    """The ``torchjfa`` parser: ``identify``, ``simulate``, ``excite`` and ``evaluate``, each
    sub-command's parser set to run its ``cmd_*``."""
    parser = _Parser(
        prog="torchjfa",
        description="Probabilistic identification of robot dynamics (Bayesian joint factor "
        "analysis, physically consistent parameters).",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    add_identify(sub)
    _add_simulate(sub)
    from .excitation._cli import add_parser as add_excite_parser

    add_excite_parser(sub).set_defaults(func=cmd_excite)

    _add_evaluate(sub)
    _add_payload(sub)
    from ._cli_refine import add_refine, cmd_refine

    add_refine(sub, _add_reading).set_defaults(func=lambda args: cmd_refine(args, _reading))
    return parser


def _add_simulate(sub) -> argparse.ArgumentParser:
    """The ``simulate`` sub-command's parser (runs `cmd_simulate`)."""
    from ._cli_simulate import add_simulate

    p = add_simulate(sub)
    p.set_defaults(func=cmd_simulate)
    return p


def _add_evaluate(sub) -> argparse.ArgumentParser:
    """The ``evaluate`` sub-command's parser (runs `cmd_evaluate`)."""
    p = sub.add_parser(
        "evaluate",
        help="evaluate an identified model on logs (or on a simulated robot)",
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
    p.add_argument("--out", default="evaluation", help="output folder (with logs)")
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
    _add_reading(p)
    p.add_argument(
        "--robot",
        default=None,
        metavar="ROBOT",
        help="evaluate in simulation instead of on logs: head, arm, a shipped description "
        "or a URDF or MJCF file",
    )
    p.add_argument("--n-samples", type=int, default=8400, help="samples of the test trajectory")
    p.add_argument("--seed", type=int, default=100, help="seed of the test trajectory")
    p.add_argument("--no-control", action="store_true", help="skip the control run")
    p.add_argument(
        "--control-seconds", type=float, default=4.0, help="duration of the control run, s"
    )
    p.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    from ._cli_simulate import add_simulation_options

    add_simulation_options(p)
    p.set_defaults(func=cmd_evaluate)
    return p


def _add_payload(sub) -> argparse.ArgumentParser:
    """The ``payload`` sub-command's parser (runs `cmd_payload`)."""
    p = sub.add_parser(
        "payload",
        help="identify a payload fixed to a link from loaded logs",
        description="The mass, centre of mass and inertia of a rigid body fixed to a link, from "
        "logs with it mounted and the identified robot (model.npz), or from loaded and "
        "unloaded runs together (--unloaded: the robot's parameters are fitted again, so what "
        "its model gets wrong cancels); physically consistent; payload.json in --out.",
    )
    p.add_argument("model", help="model.npz written by identify")
    p.add_argument("loaded", nargs="+", metavar="LOG", help="logs with the payload mounted")
    p.add_argument("--link", required=True, help="the frame the payload is fixed to")
    p.add_argument("--unloaded", nargs="+", default=None, metavar="LOG", help="logs without it")
    p.add_argument(
        "--mass",
        type=float,
        default=None,
        metavar="KG",
        help="the payload's known mass: identify the per-joint drive gains (N m/A; torque scales "
        "for torque logs) instead, with the robot fitted again; needs --unloaded; the logs are "
        "read with --drive-gains as the nominal gains; writes drive_gains.json",
    )
    p.add_argument(
        "--bounds",
        default=None,
        metavar="REGION",
        help="the region of the link's frame the payload lies in, metres: sphere:R (about the "
        "link's origin), sphere:X,Y,Z,R or box:XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX",
    )
    p.add_argument("--out", default="payload", help="output folder")
    _add_reading(p)
    p.set_defaults(func=cmd_payload)
    return p


def _add_reading(p: argparse.ArgumentParser) -> None:
    """The reading options of `torchjfa.identification.Options` (columns, time scale, drive
    gains, ROS topic and effort), as ``identify`` has them."""
    from .identification._options import GROUPS, cli_fields

    group = p.add_argument_group(GROUPS["reading"])
    for f in cli_fields():
        if f.metadata["group"] == "reading" and f.name != "max_seconds":
            add_option(group, f)


def _reading(args):
    """The `torchjfa.identification.Options` of the reading flags `_add_reading` added."""
    from .identification import Options
    from .identification._options import cli_fields

    fields = [f for f in cli_fields() if f.metadata["group"] == "reading"]
    return Options(**{f.name: getattr(args, f.name) for f in fields if hasattr(args, f.name)})


def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 bad input)."""
    from .data import LogError

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = argv
    try:
        return int(args.func(args) or 0)
    except (UsageError, LogError, FileNotFoundError) as exc:
        if args.debug:
            raise
        print(f"torchjfa {args.command}: error: {exc}", file=sys.stderr)
        return 2


def _entry() -> None:
    sys.exit(main())
