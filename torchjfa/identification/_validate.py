"""The `validate` stage: the report on the held-out data."""

from __future__ import annotations

from collections.abc import Mapping

from .._result import IdentificationResult
from ..data import JointLog, coverage
from ..report import IdentificationReport, make_report
from ._noise import NoiseChoice
from ._prepare import PreparedData

__all__ = ["coverage_warnings", "validate"]


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
