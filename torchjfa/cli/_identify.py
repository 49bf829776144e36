"""``torchjfa identify``: its parser, generated from `torchjfa.identification.Options`, and the
command.

`add_identify` adds the sub-command: one flag per field of `Options` and `Compute`
(`torchjfa.cli._common.add_option`), grouped as `GROUPS` says. `identify_options` turns the
arguments back into `Options`; `cmd_identify` runs `torchjfa.identify` and writes its report.
"""

from __future__ import annotations

import argparse
import sys

from ..identification._options import GROUPS, Compute, Options, cli_fields
from ._common import COMMANDS, UsageError, add_option, add_output, command_line, written_as

__all__ = ["add_identify", "cmd_identify", "identify_options"]

#: ``--smoke``: the first seconds of the log only
SMOKE_SECONDS = 12.0
#: the Bayesian JFA shortcuts: flag -> estimator option
_SHORTCUTS = {"max_iter": "--max-iter", "ard": "--ard"}


def identify_options(args) -> Options:
    """The `torchjfa.identification.Options` that ``torchjfa identify``'s arguments give.

    Raises:
        IdentificationError: on options that do not go together (an estimator option the
            estimator does not take, say).
    """
    values = {f.name: getattr(args, f.name) for f in cli_fields()}
    compute = {k: values.pop(k) for k in list(values) if k in Compute.__dataclass_fields__}
    estimator_options = dict(values.pop("estimator_options"))
    for key, flag in _SHORTCUTS.items():
        value = getattr(args, key)
        if value is not None:
            if key in estimator_options:
                raise UsageError(f"{flag} and --estimator-options {key}=... both set {key}")
            estimator_options[key] = value
    if args.smoke:
        values["max_seconds"] = values["max_seconds"] or SMOKE_SECONDS
    return Options(
        **values,
        estimator_options=estimator_options,
        compute=Compute(progress=not args.quiet, **compute),
    )


def cmd_identify(args) -> int:
    import warnings

    from ..identification import IdentificationWarning, LeggedIdentification, identify

    command = command_line(args)
    options = identify_options(args)
    if not options.project and any(a.startswith("--description-prior") for a in args.argv):
        raise UsageError("--description-prior acts in the projection: drop --no-project")
    with warnings.catch_warnings():  # printed below, after the report's path
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = identify(
            args.robot,
            args.log,
            options,
            validation_log=args.validation_log,
            settings={"command": command},
        )
    if isinstance(ident, LeggedIdentification):
        return _legged_done(ident, args)
    paths = ident.write(
        args.out,
        plots=not args.no_plots,
        appendix=args.appendix,
        **written_as(args, args.robot, *args.log, *(args.validation_log or ())),
    )
    for line in ident.headline():
        print(line)
    est = ident.result.estimator
    if not getattr(est, "converged_", True):
        print(
            f"warning: {type(est).__name__} stopped at its iteration limit before its "
            f"stopping rule held ({est.stop_reason_}); compare the held-out errors with "
            "--estimator ols, or raise --max-iter",
            file=sys.stderr,
        )
    print(f"report: {paths['markdown']}")
    for w in ident.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if ident.problem():
        raise UsageError(f"{ident.problem()} (report written to {paths['markdown']})")
    return 0


def _legged_done(ident, args) -> int:
    """Write a floating-base identification's report and print its headline."""
    if args.appendix:
        raise UsageError("--appendix applies to fixed-base robots; report.json holds every number")
    paths = ident.write(
        args.out,
        plots=not args.no_plots,
        **written_as(args, args.robot, *args.log, *(args.validation_log or ())),
    )
    for line in ident.headline():
        print(line)
    print(f"report: {paths['markdown']}")
    for w in ident.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def add_identify(sub) -> argparse.ArgumentParser:
    """Add the ``identify`` sub-command to ``sub`` (the ``add_subparsers`` of the ``torchjfa``
    parser); returns its parser, which runs `cmd_identify`."""
    p = sub.add_parser(
        "identify",
        help=COMMANDS["identify"],
        description="Read joint logs (CSV, NPZ, Parquet, ROS bags), drop the standing still at "
        "their ends, filter and differentiate each, identify the rigid-body and friction "
        "parameters from all of them, project them onto physically consistent ones, and write "
        "the model, tables, figures and a Markdown report. Every option is a field of "
        "torchjfa.Options (the same defaults from Python). A floating-base robot (a legged "
        "robot, a humanoid; logs with its base pose and contacts) is identified from its "
        "contact equations: see the floating-base options.",
    )
    p.add_argument(
        "robot",
        help="URDF or MJCF file, or a shipped robot: panda, panda_arm, branched_tree, head, arm",
    )
    p.add_argument(
        "log",
        nargs="+",
        help="the logs (one identification from all): .csv, .npz or .parquet with columns t, "
        "q_<joint>, [qd_<joint>], tau_<joint> (or motor currents i_<joint> with "
        "--drive-gains), or ROS bags (.bag, .mcap, .db3, a bag folder); for a floating-base "
        "robot also base_x..base_qw, contact_<frame> and f_<frame>_x/_y/_z",
    )
    add_output(p, default="result", what="the report, the model, its description and figures")
    p.add_argument(
        "--validation-log",
        nargs="+",
        default=None,
        metavar="LOG",
        help="hold out these logs instead of the end of each log",
    )
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument(
        "--appendix",
        action="store_true",
        help="end report.md with the long tables (every parameter, the base-parameter "
        "combinations, each log, each body); they are in parameters.csv and report.json anyway",
    )
    p.add_argument("--smoke", action="store_true",
                   help=f"quick check: the first {SMOKE_SECONDS:g} s only")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    groups = {key: p.add_argument_group(title) for key, title in GROUPS.items()}
    for f in cli_fields():
        add_option(groups[f.metadata["group"]], f)
    est = groups["estimator"]
    est.add_argument("--max-iter", type=int, default=None,
                     help="shortcut for --estimator-options max_iter=N (JFA, Bayesian JFA)")  # fmt: skip
    est.add_argument(
        "--ard",
        choices=("shared", "output"),
        default=None,
        help="shortcut for --estimator-options ard=...: Bayesian JFA's relevance prior on both "
        "loadings (the paper's) or on the output loading alone",
    )
    p.set_defaults(func=cmd_identify)
    return p
