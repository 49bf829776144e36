"""The `choose_noise` stage: the weights of the joints' equations and the regressor's input
noise (from the repeated excitation periods, or the sensor noise propagated)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch

from .._validation import as_tensor, check_finite
from ..data import JointLog, LogError, propagated_noise, regressor_noise
from ..dynamics import RigidBodyModel
from ._options import IdentificationError, Options
from ._prepare import PreparedData
from ._stream import residual_joint_weights

__all__ = ["NoiseChoice", "choose_noise", "cap_period_noise", "noise_vector"]


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

    @classmethod
    def given(cls, joint_weights=None, input_noise=None) -> NoiseChoice:
        """The choice of a user who knows the weights and the noise (instead of
        `choose_noise`): ``joint_weights`` ``(n_dof,)`` or None (all 1), ``input_noise``
        ``(n_params,)`` variances of the (weighted) regressor columns or None (none given)."""
        if input_noise is None:
            return cls(joint_weights, None, None, "learn", how=NOISE_HOW["learn"])
        return cls(joint_weights, None, input_noise, "given", how=NOISE_HOW["given"])


def choose_noise(model: RigidBodyModel, data, options: Options | None = None) -> NoiseChoice:
    """The joint weights (``options.weighting``) and the input noise (``options.input_noise``)
    of the training data, a `NoiseChoice`: the stage after `prepare_data`.

    ``data`` is a `PreparedData`, or prepared logs as `fit` takes them (their periods are
    those of a single `torchjfa.data.JointLog` with ``period_samples``; they have no raw log to
    propagate the sensor noise from).

    ``"auto"`` takes the spread between excitation periods where the training data hold two
    or more (``"periods"``), else, for an estimator that takes an input noise (Bayesian JFA,
    JFA), the sensor noise of the raw log propagated through the preparation, the regressor and
    the joint weights (``"propagated"``, `torchjfa.data.propagated_noise`), and none for the
    others (``"learn"``: OLS's projection keeps its plain metric). ``"learn"`` gives none
    (Bayesian JFA learns it); ``"propagated"`` insists on the propagated noise, for any
    estimator (and the projection's metric).

    Raises:
        IdentificationError: ``input_noise="periods"`` without two excitation periods, or
            ``"propagated"`` without the raw logs (``data.parts``).
    """
    options = Options() if options is None else options
    prepared = isinstance(data, PreparedData)
    if prepared:
        model = data.model_for(model)
    train, warnings = (data.train if prepared else data), []
    weights = None
    if options.weighting == "residual":
        weights = residual_joint_weights(model, train, compiled=options.compute.compiled)
    pnoise = None
    if _periods(train) >= 2:
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
        # metric alone (OLS and the like) it predicts held-out torques of a real log worse
        # (docs/report.md)
        mode = "periods" if pnoise is not None else "learn"
        if mode == "learn" and takes_input_noise(options.estimator):
            mode = "propagated"
    if mode == "periods" and pnoise is None:
        raise IdentificationError(
            "--input-noise periods needs a periodic excitation with at least two periods in "
            "the training data; none was found (use --period SECONDS, --input-noise "
            "propagated or --input-noise learn)"
        )
    if mode == "propagated":
        try:
            if not prepared:
                raise IdentificationError(
                    "prepared logs carry no raw log to propagate the sensor noise from"
                )
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


def _periods(train) -> int:
    """Whole excitation periods in ``train`` (0 where it is not one log with a period)."""
    period = getattr(train, "period_samples", None) if isinstance(train, JointLog) else None
    return 0 if not period else train.n_samples // period


def noise_vector(input_noise, d: int) -> torch.Tensor | None:
    """``input_noise`` (None, a scalar or ``(d,)`` variances) as a float64 ``(d,)`` tensor, with
    a clear error on a wrong shape, NaN or a negative variance."""
    if input_noise is None:
        return None
    v = as_tensor(input_noise, name="input_noise", dtype=torch.float64)
    if v.ndim == 0:
        v = v.expand(d).clone()
    if tuple(v.shape) != (d,):
        raise IdentificationError(
            f"input_noise must be a scalar or have shape ({d},) (one variance per regressor "
            f"column), got {tuple(v.shape)}"
        )
    check_finite(v, "input_noise")
    if bool((v < 0).any()):
        raise IdentificationError("input_noise holds variances and must be non-negative")
    return v


def takes_input_noise(estimator) -> bool:
    """Whether the estimator (a name, or an estimator given as it is) takes ``input_noise``."""
    from .. import estimators

    if isinstance(estimator, str):
        return estimators.takes(estimator, "input_noise")
    return hasattr(estimator, "input_noise")


def _propagated(model: RigidBodyModel, data: PreparedData, weights, options: Options):
    """`torchjfa.data.propagated_noise` of the training part of ``data``: with several logs,
    each log's, averaged over their rows."""
    parts = data.training_parts
    if not parts:
        raise IdentificationError(
            "the propagated noise needs the raw logs the training data were prepared from "
            "(PreparedData.parts, set by prepare_data)"
        )
    noises = [
        propagated_noise(
            model,
            part.raw,
            data.preparation,
            joint_weights=weights,
            samples=part.train.n_samples,
            compiled=options.compute.compiled,
        )
        for part in parts
    ]
    return noises[0] if len(noises) == 1 else _pooled(noises)


def _pooled(noises: list) -> object:
    """Several logs' `torchjfa.data.PropagatedNoise` as one: the per-row averages weighted by
    their rows (the Monte Carlo errors as those of a weighted mean)."""
    w = torch.tensor([float(n.n_rows) for n in noises], dtype=torch.float64)
    w = w / w.sum()

    def mean(name):
        return sum(wi * getattr(n, name) for wi, n in zip(w, noises, strict=True))

    error = sum((wi * n.input_noise_error) ** 2 for wi, n in zip(w, noises, strict=True)).sqrt()
    fields_ = ("input_noise", "output_noise", "output_noise_per_joint", "column_power")
    return replace(
        noises[0],
        **{name: mean(name) for name in fields_},
        input_noise_error=error,
        n_rows=sum(n.n_rows for n in noises),
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
    names = [model.parameter_names[i] for i in bad.nonzero().flatten().tolist()]
    shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    capped = replace(pnoise, input_noise=torch.where(bad, 0.5 * power, noise))
    return capped, [
        f"{what} is at least half the signal of {len(names)} regressor "
        f"column(s) ({shown}): their input noise is capped at half their mean square; the "
        "parameters they carry are barely determined by this log"
    ]
