"""`identify_legged`: a floating-base robot (a legged robot, a humanoid) and its logs in,
physically consistent parameters out.

The stages, each chosen from what the logs hold:

1. the model: `torchjfa.dynamics.FloatingBaseModel` of a URDF (the root link is the base) or
   an MJCF (the body with the ``<freejoint>``), with the joint terms of `Options.friction`;
2. the logs (`torchjfa.data.read_legged_log`): their joints matched to the model's, their
   contact frames checked against the description;
3. the rows (`contact_equations`): every row with the measured contact wrenches on the
   right-hand side where the logs hold forces; with contact flags only, every row with the
   contact forces projected out; the six base rows alone with `Options.base_rows_only`;
4. the cut-off: `Options.cutoff`, or ``"auto"``: of `torchjfa.data.cutoff_grid`, the one whose
   least-squares fit on the first three quarters of the training part predicts the rest best
   (against the unfiltered torques and wrenches);
5. the preparation (`torchjfa.data.prepare_legged`), the filter's reach dropped at both ends
   of each log and between its training part and its held-out end (or the validation logs);
6. the weights: each row (the base's six, each joint's) by its inverse residual variance
   from a first least-squares fit (``Options.weighting="residual"``);
7. the estimator (`Options.estimator`) on the weighted rows, with a constraint row for
   `Options.total_mass`; an estimator that models the inputs' noise (Bayesian JFA) is given
   the sensors' noise propagated through the preparation into each column
   (`propagated_legged_noise`, ``input_noise="auto"``);
8. the projection onto physically consistent parameters over every body, the base's
   included (`consistent_floating`), pulled towards the description with a weight chosen
   by cross-validation over five blocks of the training data (``description_prior="auto"``);
9. the held-out rows' RMS for the description, the estimate and the identified model.
"""

from __future__ import annotations

import copy
import os
import time
import warnings as _warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .._util import progress_bar
from ..data import (
    DEFAULT_CUTOFF_HZ,
    LeggedLog,
    LogError,
    cutoff_grid,
    edge_seconds,
    prepare_legged,
)
from ..dynamics import FloatingBaseModel
from ..physical import ConsistencyReport
from ..stats import Moments
from ._contacts import RowMoments, _Padded, consistent_floating, row_moments
from ._fit import make_estimator
from ._legged_masses import mass_index, mass_spread
from ._legged_noise import legged_input_noise, propagated_legged_noise
from ._legged_read import (
    check_legged_options,
    choose_rows,
    flat_frames,
    gains_text,
    imu_text,
    is_legged_log,
    load_floating,
    read_legged,
)
from ._noise import takes_input_noise
from ._options import IdentificationError, IdentificationWarning, Options
from ._prior import PRIOR_BLOCKS, choose_prior_weight, pick_prior_weight

__all__ = ["LeggedIdentification", "identify_legged", "is_legged_log"]

#: the description prior's weight where ``description_prior="auto"`` has too little data to
#: choose one
LEGGED_PRIOR_WEIGHT = 1.0
#: the constraint row of ``total_mass``: its weight over the largest diagonal of the data's
TOTAL_MASS_WEIGHT = 1e6
#: each part of the automatic cut-off's split needs this much time, s
_MIN_PART_SECONDS = 1.0
BASE_ROW_LABELS = ("base force x", "base force y", "base force z",
              "base moment x", "base moment y", "base moment z")  # fmt: skip


@dataclass(eq=False)
class LeggedIdentification:
    """What `identify_legged` returns.

    Attributes:
        model: the `torchjfa.dynamics.FloatingBaseModel`.
        rows: ``"all"`` (measured wrenches), ``"projected"`` (contact flags) or ``"base"``.
        row_labels: the ``r`` rows' names: the base's six, then each joint's (``"base"``:
            the base's six).
        theta_hat: ``(n_params,)`` the estimator's unconstrained estimate.
        theta: ``(n_params,)`` the physically consistent parameters (the estimate where the
            projection is off).
        consistency: theta's `torchjfa.physical.ConsistencyReport`, the base first.
        held_out: ``"description"``, ``"estimate"``, ``"identified"`` -> ``(r,)`` the
            held-out rows' RMS residual (N and N m for the base's rows, N m or N for the
            joints'), against the unfiltered torques and wrenches; ``"measured"`` the RMS
            of the rows' right-hand sides.
        weights: ``(r,)`` the rows' weights in the fit.
        cutoff_hz: the filter's cut-off, Hz; ``cutoff_how`` how it was chosen.
        n_train, n_held: training and held-out samples.
        settings: the run's record (robot, logs, choices).
        warnings: what the user should know.
        seconds: the fit's wall time, s.
        mass_spread: ``(n_bodies + 1,)`` each body's mass spread from the data alone, kg
            (the base first, the total mass last; `mass_spread`: the jackknife over the
            training blocks), or None.
        mass_in_span: ``(n_bodies + 1,)`` whether each body's mass (and the total) lies in
            the span of the training rows (the rows see it at all), or None.
    """

    model: FloatingBaseModel
    rows: str
    row_labels: tuple[str, ...]
    theta_hat: torch.Tensor
    theta: torch.Tensor
    consistency: ConsistencyReport | None
    held_out: dict[str, torch.Tensor]
    weights: torch.Tensor
    cutoff_hz: float
    cutoff_how: str
    n_train: int
    n_held: int
    settings: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    mass_spread: torch.Tensor | None = None
    mass_in_span: torch.Tensor | None = None

    def masses(self, theta=None) -> dict[str, float]:
        """Body -> mass, kg (the base first), of ``theta`` (default the identified)."""
        theta = self.theta if theta is None else torch.as_tensor(theta, dtype=torch.float64)
        index = mass_index(self.model)
        names = (self.model.base_name, *self.model.joints.body_names)
        return {b: float(theta[i]) for b, i in zip(names, index.tolist(), strict=True)}

    @property
    def total_mass(self) -> float:
        """The identified total mass, kg."""
        return sum(self.masses().values())

    @property
    def consistent(self) -> bool:
        """Whether every body of the identified model is physically consistent."""
        return self.consistency is not None and bool(self.consistency.body_ok.all())

    def ratio(self, name: str = "identified") -> float:
        """The held-out RMS over every row (in the fit's weights) of ``name`` over the
        description's."""
        w = self.weights
        own = float((w * self.held_out[name] ** 2).sum().sqrt())
        ref = float((w * self.held_out["description"] ** 2).sum().sqrt())
        return own / ref if ref > 0 else float("nan")

    def headline(self) -> list[str]:
        """Two lines: what was identified, and how it predicts the held-out rows."""
        desc = sum(self.masses(self.model.nominal_theta).values())
        state = "yes" if self.consistent else ("no" if self.consistency is not None else "-")
        return [
            f"identified {self.model.n_params} parameters of "
            f"{os.path.basename(str(self.settings.get('robot')))} "
            f"(floating base, {ROW_TEXT[self.rows]}) from {self.n_train} samples in "
            f"{self.seconds:.1f} s; total mass {self.total_mass:.4g} kg (description "
            f"{desc:.4g} kg); every body physically consistent: {state}",
            f"held-out RMS over the weighted rows: {self.ratio():.3g}x the description's "
            f"({self.n_held} samples)",
        ]

    def write(self, out_dir, **kwargs) -> dict[str, Path]:
        """Write the report's folder as one unit (`torchjfa.report.write_legged`): keywords
        ``plots``, ``overwrite``, ``inputs``, ``command``; returns the paths."""
        from ..report import write_legged

        return write_legged(self, out_dir, **kwargs)


#: how the report names each kind of rows
ROW_TEXT = {
    "all": "every row, with the measured contact wrenches",
    "projected": "contact flags, the contact forces projected out",
    "base": "the six base rows alone, with the measured contact wrenches",
}


def prepared_log(raw: LeggedLog, cutoff_hz: float, method: str = "butterworth") -> LeggedLog:
    """`torchjfa.data.prepare_legged` (with the IMU's place and gravity that `read_legged`
    put in ``raw.info``), its refusals (a log too short for the filter) as a
    `torchjfa.data.LogError` naming the log."""
    imu = {"imu_pose": raw.info.get("imu_pose"), "gravity": raw.info.get("gravity")}
    try:
        return prepare_legged(
            raw, cutoff_hz=cutoff_hz, method=method, **{k: v for k, v in imu.items() if v}
        )
    except ValueError as exc:
        raise LogError(f"{raw.info.get('source', 'the log')}: {exc}") from None


def _span(log: LeggedLog, start: float, stop: float) -> LeggedLog:
    return log.select((log.t >= start) & (log.t <= stop))


def with_raw_targets(prepared: LeggedLog, raw: LeggedLog) -> LeggedLog:
    """The prepared motion with the raw (unfiltered) torques and wrenches: the targets the
    held-out rows are judged against."""
    return LeggedLog(prepared.t, prepared.q, prepared.v, prepared.a, raw.tau, raw.contact,
                     raw.wrench, prepared.joint_names, prepared.info)  # fmt: skip


def _prepared_parts(raw, cutoff_hz, filter_, split, held, edge):
    """``(train, test)`` of one raw log prepared at ``cutoff_hz``: the training part
    ``[t0 + edge, t_split]`` and, where ``split`` is given, the held-out part
    ``[t_split + edge, t1 - edge]`` with the raw torques and wrenches."""
    prepared = prepared_log(raw, cutoff_hz, filter_)
    t0, t1 = float(raw.t[0]), float(raw.t[-1])
    if not held:
        return _span(prepared, t0 + edge, t1 - edge), None
    train = _span(prepared, t0 + edge, split)
    test = _span(with_raw_targets(prepared, raw), split + edge, t1 - edge)
    return train, test


def _moments(model, parts, rows, flat, chunk) -> RowMoments | None:
    total = None
    for part in parts:
        if part is not None and len(part.t):
            m = row_moments(model, part, rows=rows, flat=flat, chunk_size=chunk)
            total = m if total is None else total + m
    return total


def _lstsq(moments, weights) -> torch.Tensor:
    m = moments.combined(weights)
    return torch.linalg.lstsq(m.xtx, m.xty[:, None], driver="gelsd").solution[:, 0]


def _scale_weights(moments: RowMoments) -> torch.Tensor:
    """Each row weighted by its inverse mean square right-hand side (0 for an empty row)."""
    target = moments.target_rms()
    return torch.where(target > 0, 1.0 / target.clamp_min(1e-300) ** 2, 0.0)


def _choose_cutoff(model, raws, ends, rows, flat, options) -> tuple[float, str, list[str]]:
    """The cut-off of `cutoff_grid` whose least-squares fit on the first three quarters of
    each log's training part predicts the rest best; `DEFAULT_CUTOFF_HZ` with a warning
    where the training parts are too short."""
    if options.cutoff != "auto":
        return float(options.cutoff), "given", []
    grid = cutoff_grid()
    edge = edge_seconds(min(grid))
    pieces = []
    for raw, end in zip(raws, ends, strict=True):
        t0 = float(raw.t[0])
        split = t0 + 0.75 * (end - t0)
        if split - t0 - edge >= _MIN_PART_SECONDS and end - split - 2 * edge >= _MIN_PART_SECONDS:
            pieces.append((_span(raw, t0, end), split))
    if not pieces:
        return DEFAULT_CUTOFF_HZ, "the default", [
            f"the training data are too short to choose the cut-off (each log's training part "
            f"needs about {4 * (_MIN_PART_SECONDS + 2 * edge):.0f} s): "
            f"{DEFAULT_CUTOFF_HZ:g} Hz was used; give --cutoff"
        ]  # fmt: skip
    scores = []
    chunk = options.compute.chunk_size
    for fc in grid:
        parts = [_prepared_parts(raw, fc, options.filter, split, True, edge)
                 for raw, split in pieces]  # fmt: skip
        fit_m = _moments(model, [p[0] for p in parts], rows, flat, chunk)
        check = _moments(model, [p[1] for p in parts], rows, flat, chunk)
        theta = _lstsq(fit_m, _residual_weights(fit_m, options))
        scores.append(float((_scale_weights(check) * check.rms(theta) ** 2).sum()))
    best = int(np.argmin(scores))
    how = (
        f"auto: of {', '.join(f'{g:g}' for g in grid)} Hz, the one whose fit on the first "
        "three quarters of the training part predicts the rest best"
    )
    return grid[best], how, []


def _residual_weights(moments: RowMoments, options: Options) -> torch.Tensor:
    """Each row's weight: its inverse residual variance after a first least-squares fit
    (``weighting="residual"``), else 1."""
    used = (moments.target_rms() > 0).to(torch.float64)
    if options.weighting == "none":
        return used
    rms = moments.rms(_lstsq(moments, used))
    floor = 1e-6 * float(rms.max()) if float(rms.max()) > 0 else 1.0
    return used / rms.clamp_min(floor) ** 2


def identify_legged(
    robot,
    logs,
    options: Options | None = None,
    *,
    validation_log=None,
    settings: Mapping[str, object] | None = None,
) -> LeggedIdentification:
    """Identify a floating-base robot (a legged robot, a humanoid) from its logs (the module's
    stages). `torchjfa.identify` calls it for logs with base columns, as does ``torchjfa
    identify``.

    Args:
        robot: a URDF (the root link is the base) or MJCF (a ``<freejoint>``) path, or a
            `torchjfa.dynamics.FloatingBaseModel`.
        logs: a legged log or a list of them (`torchjfa.data.read_legged_log`'s columns; paths
            or `torchjfa.data.LeggedLog` s).
        options: `Options`; the reading and preparation options of joint logs that a legged
            log has no use for (column maps, drive gains, periods, ...) must stay at their
            defaults. ``description_prior="auto"`` chooses the prior's weight by
            cross-validation over blocks of the training data, as for a fixed base.
        validation_log: logs to hold out instead of the end of each log.
        settings: more entries for the report's record (the command line).

    Returns:
        A `LeggedIdentification`; ``.write(folder)`` writes its report. Its ``warnings`` are
        also issued as `IdentificationWarning` s.

    Raises:
        IdentificationError: on options or data that cannot give an identification.
        torchjfa.data.LogError: on a log that cannot be read, or whose joints or contact
            frames do not match the robot.
    """
    options = Options() if options is None else options
    check_legged_options(options)
    sources = list(logs) if isinstance(logs, list | tuple) else [logs]
    held_sources = [] if validation_log is None else (
        list(validation_log) if isinstance(validation_log, list | tuple) else [validation_log]
    )  # fmt: skip
    if not sources:
        raise IdentificationError("no log given")
    stages = ("reading", "choosing the cut-off", "preparing", "fitting", "projecting")
    with progress_bar(total=len(stages), desc="identify", enabled=options.compute.progress,
                      unit="stage") as bar:  # fmt: skip
        bar.set_description_str(f"identify: {stages[0]}")
        model = load_floating(robot, options)
        raws = [read_legged(s, model, options) for s in sources]
        helds = [read_legged(s, model, options) for s in held_sources]
        rows = choose_rows(raws + helds, options)
        flat = flat_frames(raws + helds, options) if rows == "projected" else ()
        ends = [float(r.t[-1]) if helds else
                float(r.t[0] + (1 - options.validation) * (r.t[-1] - r.t[0])) for r in raws]  # fmt: skip
        bar.update(1)
        bar.set_description_str(f"identify: {stages[1]}")
        cutoff, how, warnings = _choose_cutoff(model, raws, ends, rows, flat, options)
        bar.update(1)
        bar.set_description_str(f"identify: {stages[2]}")
        edge = edge_seconds(cutoff)
        parts = [_prepared_parts(r, cutoff, options.filter, end, not helds, edge)
                 for r, end in zip(raws, ends, strict=True)]  # fmt: skip
        parts_held = [p[1] for p in parts] + [
            with_raw_targets(*_pair(h, cutoff, options.filter, edge)) for h in helds
        ]
        chunk = options.compute.chunk_size
        blocks = _blocks(model, [p[0] for p in parts], rows, flat, chunk)
        train = sum(blocks[1:], blocks[0]) if blocks else None
        test = _moments(model, parts_held, rows, flat, chunk)
        if train is None or test is None:
            raise IdentificationError(
                f"the logs are too short: after the filter's reach ({edge:.2g} s at each end "
                "and between the parts) no training or no held-out samples are left"
            )
        bar.update(1)
        bar.set_description_str(f"identify: {stages[3]}")
        started = time.perf_counter()
        weights = _residual_weights(train, options)
        spread, in_span = mass_spread(model, blocks, weights)
        moments = _weighted(model, train, weights, options)
        noise, noise_how, more = _input_noise(model, raws, ends, helds, cutoff, options, rows,
                                              flat, weights, moments.n / train.combined(weights).n)  # fmt: skip
        warnings += more
        estimator = make_estimator(options, noise).fit_moments(moments)
        theta_hat = estimator.coef_.detach().to(torch.float64).cpu()
        bar.update(1)
        bar.set_description_str(f"identify: {stages[4]}")
        theta, consistency = theta_hat, None
        weight, prior_how = _prior_weight(model, blocks, weights, estimator, options)
        if options.project:
            theta, _, consistency = consistent_floating(model, moments, theta_hat,
                                                        prior_weight=weight)  # fmt: skip
        seconds = time.perf_counter() - started
        bar.update(1)
    labels = BASE_ROW_LABELS + (() if rows == "base" else model.joint_names)
    held_out = {
        "measured": test.target_rms(),
        "description": test.rms(model.description_theta),
        "estimate": test.rms(theta_hat),
        "identified": test.rms(theta),
    }
    if options.imu_frame is None and any(r.imu for r in raws + helds):
        warnings.append(
            f"the logs' IMU is taken to sit at the base frame {model.base_name!r} (its origin "
            "and axes): where it sits elsewhere, give its frame with --imu-frame FRAME"
        )
    if options.total_mass is None and rows == "projected":
        warnings.append(
            "with contact flags only, the total mass is weakly determined: give it with "
            "--total-mass where it is known (a scale), or log the contact forces"
        )
    sources = (raws, helds, estimator, cutoff, how, prior_how)
    record = {**_record(robot, model, rows, options, *sources), "input_noise": noise_how,
              **dict(settings or {})}  # fmt: skip
    out = LeggedIdentification(
        model, rows, labels, theta_hat, theta, consistency, held_out, weights, cutoff, how,
        train.n_samples, test.n_samples, record, warnings, seconds, spread, in_span,
    )  # fmt: skip
    for line in out.warnings:
        _warnings.warn(line, IdentificationWarning, stacklevel=2)
    return out


def _input_noise(model, raws, ends, helds, cutoff, options, rows, flat, weights, scale):
    """`legged_input_noise` of the training parts (``scale``: the moments' weight over the
    rows', which the total mass's constraint row raises)."""
    edge = edge_seconds(cutoff)
    spans = [(r, float(r.t[0]) + edge, float(r.t[-1]) - edge if helds else end)
             for r, end in zip(raws, ends, strict=True)]  # fmt: skip

    def propagate():
        noise = propagated_legged_noise(
            model, spans, lambda raw: prepared_log(raw, cutoff, options.filter),
            rows=rows, flat=flat, weights=weights,
        )  # fmt: skip
        return replace(noise, input_noise=noise.input_noise / scale,
                       column_power=noise.column_power / scale)  # fmt: skip

    return legged_input_noise(model, options, takes_input_noise(options.estimator), propagate)


def _record(robot, model, rows, options, raws, helds, estimator, cutoff, how, prior_how) -> dict:
    """The report's record of how the identification ran."""
    return {
        "robot": str(robot) if isinstance(robot, str | os.PathLike) else model.base_name,
        "log": ", ".join(str(r.info.get("source")) for r in raws),
        "validation": (
            ", ".join(str(h.info.get("source")) for h in helds)
            if helds
            else f"the last {options.validation:.0%} of each log"
        ),
        "rows": ROW_TEXT[rows],
        "flat_contacts": ", ".join(options.flat_contacts) or "none (point contacts)",
        "cutoff": f"{cutoff:g} Hz, {how}",
        "filter": options.filter,
        "joint_terms": ", ".join(model.joints.friction) or "none",
        "estimator": type(estimator).__name__,
        "weighting": options.weighting,
        "description_prior": prior_how,
        "total_mass": "none" if options.total_mass is None else f"{options.total_mass:g} kg",
        "drive_gains": gains_text(raws),
        "imu": imu_text(raws[0]),
    }


def _pair(raw, cutoff, filter_, edge) -> tuple[LeggedLog, LeggedLog]:
    """A validation log prepared whole, the filter's reach dropped at its ends, beside its raw
    samples at the same times."""
    t0, t1 = float(raw.t[0]), float(raw.t[-1])
    keep = (raw.t >= t0 + edge) & (raw.t <= t1 - edge)
    return prepared_log(raw, cutoff, filter_).select(keep), raw.select(keep)


def _blocks(model, parts, rows, flat, chunk) -> list[RowMoments]:
    """The training rows in `PRIOR_BLOCKS` blocks: each part cut into that many consecutive
    pieces, the k-th pieces of every part summed into block k (the description prior's
    cross-validation folds)."""
    blocks: list[RowMoments | None] = [None] * PRIOR_BLOCKS
    for part in parts:
        edges = np.linspace(0, len(part.t), PRIOR_BLOCKS + 1).astype(int)
        for k in range(PRIOR_BLOCKS):
            piece = part.select(np.arange(edges[k], edges[k + 1]))
            if len(piece.t):
                m = row_moments(model, piece, rows=rows, flat=flat, chunk_size=chunk)
                blocks[k] = m if blocks[k] is None else blocks[k] + m
    return [b for b in blocks if b is not None]


def _weighted(model, rows: RowMoments, weights, options: Options) -> Moments:
    """The rows' `Moments` in the fit's weights, with the total mass's constraint row."""
    moments = rows.combined(weights)
    if options.total_mass is not None:
        moments = _with_total_mass(model, moments, float(options.total_mass))
    return moments


def _prior_weight(model, blocks, weights, estimator, options: Options):
    """``(weight or None, how)`` of the description prior: given, or with ``"auto"`` chosen
    by cross-validation over the training blocks as for a fixed base
    (`torchjfa.identification.choose_prior_weight` on the padded layout). An estimator with
    several starts (Bayesian JFA) refits each fold from its first start alone: the refits only
    rank the weights, and they are most of the fit's time."""
    w = options.description_prior
    if not options.project:
        return None, "none (no projection)"
    if w != "auto":
        return (float(w) if w else None), (str(w) if w else "none")
    if len(blocks) < 2:
        return LEGGED_PRIOR_WEIGHT, f"{LEGGED_PRIOR_WEIGHT:g} (too little data to choose)"
    padded = _Padded(model)
    folds = [padded.pad_moments(_weighted(model, b, weights, options)) for b in blocks]
    noise = getattr(estimator, "input_noise", None)
    estimator = copy.deepcopy(estimator)
    if noise is not None:  # the given input noise, padded as the moments are
        noise = padded.pad(torch.as_tensor(noise, dtype=torch.float64))
        estimator.input_noise = noise
    if getattr(estimator, "n_starts", 1) > 1:  # the folds' refits from the first start alone
        estimator.n_starts = 1
    choice = choose_prior_weight(estimator, folds, padded, noise, options.parametrization, {})
    weight = pick_prior_weight(choice)
    return weight, (
        f"{weight:g} (auto: of {', '.join(f'{c:g}' for c in choice)}, by cross-validation "
        f"over {len(folds)} blocks of the training data)"
    )


def _with_total_mass(model, moments, mass: float):
    """``moments`` with a row ``sum of masses = mass`` of `TOTAL_MASS_WEIGHT` times the
    largest diagonal entry of the data's."""
    e = torch.zeros(model.n_params, dtype=torch.float64)
    e[mass_index(model)] = 1.0
    w = TOTAL_MASS_WEIGHT * float(moments.xtx.diagonal().max())
    row = Moments.from_data(e[None], torch.tensor([mass], dtype=torch.float64),
                            torch.tensor([w], dtype=torch.float64))  # fmt: skip
    return moments + row
