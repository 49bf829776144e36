"""The ``torchjfa`` command: identify a robot from a log, simulate logs, evaluate a model.

    torchjfa simulate head --out log.csv
    torchjfa identify head log.csv --estimator bayes-jfa --friction viscous,coulomb --out result/
    torchjfa evaluate result/model.npz --robot head

A thin shell over `torchjfa.data` (read and prepare the log), `torchjfa.identify` (moments,
estimator, projection) and `torchjfa.report` (held-out errors, tables, figures). Bad input
(a missing column, an unknown joint, NaN rows, time going backwards, too few samples, a robot
file that does not parse) ends with one line on stderr and exit status 2, not a traceback;
``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

from .estimators import available as _estimators
from .identification._options import JOINT_TERMS as _FRICTION
from .identification._options import IdentificationError
from .sim import ROBOTS

__all__ = ["main", "ESTIMATORS"]

ESTIMATORS = _estimators()  # the library's; a registered one is taken by torchjfa.identify

_SIM_ROBOTS = tuple(ROBOTS)  # the simulated robots


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
def _friction(text: str) -> tuple[str, ...]:
    if text.strip().lower() in ("", "none"):
        return ()
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in _FRICTION]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown friction term(s) {bad}; choose from {_FRICTION}")
    return kinds


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


def load_model(robot: str, friction: tuple[str, ...]):
    """A `RigidBodyModel` from a URDF/MJCF path, a shipped robot or a simulated robot name
    (`torchjfa.identification.load_model`)."""
    from .identification import load_model as load

    return load(robot, friction)


def _period(text: str):
    if text in ("auto", "none"):
        return None if text == "none" else "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 'auto', 'none' or seconds, got {text!r}"
        ) from None


def _cutoff(text: str):
    if text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(
            f"expected 'auto' or a positive cut-off in Hz, got {text!r}"
        )
    return value


def _prior_weight(text: str):
    """``--description-prior``: ``auto`` or a weight >= 0."""
    if text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected 'auto' or a weight >= 0, got {text!r}")
    return value


def _skip(text: str):
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or seconds, got {text!r}") from None


# ------------------------------------------------------------------------------ identify
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
        project=not args.no_project,
        parametrization=args.parametrization,
        description_prior=args.description_prior,
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


# ------------------------------------------------------------------------------ simulate
def cmd_simulate(args) -> int:
    from .data import JointLog, write_log
    from .sim import SensorNoise, generate_log

    noise = SensorNoise().scaled(args.noise_scale)
    trajectory = None
    if args.trajectory:  # a trajectory written by torchjfa excite
        from .excitation._cli import simulation_reference

        try:
            trajectory = simulation_reference(args.trajectory, args.robot)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    log = generate_log(
        args.robot,
        n_samples=args.n_samples,
        unmodeled=not args.no_unmodeled,
        noise=noise,
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
    print(
        f"wrote {log.n_samples} samples ({log.n_samples / log.control_rate:.1f} s at "
        f"{log.control_rate:g} Hz) of the simulated {args.robot} to {out}; identify with:\n"
        f"  torchjfa identify {args.robot} {shlex.quote(str(out))} --out result/"
    )
    return 0


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
    from .experiments.robots import evaluate_control
    from .io import read_identified
    from .report import predicted_torques, torque_errors
    from .sim import generate_log, random_trajectory

    if not os.path.isfile(args.model):
        raise UsageError(f"no model file {args.model!r}")
    try:
        ident = read_identified(args.model)
    except ValueError as exc:  # not a model file, or a damaged one: the message says which
        raise UsageError(str(exc)) from None
    model, theta = ident.model, ident.theta
    log = generate_log(
        args.robot, n_samples=args.n_samples, seed=args.seed, progress=not args.quiet
    )
    try:
        log = log.reorder(model.joint_names)
    except ValueError:
        raise UsageError(
            f"the model's joints {model.joint_names} are not the simulated {args.robot}'s "
            f"{log.joint_names}"
        ) from None
    q, qd, qdd, tau = (getattr(log, k + "_true") for k in ("q", "qd", "qdd", "tau"))
    pred = predicted_torques(model, theta, q, qd, qdd, tau)
    nmse, rms = torque_errors(tau, pred)
    print(f"{args.robot}: torque prediction on a fresh noiseless trajectory (seed {args.seed})")
    print(f"{'joint':<16} {'nMSE':>10} {'RMS [N m]':>10}")
    for j, name in enumerate(model.joint_names):
        print(f"{name:<16} {float(nmse[j]):>10.4g} {float(rms[j]):>10.4g}")
    print(f"{'mean':<16} {float(nmse.mean()):>10.4g} {float(rms.pow(2).mean().sqrt()):>10.4g}")
    out = {"nmse": nmse.tolist(), "rms": rms.tolist()}
    if not args.no_control:
        from .sim import load_robot

        traj = random_trajectory(load_robot(args.robot), seed=args.seed + 1)
        res = evaluate_control(
            args.robot, model, {"identified": theta}, traj, duration=args.control_seconds
        )["identified"]
        if res.success:
            print(
                f"computed-torque control for {args.control_seconds:g} s: RMS position error "
                f"{res.mean_rms_position:.4g} rad, RMS feedback {res.mean_rms_feedback:.4g} N m"
            )
        else:
            print(f"computed-torque control FAILED: {res.reason}")
        out["control"] = {
            "success": res.success,
            "reason": res.reason,
            "rms_position": None if not res.success else res.mean_rms_position,
        }
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


# ------------------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    from .data import DEFAULT_CUTOFF_HZ

    parser = _Parser(
        prog="torchjfa",
        description="Probabilistic identification of robot dynamics (Bayesian joint factor "
        "analysis, physically consistent parameters).",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

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
        type=_friction,
        default=("viscous", "coulomb", "offset"),
        help="joint terms, comma separated from viscous,coulomb,offset (friction) and armature "
        "(reflected motor inertia), or 'none'",
    )
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
        default=5,
        help="blocks for the jackknife spread of the parameters, 0 for none",
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
        help="pull the projection towards the description where the data are silent: a "
        "weight >= 0 (prior std = a typical value of each kind / sqrt(weight)) or 'auto' "
        "(chosen on a held-out block of the training data); default off",
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
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument("--smoke", action="store_true", help="quick check: the first seconds only")
    p.add_argument("--smoke-seconds", type=float, default=12.0, help=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser(
        "simulate",
        help="simulate a robot tracking an excitation and write its log",
        description="Simulate the Sarcos-like head (7 DoF) or arm (10 DoF) in MuJoCo with "
        "sensor noise and write a log as a real robot would give it: t, q_<joint>, "
        "qd_<joint>, tau_<joint> (no accelerations).",
    )
    p.add_argument("robot", choices=_SIM_ROBOTS, help="the simulated robot")
    p.add_argument("--out", required=True, help="output: .csv, .npz or .parquet")
    p.add_argument("--n-samples", type=int, default=50_000, help="samples at the control rate")
    p.add_argument("--seed", type=int, default=0, help="seed of the excitation and the noise")
    p.add_argument("--noise-scale", type=float, default=1.0, help="x the default sensor noise")
    p.add_argument(
        "--no-unmodeled",
        action="store_true",
        help="rigid-body dynamics only (no armature, friction, ...)",
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
        help="track this trajectory.npz from torchjfa excite (default: a random excitation)",
    )
    p.set_defaults(func=cmd_simulate)

    from .excitation._cli import add_parser as add_excite_parser

    add_excite_parser(sub).set_defaults(func=cmd_excite)

    p = sub.add_parser(
        "evaluate",
        help="evaluate an identified model on a simulated robot",
        description="Predict the torques of a fresh noiseless trajectory of a simulated "
        "robot and run computed-torque control with the model in MuJoCo.",
    )
    p.add_argument("model", help="model.npz written by identify")
    p.add_argument("--robot", choices=_SIM_ROBOTS, required=True, help="the simulated robot")
    p.add_argument("--n-samples", type=int, default=8400, help="samples of the test trajectory")
    p.add_argument("--seed", type=int, default=100, help="seed of the test trajectory")
    p.add_argument("--no-control", action="store_true", help="skip the control run")
    p.add_argument(
        "--control-seconds", type=float, default=4.0, help="duration of the control run, s"
    )
    p.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_evaluate)
    return parser


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
