"""The stages of `torchjfa.identify`, each callable alone in the flow's order:

`load_model` -> `read` -> `prepare_data` -> `choose_noise` -> `fit` -> `validate`

Each stage's output is the next one's input; each collects the warnings it has for the user.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from .._joints import permutation
from ..data import (
    DEFAULT_CUTOFF_HZ,
    JointLog,
    LogError,
    check_log,
    choose_cutoff,
    coverage,
    cutoff_grid,
    prepare,
    propagated_noise,
    read_log,
    regressor_noise,
)
from ..dynamics import RigidBodyModel
from ..pipeline import IdentificationResult, noise_vector, residual_joint_weights
from ..pipeline import identify as _identify
from ..report import IdentificationReport, make_report
from ._options import IdentificationError, Options

__all__ = [
    "RawLog",
    "PreparedData",
    "NoiseChoice",
    "load_model",
    "read",
    "prepare_data",
    "choose_noise",
    "make_estimator",
    "cap_period_noise",
    "coverage_warnings",
    "fit",
    "validate",
]


# ------------------------------------------------------------------------------ robot
def load_model(robot, friction=("viscous", "coulomb", "offset")) -> RigidBodyModel:
    """The `RigidBodyModel` of ``robot``: a URDF / MJCF path, a shipped robot's name
    (`torchjfa.robots.available`), a simulated robot's name (`torchjfa.sim.ROBOTS`) or a model
    (returned as it is), with the joint terms ``friction``.

    Raises:
        IdentificationError: on a missing file or one that does not give a model.
    """
    if isinstance(robot, RigidBodyModel):
        return robot
    from .. import robots
    from ..sim import ROBOTS, model_path

    robot = os.fspath(robot)
    if robot in ROBOTS:
        path, fmt = str(model_path(robot)), "mjcf"
    elif robot in robots.available():
        path = robots.path(robot)
        fmt = "urdf" if path.endswith(".urdf") else "mjcf"
    else:
        path = robot
        if not os.path.isfile(path):
            raise IdentificationError(
                f"no robot file {path!r} (give a .urdf or MJCF .xml path, or one of "
                f"{sorted(set(robots.available()) | set(ROBOTS))})"
            )
        fmt = "urdf" if path.lower().endswith(".urdf") else "mjcf"
    try:
        if fmt == "urdf":
            return RigidBodyModel.from_urdf(path, friction=tuple(friction))
        return RigidBodyModel.from_mjcf(path, friction=tuple(friction))
    except Exception as exc:  # the parsers raise many kinds; all mean "this file is not usable"
        raise IdentificationError(
            f"cannot build a robot model from {path!r}: {type(exc).__name__}: {exc}"
        ) from None


# ------------------------------------------------------------------------------ read
@dataclass
class RawLog:
    """What `read` returns.

    Attributes:
        log: the `JointLog` as recorded, its joints in the model's order.
        warnings: what `torchjfa.data.check_log` found that does not stop identification.
    """

    log: JointLog
    warnings: list[str] = field(default_factory=list)


def read(source, model: RigidBodyModel, options: Options | None = None) -> RawLog:
    """Read a raw log (a CSV / NPZ / Parquet path, or a `JointLog`), put its joints in the
    model's order and check it (`torchjfa.data.check_log` with the description's joint limits).

    Raises:
        IdentificationError: on a log too short for the model's parameters.
        LogError: on a log that cannot be read or cannot identify anything (gaps, a robot
            standing still, degrees, scrambled columns).
    """
    options = Options() if options is None else options
    if isinstance(source, JointLog):
        log = source
    else:
        log = read_log(
            source,
            columns=None if options.columns is None else dict(options.columns),
            time_scale=options.time_scale,
            drop_nan=options.drop_nan,
        )
    log = log.reorder(model.joint_names)
    enough(log.n_samples, model, "the log has")
    problems = check_log(log, limits=joint_limits(model))
    fatal = [p.message for p in problems if p.fatal]
    if fatal:
        raise LogError(fatal[0])
    if options.max_seconds is not None:  # the first seconds only
        keep = int(torch.searchsorted(log.t, log.t[0] + options.max_seconds)) + 1
        log = log.select(slice(0, min(keep, log.n_samples)))
    return RawLog(log, [p.message for p in problems])


def enough(n_samples: int, model: RigidBodyModel, where: str) -> None:
    """At least as many equations (samples x joints) as parameters, else an error."""
    rows = n_samples * model.n_dof
    if rows < model.n_params:
        raise IdentificationError(
            f"{where} {n_samples} samples: with {model.n_dof} joints that is {rows} equations "
            f"for {model.n_params} parameters; record a longer log"
        )


def joint_limits(model: RigidBodyModel) -> np.ndarray | None:
    """``(n_dof, 2)`` position limits of the description in the model's joint order, or None."""
    if model.chain is None:
        return None
    lo, hi = model.chain.get_joint_limits()
    order = list(model.chain.get_joint_parameter_names())
    if sorted(order) != sorted(model.joint_names):
        return None
    lim = np.stack([np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)], axis=1)
    return lim[permutation(order, model.joint_names, have_name="the description's limits")]


# ------------------------------------------------------------------------------ prepare
@dataclass
class PreparedData:
    """What `prepare_data` returns: filtered, differentiated training and held-out data.

    Attributes:
        train: the prepared `JointLog` (q, qd, qdd, tau) to identify from.
        validation: the prepared held-out `JointLog`.
        split: how the held-out part was chosen (for the report).
        cutoff_hz: the low-pass cut-off used, Hz.
        cutoff_how: how it was chosen.
        preparation: the keywords of `torchjfa.data.prepare` used.
        info: what `prepare` did to the identification log (rates, period, samples dropped).
        warnings: the stages' warnings so far (the logs' checks, the cut-off's choice).
        raw: the raw identification log ``train`` was prepared from (its first
            ``train.n_samples`` prepared samples are ``train``), or None; `choose_noise`
            propagates its sensor noise (`torchjfa.data.propagated_noise`).
        coulomb_velocity: the Coulomb term's smoothing velocity the later stages fit with,
            rad/s (`RigidBodyModel.coulomb_velocity`; chosen with the cut-off under
            ``"auto"``); `model_for` applies it.
    """

    train: JointLog
    validation: JointLog
    split: str
    cutoff_hz: float
    cutoff_how: str
    preparation: dict
    info: dict
    warnings: list[str] = field(default_factory=list)
    raw: JointLog | None = None
    coulomb_velocity: float = 0.0

    def model_for(self, model: RigidBodyModel) -> RigidBodyModel:
        """``model`` with this preparation's Coulomb smoothing velocity (itself if it has it)."""
        if model.coulomb_velocity == self.coulomb_velocity:
            return model
        return model.with_coulomb_velocity(self.coulomb_velocity)

    def describe(self) -> str:
        """One line on what the preparation did."""
        info, prep = self.info, self.preparation
        return (
            f"{info['raw_samples']} samples at {info['raw_rate_hz']:.6g} Hz"
            + (", resampled" if info["resampled"] else "")
            + f"; {prep['method']} cut-off {self.cutoff_hz:g} Hz, velocities {info['velocity']}"
            + (f"; period {info['period_s']:.6g} s" if info["period_s"] else "; no period")
            + f"; dropped {info['dropped_start_s']:.3g} s at the start, "
            f"{info['dropped_end_s']:.3g} s at the end; decimated x{prep['decimate']} to "
            f"{info['rate_hz']:.6g} Hz"
        )


def prepare_data(
    model: RigidBodyModel,
    raw: RawLog,
    options: Options | None = None,
    validation: RawLog | None = None,
) -> PreparedData:
    """Filter and differentiate the log (`torchjfa.data.prepare`) and hold part of it out.

    The cut-off is ``options.cutoff``, or with ``"auto"`` the one `torchjfa.data.choose_cutoff`
    finds on the part of the raw log the held-out data never reach. Without a ``validation``
    log the last ``options.validation`` of the prepared log is held out, ``4 / cutoff`` s (the
    filter's reach) apart from the training part.
    """
    options = Options() if options is None else options
    warnings = list(raw.warnings)
    cutoff, how, v_c = _cutoff(model, raw.log, options, validation is None, warnings)
    prep = {
        "cutoff_hz": cutoff,
        "method": options.filter,
        "velocity": options.velocity,
        "period_s": options.period,
        "skip_start_s": options.skip_start,
        "decimate": options.decimate,
    }
    data = prepare(raw.log, **prep)
    if validation is not None:
        warnings += validation.warnings
        train, valid = data, prepare(validation.log, **{**prep, "skip_start_s": 0.0})
        split = f"separate log {validation.log.source}"
    else:
        # the gap keeps the filter's reach (4 / cutoff s) from linking the two parts
        gap = int(4.0 / cutoff * data.info["rate_hz"])
        train, valid = data.split(options.validation, gap=gap)
        split = f"last {options.validation:.0%} of the log, {gap} samples apart"
    enough(train.n_samples, model, "after filtering and the validation split, training has")
    return PreparedData(
        train,
        valid,
        split,
        cutoff,
        how,
        prep,
        dict(data.info),
        warnings,
        raw=raw.log,
        coulomb_velocity=v_c,
    )


def _cutoff(model, log: JointLog, options: Options, held_in_log: bool, warnings: list):
    """``(cutoff_hz, how, coulomb_velocity)``: the given cut-off, or `choose_cutoff`'s on the
    training part; the given Coulomb smoothing velocity, or the one chosen with the cut-off."""
    given_v = options.coulomb_velocity != "auto" or "coulomb" not in model.friction
    if options.coulomb_velocity != "auto":
        model = model.with_coulomb_velocity(options.coulomb_velocity)
    if options.cutoff != "auto" and given_v:
        return float(options.cutoff), "given (--cutoff)", model.coulomb_velocity
    given = options.cutoff != "auto"
    if held_in_log:
        # the held-out part is not seen by the choice: it starts at (1 - v) of the log less
        # (1 - 2 v) of the filter's edge (the split is by prepared samples, the edges trimmed),
        # 4 / f s at the grid's lowest cut-off f
        v = options.validation
        low = float(options.cutoff) if given else cutoff_grid()[0]
        end = (1.0 - v) * log.duration - max(0.0, 1.0 - 2.0 * v) * 4.0 / low
        log = log.select(log.t < log.t[0] + end)
    try:
        choice = choose_cutoff(
            model,
            log,
            grid_hz=(float(options.cutoff),) if given else None,
            method=options.filter,
            velocity=options.velocity,
            compiled=options.compute.compiled,
            coulomb_grid=() if given_v else None,
        )
    except LogError as exc:
        fallback = float(options.cutoff) if given else DEFAULT_CUTOFF_HZ
        what = "the Coulomb smoothing velocity" if given else "--cutoff auto"
        sign = (
            ""
            if given_v
            else f", the Coulomb term's smoothing velocity {model.coulomb_velocity:g} rad/s"
        )
        warnings.append(f"{what}: {exc}; {fallback:g} Hz used{sign}")
        how = "given (--cutoff)" if given else "the default: the log is too short to choose one"
        return fallback, how + " (see the warnings)", model.coulomb_velocity
    if choice.coulomb_velocity is None:
        return choice.cutoff_hz, choice.how, model.coulomb_velocity
    if given:
        scores = zip(choice.coulomb_grid, choice.coulomb_scores, strict=True)
        how = (
            "given (--cutoff); the Coulomb term's smoothing velocity tanh(qd / v_c) chosen at it "
            "by held-out torque prediction (as for --cutoff auto), mean nMSE "
            + ", ".join(f"{v:g} rad/s {sc:.3g}" for v, sc in scores)
            + f"; v_c = {choice.coulomb_velocity:g} rad/s"
        )
        return choice.cutoff_hz, how, choice.coulomb_velocity
    return choice.cutoff_hz, choice.how, choice.coulomb_velocity


# ------------------------------------------------------------------------------ noise
#: how each `NoiseChoice.mode` sets the input noise, for the report
NOISE_HOW = {
    "periods": "the spread between the training data's excitation periods "
    "(torchjfa.data.regressor_noise)",
    "learn": "none given: the estimator learns it",
    "given": "given by the user",
}


@dataclass
class NoiseChoice:
    """What `choose_noise` returns: the weights of the joints' equations and the input noise.

    Attributes:
        joint_weights: ``(n_dof,)`` weights (mean 1), or None (all 1).
        period_noise: the `torchjfa.data.PeriodNoise` of the training data (the spread between
            excitation periods, capped where it swamps a column), or None without two periods.
        input_noise: ``(n_params,)`` the regressor's input-noise variances given to the
            estimator and the projection, or None (the estimator's own, or none).
        mode: ``"periods"``, ``"propagated"``, ``"learn"`` or ``"given"``.
        warnings: what the user should know about these choices.
        how: one line on how the input noise was set (for the report's settings).
        propagated: the `torchjfa.data.PropagatedNoise` in ``"propagated"`` mode, else None.
    """

    joint_weights: torch.Tensor | None
    period_noise: object
    input_noise: torch.Tensor | None
    mode: str
    warnings: list[str] = field(default_factory=list)
    how: str = ""
    propagated: object = None


def choose_noise(model: RigidBodyModel, data: PreparedData, options: Options | None = None):
    """The joint weights (``options.weighting``) and the input noise (``options.input_noise``)
    of the training data: a `NoiseChoice`.

    ``"auto"`` takes the spread between excitation periods where the training data hold two
    or more (``"periods"``), else, for an estimator that takes an input noise (Bayesian JFA,
    JFA), the sensor noise of the raw log propagated through the preparation, the regressor and
    the joint weights (``"propagated"``, `torchjfa.data.propagated_noise`), and none for the
    others (``"learn"``: OLS's projection keeps its plain metric). ``"learn"`` gives none
    (Bayesian JFA learns it); ``"propagated"`` insists on the propagated noise, for any
    estimator (and the projection's metric).

    Raises:
        IdentificationError: ``input_noise="periods"`` without two excitation periods, or
            ``"propagated"`` without the raw log (``data.raw``).
    """
    options = Options() if options is None else options
    model = data.model_for(model)
    train, warnings = data.train, []
    weights = None
    if options.weighting == "residual":
        weights = residual_joint_weights(model, train, compiled=options.compute.compiled)
    pnoise = None
    if train.period_samples is not None and train.n_samples >= 2 * train.period_samples:
        pnoise, capped = cap_period_noise(
            model, regressor_noise(model, train, joint_weights=weights)
        )
        warnings += capped
    mode = options.input_noise
    if not isinstance(mode, str):
        noise = noise_vector(mode, model.n_params)
        return NoiseChoice(weights, pnoise, noise, "given", warnings, NOISE_HOW["given"])
    auto = mode == "auto"
    if auto:
        # the propagated noise only where the estimator takes it: given to the projection's
        # metric alone (OLS and the like) it made the real Panda log's default run worse
        # (docs/report.md), so that stays as it was
        mode = "periods" if pnoise is not None else "learn"
        if mode == "learn" and _takes_input_noise(options.estimator):
            mode = "propagated"
    if mode == "periods" and pnoise is None:
        raise IdentificationError(
            "--input-noise periods needs a periodic excitation with at least two periods in "
            "the training data; none was found (use --period SECONDS, --input-noise "
            "propagated or --input-noise learn)"
        )
    if mode == "propagated":
        try:
            prop = _propagated(model, data, weights, options)
        except (LogError, IdentificationError) as exc:
            if not auto:
                raise IdentificationError(f"--input-noise propagated: {exc}") from None
            warnings.append(f"--input-noise auto: {exc}; no input noise is given")
            return NoiseChoice(weights, pnoise, None, "learn", warnings, NOISE_HOW["learn"])
        prop, capped = cap_period_noise(model, prop, "the propagated sensor noise")
        warnings += capped
        return NoiseChoice(weights, pnoise, prop.input_noise, mode, warnings, prop.describe(), prop)
    noise = pnoise.input_noise if mode == "periods" else None
    return NoiseChoice(weights, pnoise, noise, mode, warnings, NOISE_HOW[mode])


def _takes_input_noise(estimator) -> bool:
    """Whether the estimator (a name, or an estimator given as it is) takes ``input_noise``."""
    from .. import estimators

    if isinstance(estimator, str):
        return estimators.takes(estimator, "input_noise")
    return hasattr(estimator, "input_noise")


def _propagated(model: RigidBodyModel, data: PreparedData, weights, options: Options):
    """`torchjfa.data.propagated_noise` of the training part of ``data``."""
    if data.raw is None:
        raise IdentificationError(
            "the propagated noise needs the raw log the training data were prepared from "
            "(PreparedData.raw, set by prepare_data)"
        )
    return propagated_noise(
        model,
        data.raw,
        data.preparation,
        joint_weights=weights,
        samples=data.train.n_samples,
        compiled=options.compute.compiled,
    )


def cap_period_noise(
    model: RigidBodyModel, pnoise, what: str = "the spread between periods"
) -> tuple[object, list[str]]:
    """Period noise (or any noise estimate with ``input_noise`` and ``column_power``, named
    ``what`` in the warning) of at least half a column's mean square (a column whose signal
    the noise swamps) capped at half of it, with a warning: the estimators refuse noise at or
    above a column's variance, and de-attenuating such a column more than 2x amplifies its
    noise."""
    power = pnoise.column_power
    noise = pnoise.input_noise
    bad = (noise >= 0.5 * power) & (power > 1e-20 * power.max())  # not round-off columns
    if not bool(bad.any()):
        return pnoise, []
    names = [model.layout.parameter_names[i] for i in bad.nonzero().flatten().tolist()]
    shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    capped = replace(pnoise, input_noise=torch.where(bad, 0.5 * power, noise))
    return capped, [
        f"{what} is at least half the signal of {len(names)} regressor "
        f"column(s) ({shown}): their input noise is capped at half their mean square; the "
        "parameters they carry are barely determined by this log"
    ]


# ------------------------------------------------------------------------------ fit
def make_estimator(options: Options, input_noise: torch.Tensor | None = None):
    """``options.estimator``: made by name (`torchjfa.estimators.make`, no intercept, with
    ``options.estimator_options`` and, for an estimator that takes one
    (`torchjfa.estimators.takes`), the input noise), or the estimator given, as it is."""
    from .. import estimators

    if not isinstance(options.estimator, str):
        return options.estimator
    kw = {"fit_intercept": False, **dict(options.estimator_options)}
    if input_noise is not None and estimators.takes(options.estimator, "input_noise"):
        kw["input_noise"] = input_noise
    return estimators.make(options.estimator, **kw)


def fit(
    model: RigidBodyModel, data: PreparedData, noise: NoiseChoice, options: Options | None = None
) -> IdentificationResult:
    """Moments of the training data -> estimator -> bias correction -> projection
    (`torchjfa.pipeline.identify`), with the model's Coulomb term smoothed as the preparation
    chose (`PreparedData.model_for`).

    With ``options.bias_refits(estimator)`` refits (by default 20 for OLS, none for the other
    estimators) the unconstrained estimate is corrected for the bias the sensor noise gives it
    (`torchjfa.identification.simex_bias`) before the projection; where the raw log's noise
    cannot be read (its spectrum), the estimate stays uncorrected and the result's
    ``warnings`` say so."""
    options = Options() if options is None else options
    model = data.model_for(model)
    estimator = make_estimator(options, noise.input_noise)
    n_refits = options.bias_refits(estimator)
    notes: list[str] = []
    refits: list[torch.Tensor] = []

    def bias(theta_hat: torch.Tensor) -> torch.Tensor | None:
        from ._bootstrap import simex_bias  # it builds on this module's stages

        try:
            b, coefs = simex_bias(
                model, data, noise, theta_hat, options, n_draws=n_refits,
                progress=options.compute.progress,
            )  # fmt: skip
        except (LogError, IdentificationError) as err:
            notes.append(
                f"the estimate is not corrected for the sensor noise's bias ({err}); "
                "bias_correction=0 (--bias-correction 0) turns the correction off"
            )
            return None
        refits.append(coefs)
        return b

    result = _identify(
        model,
        data.train,
        estimator=estimator,
        project=options.project,
        parametrization=options.parametrization,
        input_noise=noise.input_noise,
        projection_options=dict(options.projection_options),
        jackknife=options.jackknife,
        description_prior=options.description_prior if options.project else None,
        joint_weights=noise.joint_weights,
        bias=bias if n_refits else None,
        **options.compute.stream(),
    )
    result.warnings.extend(notes)
    result.theta_hat_redrawn = refits[0] if refits else None
    return result


# ------------------------------------------------------------------------------ validate
def coverage_warnings(train: JointLog, valid: JointLog) -> list[str]:
    """Where the held-out data move beyond the identification data (extrapolation)."""
    lines = coverage(
        (train.q, train.qd, train.qdd),
        (valid.q, valid.qd, valid.qdd),
        joint_names=train.joint_names,
    ).warnings()
    if not lines:
        return []
    return [
        "the held-out data move beyond the identification data, so their errors measure "
        "extrapolation: " + "; ".join(lines)
    ]


def validate(
    result: IdentificationResult,
    data: PreparedData,
    noise: NoiseChoice | None = None,
    settings: Mapping[str, object] | None = None,
) -> IdentificationReport:
    """The report on the held-out data (`torchjfa.report.make_report`); warns where the
    held-out data move beyond the identification data (their errors then measure
    extrapolation)."""
    settings = dict(settings or {})
    settings["warnings"] = list(settings.get("warnings", [])) + coverage_warnings(
        data.train, data.validation
    )
    period_noise = None if noise is None else noise.period_noise
    return make_report(result, data.validation, period_noise=period_noise, settings=settings)
