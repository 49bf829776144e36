"""The `validate` stage: the report on the held-out data, judged against the measured torque.

The held-out target is the torque as measured, not filtered: the prepared (filtered) torque
depends on the run's own cut-off, so two runs with different cut-offs would be judged on
different targets (a low cut-off smooths the target towards the model's prediction). The
prediction uses the prepared positions, velocities and accelerations, as the model would in
use. Where the log was resampled onto uniform time, the measured torque is read at the
held-out samples' times by the same cubic spline (`torchjfa.data.resample`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np
import torch
from scipy import interpolate

from ..data import JointLog, coverage
from ..report import IdentificationReport, make_report, torque_errors
from ..report._result import IdentificationResult
from ._noise import NoiseChoice
from ._prepare import LogPart, PreparedData, concatenate

__all__ = ["HELD_OUT_TARGET", "coverage_warnings", "measured_torque", "validate"]

#: how the report names the held-out target
HELD_OUT_TARGET = (
    "the measured torque, unfiltered (the same target whatever the cut-off); the prediction "
    "from the prepared q, qd, qdd"
)


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


def measured_torque(raw: JointLog, t: torch.Tensor) -> torch.Tensor:
    """``(len(t), n_dof)`` the raw log's torque at the times ``t`` (s): its own samples where
    ``t`` holds them, else its cubic spline (as `torchjfa.data.resample` reads it)."""
    rt, tt = raw.t.numpy(), t.numpy()
    idx = np.clip(np.searchsorted(rt, tt), 0, len(rt) - 1)
    scale = max(1.0, float(np.abs(rt).max()))
    if np.all(np.abs(rt[idx] - tt) <= 1e-12 * scale):
        return raw.tau[torch.from_numpy(idx)]
    spline = interpolate.CubicSpline(rt, raw.tau.numpy(), axis=0)
    return torch.from_numpy(spline(tt))


def _held_out(parts: list[LogPart]) -> list[tuple[LogPart, JointLog]]:
    """Each part's held-out samples with their measured (unfiltered) torque as ``tau``."""
    out = []
    for part in parts:
        if part.validation is not None:
            v = part.validation
            out.append((part, replace(v, tau=measured_torque(part.raw, v.t))))
    return out


def validate(
    result: IdentificationResult,
    data: PreparedData,
    noise: NoiseChoice | None = None,
    settings: Mapping[str, object] | None = None,
) -> IdentificationReport:
    """The report on the held-out data (`torchjfa.report.make_report`) against the measured,
    unfiltered torque (`HELD_OUT_TARGET`), with each log's own held-out error
    (``settings["logs"]``); warns where the held-out data move beyond the identification data
    (their errors then measure extrapolation)."""
    settings = dict(settings or {})
    settings["warnings"] = list(settings.get("warnings", [])) + coverage_warnings(
        data.train, data.validation
    )
    held = _held_out(data.parts)
    target = data.validation
    if held:
        target = concatenate([v for _, v in held])
        settings["held_out_target"] = HELD_OUT_TARGET
    period_noise = None if noise is None else noise.period_noise
    report = make_report(result, target, period_noise=period_noise, settings=settings)
    report.settings["logs"] = _per_log(data.parts, held, report)
    return report


def _per_log(parts: list[LogPart], held, report: IdentificationReport) -> list[dict]:
    """One record per log: its samples, the rest dropped, and its held-out error, read off
    the report's prediction of all the held-out samples (the logs' parts one after the
    other)."""
    errors = {}
    predicted, measured = report.fits["identified"].predicted, report.validation.tau
    start = 0
    for part, v in held:
        stop = start + v.n_samples
        nmse, rms = torque_errors(measured[start:stop], predicted[start:stop])
        start = stop
        errors[id(part)] = {
            "nmse": [float(x) for x in nmse],
            "mean_nmse": float(nmse.mean()),
            "rms": [float(x) for x in rms],
            "mean_rms": float(rms.mean()),
        }
    return [
        {
            "log": part.source,
            "train_samples": 0 if part.train is None else part.train.n_samples,
            "held_out_samples": 0 if part.validation is None else part.validation.n_samples,
            "rest_dropped_s": list(part.rest_s),
            **errors.get(id(part), {}),
        }
        for part in parts
    ]
