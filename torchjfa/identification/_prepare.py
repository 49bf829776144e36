"""The `prepare_data` stage: the cut-off, the zero-phase filter, the derivatives and the
held-out part of the log (`torchjfa.data.prepare`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..data import DEFAULT_CUTOFF_HZ, JointLog, LogError, choose_cutoff, cutoff_grid, prepare
from ..dynamics import RigidBodyModel
from ._options import Options
from ._read import RawLog, enough

__all__ = ["PreparedData", "prepare_data"]


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
