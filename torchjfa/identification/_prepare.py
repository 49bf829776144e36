"""The `prepare_data` stage: the rest at the logs' ends, the cut-off, the zero-phase filter,
the derivatives and the held-out part of each log (`torchjfa.data.prepare`); and for the
stages that start from an identified model (`evaluate`, `identify_payload`,
`identify_drive_gains`), the model with the cut-off it was identified at (`identified_model`)
and each log prepared at that cut-off (`read_prepared`, `split_held_out`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import torch

from ..data import (
    DEFAULT_CUTOFF_HZ,
    EDGE_PERIODS,
    JointLog,
    LogError,
    armature_helps,
    choose_cutoff,
    coupled_drives,
    cutoff_grid,
    edge_seconds,
    prepare,
)
from ..data._rest import RestSpan, motion_span
from ..dynamics import RigidBodyModel
from ..io import IdentifiedModel, read_identified
from ._channels import channel_warnings
from ._options import IdentificationError, Options
from ._read import RawLog, enough, read

__all__ = ["LogPart", "PreparedData", "concatenate", "prepare_data", "read_prepared", "several"]


@dataclass
class LogPart:
    """One log of a `PreparedData`: where it came from and what was made of it.

    Attributes:
        source: the log's name (its path).
        raw: the raw log its parts were prepared from (the rest at its ends dropped: its
            prepared samples begin with ``train``).
        info: what `torchjfa.data.prepare` did to it (rates, period, samples dropped).
        train: its prepared training samples, or None (a validation log, or one too short to
            identify from).
        validation: its prepared held-out samples, or None.
        rest_s: ``(start, end)`` seconds of standing still dropped at its ends.
    """

    source: str
    raw: JointLog
    info: dict
    train: JointLog | None
    validation: JointLog | None
    rest_s: tuple[float, float] = (0.0, 0.0)

    def describe(self) -> str:
        """One line: the log, its samples for training and held out, the rest dropped."""
        n_t = 0 if self.train is None else self.train.n_samples
        n_v = 0 if self.validation is None else self.validation.n_samples
        rest = ""
        if any(self.rest_s):
            rest = f"; standing still dropped: {self.rest_s[0]:.3g} s at the start, "
            rest += f"{self.rest_s[1]:.3g} s at the end"
        return f"{self.source}: {n_t} samples for training, {n_v} held out{rest}"


@dataclass
class PreparedData:
    """What `prepare_data` returns: filtered, differentiated training and held-out data.

    Attributes:
        train: the prepared `JointLog` (q, qd, qdd, tau) to identify from: with several logs,
            their training parts one after the other (its time runs on across them).
        validation: the prepared held-out `JointLog`, the logs' held-out parts the same way.
        split: how the held-out part was chosen (for the report).
        cutoff_hz: the low-pass cut-off used, Hz.
        cutoff_how: how it was chosen.
        preparation: the keywords of `torchjfa.data.prepare` used.
        info: what `prepare` did to the (first) identification log (rates, period, samples
            dropped).
        warnings: the stages' warnings so far (the logs' checks, the cut-off's choice).
        parts: one `LogPart` per log read, the identification logs first.
        coulomb_velocity: the Coulomb term's smoothing velocity the later stages fit with,
            rad/s (`RigidBodyModel.coulomb_velocity`; chosen with the cut-off under
            ``"auto"``); `model_for` applies it.
        joint_terms: the joint terms the later stages fit with when the preparation chose
            them (the armature added, ``Options.armature``), else None; `model_for` applies
            them.
        joint_terms_how: how the armature was chosen (for the report), or "".
    """

    train: JointLog
    validation: JointLog
    split: str
    cutoff_hz: float
    cutoff_how: str
    preparation: dict
    info: dict
    warnings: list[str] = field(default_factory=list)
    parts: list[LogPart] = field(default_factory=list)
    coulomb_velocity: float = 0.0
    joint_terms: tuple[str, ...] | None = None
    joint_terms_how: str = ""

    @property
    def training_parts(self) -> list[LogPart]:
        """The parts with training samples, in the order of ``train``."""
        return [p for p in self.parts if p.train is not None]

    @property
    def raw(self) -> JointLog | None:
        """The raw log ``train`` was prepared from (its first ``train.n_samples`` prepared
        samples are ``train``) when it comes from one log, else None (see ``parts``)."""
        parts = self.training_parts
        return parts[0].raw if len(parts) == 1 else None

    def model_for(self, model: RigidBodyModel) -> RigidBodyModel:
        """``model`` with this preparation's joint terms and Coulomb smoothing velocity (itself
        if it has them)."""
        if self.joint_terms is not None and tuple(model.friction) != tuple(self.joint_terms):
            model = model.with_joint_terms(self.joint_terms)
        if model.coulomb_velocity == self.coulomb_velocity:
            return model
        return model.with_coulomb_velocity(self.coulomb_velocity)

    def describe(self) -> str:
        """One line on what the preparation did."""
        info, prep = self.info, self.preparation
        n_logs = len(self.training_parts)
        logs = f"{n_logs} logs, the first: " if n_logs > 1 else ""
        return (
            f"{logs}{info['raw_samples']} samples at {info['raw_rate_hz']:.6g} Hz"
            + (", resampled" if info["resampled"] else "")
            + f"; {prep['method']} cut-off {self.cutoff_hz:g} Hz, velocities {info['velocity']}"
            + (f"; period {info['period_s']:.6g} s" if info["period_s"] else "; no period")
            + f"; dropped {info['dropped_start_s']:.3g} s at the start, "
            f"{info['dropped_end_s']:.3g} s at the end; decimated x{prep['decimate']} to "
            f"{info['rate_hz']:.6g} Hz"
        )


def prepare_data(
    model: RigidBodyModel,
    raw: RawLog | Sequence[RawLog],
    options: Options | None = None,
    validation: RawLog | Sequence[RawLog] | None = None,
) -> PreparedData:
    """Filter and differentiate the logs (`torchjfa.data.prepare`) and hold part of them out.

    Each log is prepared on its own time base with the same cut-off: ``options.cutoff``, or
    with ``"auto"`` the one `torchjfa.data.choose_cutoff` finds on the longest log, on the part
    of it the held-out data never reach. With ``options.trim_rest`` the standing still at each
    log's ends is dropped first (`torchjfa.data.motion_span`), all but the filter's reach
    (`torchjfa.data.edge_seconds`), which the preparation drops anyway. Without ``validation``
    logs the last ``options.validation`` of each prepared log is held out, that reach apart from
    its training part, so that every log contributes to both; a log too short to split
    trains only, and one too short to prepare is left out, each with a warning.

    Args:
        model: the robot (`load_model`).
        raw: the `RawLog` of `read`, or several (one identification from all).
        options: `Options`.
        validation: logs to hold out instead of the ends of ``raw`` (one or several).

    Raises:
        LogError: on a log that cannot be prepared (the only one), or logs that leave no
            training or no held-out samples.
    """
    options = Options() if options is None else options
    raws = [raw] if isinstance(raw, RawLog) else list(raw)
    held = [] if validation is None else (
        [validation] if isinstance(validation, RawLog) else list(validation)
    )  # fmt: skip
    if not raws:
        raise LogError("no log to identify from")
    warnings = [w for r in raws + held for w in r.warnings]
    spans = [_span(r.log, options) for r in raws]
    longest = max(range(len(raws)), key=lambda i: raws[i].log.duration)
    pick = _trim(raws[longest].log, spans[longest], edge_seconds(_lowest(options)))
    cutoff, how, v_c = _cutoff(model, pick, options, not held, warnings)
    if len(raws) > 1 and options.cutoff == "auto":
        how += f" (on the longest log, {raws[longest].log.source})"
    terms, terms_how = _armature(model, pick, options, not held, cutoff, v_c)
    warnings += _coupled(model, pick, options, not held, cutoff, v_c, terms)
    prep = {
        "cutoff_hz": cutoff,
        "method": options.filter,
        "velocity": options.velocity,
        "period_s": options.period,
        "skip_start_s": options.skip_start,
        "decimate": options.decimate,
    }
    single = len(raws) == 1 and not held
    parts = [
        _part(r.log, span, prep, cutoff, None if held else options.validation, single, warnings)
        for r, span in zip(raws, spans, strict=True)
    ]
    valid_prep = {**prep, "skip_start_s": 0.0, "period_s": None}  # as `evaluate` prepares
    parts += [
        _part(r.log, _span(r.log, options), valid_prep, cutoff, 1.0, False, warnings) for r in held
    ]
    trains = [p.train for p in parts if p.train is not None]
    valids = [p.validation for p in parts if p.validation is not None]
    if not trains or not valids:
        what = "training" if not trains else "held-out"
        raise LogError(f"the logs leave no {what} samples after filtering (see the warnings)")
    if held:
        split = f"separate log{'s' if len(held) > 1 else ''} " + ", ".join(
            r.log.source for r in held
        )
    else:
        gaps = f"the filter's reach ({EDGE_PERIODS:g} / cut-off) apart"
        each = "of each log" if len(raws) > 1 else "of the log"
        split = f"last {options.validation:.0%} {each}, {gaps}"
        if single:
            gap = _gap(cutoff, parts[0].info)
            split = f"last {options.validation:.0%} of the log, {gap} samples apart"
    train = concatenate(trains)
    enough(train.n_samples, model, "after filtering and the validation split, training has")
    for part in parts:
        if part.train is not None:
            warnings += channel_warnings(model, replace(part.train, source=part.source))
    first = next(p for p in parts if p.train is not None)
    return PreparedData(
        train,
        concatenate(valids),
        split,
        cutoff,
        how,
        prep,
        dict(first.info),
        warnings,
        parts,
        coulomb_velocity=v_c,
        joint_terms=terms,
        joint_terms_how=terms_how,
    )


def _armature(model, log, options: Options, held_in_log: bool, cutoff: float, v_c: float):
    """``(joint terms or None, how)``: the default terms with the armature where
    `torchjfa.data.armature_helps` says so (``options.armature="auto"``, ``friction=None``)."""
    if options.friction is not None or options.armature != "auto" or "armature" in model.friction:
        return None, ""
    try:
        helps, how = armature_helps(
            model.with_coulomb_velocity(v_c),
            _choice_log(log, options, held_in_log),
            cutoff,
            method=options.filter,
            velocity=options.velocity,
            compiled=options.compute.compiled,
        )
    except LogError as exc:
        return None, f"left out: the log is too short to tell ({exc})"
    return ((*model.friction, "armature") if helps else None), how


def _coupled(model, log, options: Options, held_in_log: bool, cutoff: float, v_c: float, terms):
    """Warnings naming consecutive joints that a shared motor the model lacks would explain
    (`torchjfa.data.coupled_drives`); none where a drive train is given."""
    if model.transmission is not None or model.n_dof < 2:
        return []
    model = model.with_coulomb_velocity(v_c)
    if terms is not None:
        model = model.with_joint_terms(terms)
    try:
        found = coupled_drives(
            model,
            _choice_log(log, options, held_in_log),
            cutoff,
            method=options.filter,
            velocity=options.velocity,
            compiled=options.compute.compiled,
        )
    except LogError:  # too short to tell: nothing to say
        return []
    return [f.describe() for f in found]


def _choice_log(log: JointLog, options: Options, held_in_log: bool) -> JointLog:
    """The part of the raw log the data-driven choices see: the training part, less the
    filter's reach before the held-out part when that is the log's end."""
    if not held_in_log:
        return log
    # the held-out part is not seen by the choice: it starts at (1 - v) of the log less
    # (1 - 2 v) of the filter's edge (the split is by prepared samples, the edges trimmed),
    # at the grid's lowest cut-off
    v = options.validation
    end = (1.0 - v) * log.duration - max(0.0, 1.0 - 2.0 * v) * edge_seconds(_lowest(options))
    return log.select(log.t < log.t[0] + end)


def _lowest(options: Options) -> float:
    """The lowest cut-off the preparation may use, Hz (the longest reach of the filter)."""
    return float(options.cutoff) if options.cutoff != "auto" else cutoff_grid()[0]


def _span(log: JointLog, options: Options) -> RestSpan | None:
    """Where ``log`` moves (None: keep it whole, ``trim_rest=False``)."""
    if not options.trim_rest:
        return None
    span = motion_span(log)
    if not span.moves:
        raise LogError(f"{log.source}: no joint moves in the log: it identifies nothing")
    return span


def _trim(log: JointLog, span: RestSpan | None, keep_s: float) -> JointLog:
    """``log`` less its rest, keeping ``keep_s`` seconds of it at each end."""
    if span is None or (span.start == 0 and span.stop == log.n_samples):
        return log
    t = log.t
    a = int(torch.searchsorted(t, t[span.start] - keep_s))
    b = int(torch.searchsorted(t, t[span.stop - 1] + keep_s, right=True))
    return log if (a, b) == (0, log.n_samples) else log.select(slice(a, b))


def _part(log, span, prep, cutoff, fraction, single, warnings) -> LogPart:
    """One log prepared (its rest dropped) and split: ``fraction`` None trains only, 1.0
    holds it all out; ``single``: the only log, whose errors are raised."""
    raw = _trim(log, span, edge_seconds(cutoff))
    rest = (0.0, 0.0) if span is None else (span.rest_start_s, span.rest_end_s)
    try:
        data = prepare(raw, **prep)
    except LogError as exc:
        if single:
            raise
        warnings.append(f"{exc}; the log is left out")
        return LogPart(log.source, raw, {}, None, None, rest)
    if fraction is None:
        return LogPart(log.source, raw, dict(data.info), data, None, rest)
    if fraction == 1.0:
        return LogPart(log.source, raw, dict(data.info), None, data, rest)
    try:
        train, valid = split_held_out(data, fraction, cutoff)
    except LogError as exc:
        if single:
            raise
        warnings.append(f"{exc}; the whole log is used for training")
        return LogPart(log.source, raw, dict(data.info), data, None, rest)
    return LogPart(log.source, raw, dict(data.info), train, valid, rest)


def split_held_out(data: JointLog, fraction: float, cutoff_hz: float):
    """``(train, held_out)``: the last ``fraction`` of a prepared log held out, the filter's
    reach (`torchjfa.data.edge_seconds` of ``cutoff_hz``) apart from the rest.

    Raises:
        LogError: on a log too short to split.
    """
    return data.split(fraction, gap=_gap(cutoff_hz, data.info))


def _gap(cutoff_hz: float, info: dict) -> int:
    """The filter's reach in samples of a prepared log (its ``info``)."""
    return int(edge_seconds(cutoff_hz) * info["rate_hz"])


def concatenate(logs: Sequence[JointLog]) -> JointLog:
    """Prepared logs one after the other, as one `JointLog` (the first's type and joints):
    each next log's time starts one step (its own) after the last's end; ``period_samples``
    is kept for one log only. One log is returned as it is."""
    if len(logs) == 1:
        return logs[0]
    first = logs[0]
    logs = [g.reorder(first.joint_names) for g in logs]
    times, end = [], None
    for g in logs:
        t = g.t - g.t[0]
        if end is not None:
            step = float(torch.median(torch.diff(g.t))) if g.n_samples > 1 else 0.0
            t = t + end + step
        times.append(t)
        end = float(t[-1])
    arrays = {k: torch.cat([g._sample_arrays()[k] for g in logs]) for k in first._sample_arrays()}
    t = torch.cat(times) + first.t[0]
    return replace(first, t=t, period_samples=None, source=f"{len(logs)} logs", **arrays)


def _cutoff(model, log: JointLog, options: Options, held_in_log: bool, warnings: list):
    """``(cutoff_hz, how, coulomb_velocity)``: the given cut-off, or `choose_cutoff`'s on the
    training part; the given Coulomb smoothing velocity, or the one chosen with the cut-off."""
    given_v = options.coulomb_velocity != "auto" or "coulomb" not in model.friction
    if options.coulomb_velocity != "auto":
        model = model.with_coulomb_velocity(options.coulomb_velocity)
    if options.cutoff != "auto" and given_v:
        return float(options.cutoff), "given (--cutoff)", model.coulomb_velocity
    given = options.cutoff != "auto"
    log = _choice_log(log, options, held_in_log)
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
        if not given:  # too short for the grid's reach: the default cut-off, v_c chosen at it
            warnings.append(f"--cutoff auto: {exc}; {DEFAULT_CUTOFF_HZ:g} Hz used")
            short = "the default: the log is too short to choose one (see the warnings)"
            if given_v:
                return DEFAULT_CUTOFF_HZ, short, model.coulomb_velocity
            fallback = options.replace(cutoff=DEFAULT_CUTOFF_HZ)
            cutoff, how, v_c = _cutoff(model, log, fallback, False, warnings)
            return cutoff, how.replace("given (--cutoff)", short, 1), v_c
        sign = (
            ""
            if given_v
            else f", the Coulomb term's smoothing velocity {model.coulomb_velocity:g} rad/s"
        )
        warnings.append(f"the Coulomb smoothing velocity: {exc}; {options.cutoff:g} Hz used{sign}")
        return float(options.cutoff), "given (--cutoff) (see the warnings)", model.coulomb_velocity
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


def several(logs) -> list:
    """``logs`` as a list: one path or log, or a sequence of them."""
    if isinstance(logs, str | os.PathLike | JointLog):
        return [logs]
    if isinstance(logs, Sequence) and not isinstance(logs, bytes):
        if not logs:
            raise IdentificationError("no log given")
        return list(logs)
    return [logs]


def identified_model(identified) -> IdentifiedModel:
    """The identified robot that `evaluate`, `identify_payload` and `identify_drive_gains`
    start from, with ``theta`` in float64.

    Args:
        identified: a ``model.npz`` path (`torchjfa.io.read_identified`: its
            ``cutoff_hz`` is the cut-off it was identified at), or a ``(RigidBodyModel,
            theta)`` pair (no cut-off stored: `torchjfa.data.DEFAULT_CUTOFF_HZ`).

    Raises:
        IdentificationError: on a path that is no file, or a file that is no model file or a
            damaged one.
    """
    if isinstance(identified, Sequence) and not isinstance(identified, str):
        model, theta = identified
        return IdentifiedModel(model, torch.as_tensor(theta, dtype=torch.float64))
    path = os.fspath(identified)
    if not os.path.isfile(path):
        raise IdentificationError(f"no model file {path!r}")
    try:
        ident = read_identified(path)
    except ValueError as exc:  # not a model file, or a damaged one: the message says which
        raise IdentificationError(f"{path}: {exc}") from None
    return replace(ident, theta=ident.theta.to(torch.float64))


def read_prepared(source, model: RigidBodyModel, options: Options, cutoff_hz: float):
    """``(raw, prepared)``: a log read (`read`), the rest at its ends dropped (with
    ``options.trim_rest``) and prepared whole at ``cutoff_hz`` with the options' filter,
    velocities and decimation and no period, as a saved model is judged (`evaluate`,
    `identify_payload`)."""
    raw = read(source, model, options).log
    raw = _trim(raw, _span(raw, options), edge_seconds(cutoff_hz))
    prep = {"cutoff_hz": cutoff_hz, "method": options.filter, "velocity": options.velocity,
            "period_s": None, "decimate": options.decimate}  # fmt: skip
    return raw, prepare(raw, **prep)
