"""``torchjfa identify``: its parser, its options and the command.

`add_identify` adds the sub-command to ``torchjfa``'s parser (`torchjfa.cli.build_parser`);
`identify_options` turns its arguments into `torchjfa.identification.Options`; `cmd_identify`
runs it. `torchjfa.cli` re-exports `identify_options`; import it from there.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

from .estimators import available as _estimators
from .identification._options import AUTO_BIAS_REFITS, Options, joint_terms
from .identification._options import IdentificationError as UsageError

__all__ = ["add_identify", "cmd_identify", "identify_options"]


# ------------------------------------------------------------------------------ argument types
def friction_terms(text: str) -> tuple[str, ...]:
    """``--friction``: `torchjfa.identification.joint_terms` of the text, as an argument type."""
    try:
        return joint_terms(text)
    except UsageError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _columns(text: str | None) -> dict[str, str] | None:
    """``ours=theirs,...`` or a JSON file/object mapping the library's names to the log's."""
    if not text:
        return None
    if os.path.isfile(text):
        text = Path(text).read_text()
    text = text.strip()
    if text.startswith("{"):
        try:
            mapping = json.loads(text)
        except json.JSONDecodeError as exc:
            raise UsageError(f"--columns: not valid JSON: {exc}") from None
    else:
        mapping = {}
        for item in text.split(","):
            if "=" not in item:
                raise UsageError(f"--columns: expected ours=theirs pairs, got {item!r}")
            k, v = item.split("=", 1)
            mapping[k.strip()] = v.strip()
    if not isinstance(mapping, dict):
        raise UsageError("--columns must map the library's column names to the log's")
    return {str(k): str(v) for k, v in mapping.items()}


def _period(text: str):
    if text in ("auto", "none"):
        return None if text == "none" else "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 'auto', 'none' or seconds, got {text!r}"
        ) from None


def _auto_or(what: str, *, zero: bool):
    """An argparse type: ``"auto"`` or a finite number > 0 (>= 0 with ``zero``); the error
    says ``expected 'auto' or <what>``."""

    def parse(text: str):
        if text == "auto":
            return text
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not ((value >= 0) if zero else (value > 0)) or value == float("inf"):
            raise argparse.ArgumentTypeError(f"expected 'auto' or {what}, got {text!r}")
        return value

    return parse


_coulomb_velocity = _auto_or("a smoothing velocity >= 0 in rad/s", zero=True)
_cutoff = _auto_or("a positive cut-off in Hz", zero=False)
_prior_weight = _auto_or("a weight >= 0", zero=True)  # --description-prior


def _skip(text: str):
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or seconds, got {text!r}") from None


# ------------------------------------------------------------------------------ identify
def _description_prior(value):
    """``--description-prior``: not given -> ``"auto"`` (`Options`' default; none with
    ``--no-project``, whose projection is off), 0 -> None (off), else the value."""
    if value is None:
        return "auto"
    return None if value == 0 else value


def identify_options(args):
    """The `torchjfa.identification.Options` that ``torchjfa identify``'s arguments give."""
    from .identification import Compute, Options

    estimator_options = {}
    if args.estimator in ("bayes-jfa", "jfa"):
        estimator_options["max_iter"] = args.max_iter
    if args.estimator == "bayes-jfa":
        estimator_options["ard"] = args.ard
    return Options(
        friction=args.friction,
        columns=_columns(args.columns),
        time_scale=args.time_scale,
        drop_nan=args.drop_nan,
        max_seconds=args.smoke_seconds if args.smoke else None,
        cutoff=args.cutoff,
        coulomb_velocity=args.coulomb_velocity,
        filter=args.filter,
        velocity=args.velocity,
        period=args.period,
        skip_start=args.skip_start,
        decimate=args.decimate,
        validation=args.validation,
        estimator=args.estimator,
        estimator_options=estimator_options,
        weighting=args.weighting,
        input_noise=args.input_noise,
        jackknife=args.jackknife,
        bias_correction=args.bias_correction,
        project=not args.no_project,
        parametrization=args.parametrization,
        description_prior=_description_prior(args.description_prior),
        compute=Compute(progress=not args.quiet, compiled=args.compiled),
    )


def cmd_identify(args) -> int:
    import warnings

    from .identification import IdentificationWarning, identify

    if args.no_project and args.description_prior is not None:
        raise UsageError("--description-prior acts in the projection: drop --no-project")
    command = "torchjfa " + " ".join(shlex.quote(a) for a in args.argv)
    with warnings.catch_warnings():  # printed below, after the report's path
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = identify(
            args.robot,
            args.log,
            identify_options(args),
            validation_log=args.validation_log,
            settings={"command": command},
        )
    paths = ident.write(args.out, plots=not args.no_plots)
    for line in ident.headline():
        print(line)
    est = ident.result.estimator
    if not getattr(est, "converged_", True):
        print(
            f"warning: {type(est).__name__} stopped at --max-iter {args.max_iter} before its "
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


# ------------------------------------------------------------------------------ parser
def add_identify(sub) -> argparse.ArgumentParser:
    """Add the ``identify`` sub-command to ``sub`` (the ``add_subparsers`` of `torchjfa.cli`);
    returns its parser, which runs `cmd_identify`."""
    p = sub.add_parser(
        "identify",
        help="identify a robot's parameters from a log and write a report",
        description="Read a joint log (CSV, NPZ, Parquet), filter and differentiate it, "
        "identify the rigid-body and friction parameters, project them onto physically "
        "consistent ones, and write the model, tables, figures and a Markdown report.",
    )
    p.add_argument(
        "robot",
        help="URDF or MJCF file, or a shipped robot: panda, panda_arm, branched_tree, head, arm",
    )
    p.add_argument(
        "log",
        help="the log: .csv, .npz or .parquet with columns t, q_<joint>, [qd_<joint>], tau_<joint>",
    )
    p.add_argument("--out", default="result", help="output folder")
    p.add_argument(
        "--estimator",
        choices=_estimators(),
        default="ols",
        help="the estimator (OLS by default: on the real Panda log of docs/real-robot.md it "
        "predicts held-out torques better than Bayesian JFA)",
    )
    p.add_argument(
        "--friction",
        type=friction_terms,
        default=("viscous", "coulomb", "offset"),
        help="joint terms, comma separated from viscous,coulomb,offset (friction) and armature "
        "(reflected motor inertia), or 'none'",
    )
    _add_preparation_arguments(p)
    _add_fit_arguments(p)
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument("--smoke", action="store_true", help="quick check: the first seconds only")
    p.add_argument("--smoke-seconds", type=float, default=12.0, help=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_identify)
    return p


def _add_preparation_arguments(p: argparse.ArgumentParser) -> None:
    """How the log is read, filtered, differentiated, cut and split (`torchjfa.data`)."""
    from .data import COULOMB_GRID, DEFAULT_CUTOFF_HZ

    p.add_argument(
        "--columns",
        default=None,
        help="map the library's column names to the log's: 't=time,q_j1=pos1' or a "
        "JSON object or file",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="seconds per unit of the time column, e.g. 1e-9 for ns",
    )
    p.add_argument(
        "--drop-nan",
        action="store_true",
        help="drop rows holding NaN (default: report them and stop)",
    )
    p.add_argument(
        "--cutoff",
        type=_cutoff,
        default="auto",
        help="low-pass cut-off, Hz, or 'auto': the one of 2..30 Hz that predicts held-out "
        "torques best inside the training part (torchjfa.data.choose_cutoff; "
        f"{DEFAULT_CUTOFF_HZ:g} Hz, with a warning, where the log is too short to choose)",
    )
    p.add_argument(
        "--coulomb-velocity",
        type=_coulomb_velocity,
        default="auto",
        metavar="V",
        help="smoothing velocity of the Coulomb friction term, rad/s: its column is "
        "tanh(qd / V), sign(qd) for 0; 'auto' chooses it with the cut-off by the same held-out "
        "prediction, from " + ", ".join(f"{v:g}" for v in COULOMB_GRID),
    )
    p.add_argument(
        "--filter",
        choices=("butterworth", "savgol"),
        default="butterworth",
        help="zero-phase low-pass filter: Butterworth (order 4) or Savitzky-Golay",
    )
    p.add_argument(
        "--velocity",
        choices=("auto", "measured", "differentiate"),
        default="auto",
        help="use the log's velocities ('measured'), differentiate the positions, or 'auto': "
        "the log's velocities if it has them",
    )
    p.add_argument(
        "--period",
        type=_period,
        default="auto",
        help="excitation period in s, 'auto' (detect) or 'none'",
    )
    p.add_argument(
        "--skip-start",
        type=_skip,
        default=0.0,
        help="seconds of start-up transient to drop, or 'auto', which needs a period",
    )
    p.add_argument("--decimate", type=int, default=1, help="keep every k-th sample after filtering")
    p.add_argument(
        "--validation",
        type=float,
        default=0.2,
        help="held-out fraction at the end of the log",
    )
    p.add_argument("--validation-log", default=None, help="hold out this log instead")


def _add_fit_arguments(p: argparse.ArgumentParser) -> None:
    """How the parameters are estimated and projected (`torchjfa.identification.Options`)."""
    p.add_argument(
        "--input-noise",
        choices=("auto", "learn", "periods", "propagated"),
        default="auto",
        help="the regressor's input noise (Bayesian JFA's, and the projection's metric): the "
        "spread between excitation periods ('periods'), the log's sensor noise from its "
        "spectrum propagated through the preparation ('propagated'), learned ('learn': the "
        "seed's estimator, whose eq. 4 the data do not identify), or 'auto': periods when "
        "the training data hold two or more, else propagated for an estimator that takes "
        "an input noise (Bayesian JFA, JFA)",
    )
    p.add_argument(
        "--jackknife",
        type=int,
        default=Options.jackknife,
        help="blocks for the jackknife spread of the parameters, 0 for none (default: %(default)s)",
    )
    p.add_argument(
        "--bias-correction",
        type=_refits,
        default=Options.bias_correction,
        metavar="N",
        help="refits on the log with re-drawn sensor noise for the noise's bias of the "
        "estimate (SIMEX), subtracted before the projection; 0 for none; 'auto': "
        f"{AUTO_BIAS_REFITS} for --estimator ols, none for the others (default: %(default)s)",
    )
    p.add_argument(
        "--weighting",
        choices=("residual", "none"),
        default="residual",
        help="weight each joint's equations by its inverse residual variance from a first "
        "least-squares fit (weighted least squares), or not at all",
    )
    p.add_argument(
        "--parametrization",
        choices=("virtual", "log-cholesky"),
        default="log-cholesky",
        help="the projection's parameters: the seed's virtual parameters (mass > 0, inertia "
        "PSD) or log-Cholesky, fully consistent (triangle inequalities too)",
    )
    p.add_argument("--no-project", action="store_true", help="skip the physical projection")
    p.add_argument(
        "--description-prior",
        type=_prior_weight,
        default=None,
        help="pull the projection towards the description where the data are silent: 'auto' "
        "(the weight chosen by cross-validation over blocks of the training data) or a weight "
        "(prior std = a typical value of each kind / sqrt(weight)); 0 turns it off "
        "(default: auto)",
    )
    p.add_argument(
        "--max-iter", type=int, default=20_000, help="most EM iterations of JFA and Bayesian JFA"
    )
    p.add_argument(
        "--ard",
        choices=("shared", "output"),
        default="shared",
        help="Bayesian JFA's relevance prior: on both loadings (the paper) or on the output "
        "loading alone, better with --input-noise (see BayesianJFA)",
    )
    p.add_argument(
        "--compiled",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="form the regressor with a C++ kernel generated for the robot (several times "
        "faster; about 2 s to build the first time); by default wherever a C++ compiler is "
        "found, else the torch path",
    )


def _refits(text: str):
    """``--bias-correction``: ``auto`` or a whole number of refits."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'auto' or a whole number, got {text!r}") from None
