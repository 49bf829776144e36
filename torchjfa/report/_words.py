"""The words the report shares between ``report.md``, ``report.json``, the figures and the
command's output: the estimator on one line (`estimator_text`), the consistency check's verdict
(`verdict`) and table (`consistency_table`), the rule of what reads "off scale"
(`undetermined`), how the training data were filtered, and numbers to 3 significant digits
(`g3`). `torchjfa.report` re-exports the public names."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import torch

from ..physical import ConsistencyReport
from ..physical._base import parameter_kind

__all__ = [
    "UNDETERMINED_FACTOR",
    "consistency_table",
    "convergence",
    "estimator_text",
    "g3",
    "undetermined",
    "verdict",
]


def g3(x: float) -> str:
    """``x`` to 3 significant digits, trailing zeros kept (0.320, 1.56, 0.0249, 12.0)."""
    text = f"{x:#.3g}"
    return text[:-1] if text.endswith(".") else text


def _setting(value) -> str:
    """One estimator setting, short: a per-column tensor as its size and median, not its
    entries."""
    if isinstance(value, (torch.Tensor, np.ndarray)):
        v = torch.as_tensor(value, dtype=torch.float64).reshape(-1)
        if v.numel() == 1:
            return f"{float(v):.4g}"
        zeros = int((v == 0).sum())
        text = f"given: {v.numel()} columns, median {float(v.median()):.2g}"
        return "(" + text + (f", {zeros} of them 0" if zeros else "") + ")"
    if isinstance(value, float):
        return f"{value:.4g}"
    return repr(value)


def estimator_text(est) -> str:
    """The estimator's name and settings on one line, e.g. ``BayesianJFA(max_iter=20000, ...,
    input_noise=(given: 84 columns, median 0.00031, 10 of them 0))``: arrays summarised (`repr`
    would print every entry)."""
    params = ", ".join(
        f"{k}={_setting(v)}" for k, v in vars(est).items() if not k.endswith("_") and k[0] != "_"
    )
    return f"{type(est).__name__}({params})"


_NOISE_MODES = {
    "periods": "fixed to the spread between excitation periods",
    "learn": "learned by the estimator",
    "propagated": "the log's sensor noise (from its spectrum) propagated to the regressor",
}


def convergence(est) -> tuple[str, str | None]:
    """``(line, warning)``: the estimator's iterations and whether its stopping rule held, and a
    warning when it did not (None when it did or the estimator is not iterative)."""
    name = type(est).__name__
    if not hasattr(est, "converged_"):
        if hasattr(est, "n_iter_"):
            return f"{int(est.n_iter_)} iterations (no convergence flag)", None
        return "closed form (no iterations)", None
    n_iter = int(getattr(est, "n_iter_", -1))
    reason = getattr(est, "stop_reason_", None)
    if est.converged_:
        return f"{n_iter} iterations, converged: yes (stopping rule: {reason})", None
    cap = getattr(est, "max_iter", None)
    return (
        f"{n_iter} iterations, converged: **no** (stopped by {reason})",
        f"{name} did not converge: it stopped at its iteration cap"
        + (f" (max_iter={cap})" if cap is not None else "")
        + " before its stopping rule held, so its estimates may be far from the optimum; "
        "compare the held-out errors with `--estimator ols`, or raise `--max-iter`",
    )


# the unit value of each parameter kind (kg, kg m, kg m^2, N m s/rad, N m): a floor under the
# description's scale, so that a description with (near-)zero masses still has a scale
_UNIT_SCALE = 1.0
UNDETERMINED_FACTOR = 1e6  # |value| above this x the kind's scale is beyond any physical scale


def undetermined(values, names, description) -> torch.Tensor:
    """Which ``values`` lie beyond any physical scale: not finite, or larger in magnitude than
    `UNDETERMINED_FACTOR` times their kind's scale, the largest ``|description|`` value of that
    kind (at least 1 in SI units, so that a description with near-zero masses does not make
    every value look unphysical). The report prints such entries as "off scale".

    Args:
        values: ``(n_params,)`` values (unconstrained estimates, spreads), NaN allowed.
        names: the ``n_params`` parameter names (``joint.m``, ``joint.Ixx``, ``joint.fv``, ...).
        description: ``(n_params,)`` the description's parameters.

    Returns:
        ``(n_params,)`` bool, True where the value lies beyond any physical scale.
    """
    v = torch.as_tensor(values, dtype=torch.float64).reshape(-1)
    d = torch.as_tensor(description, dtype=torch.float64).reshape(-1).abs()
    kinds = [parameter_kind(n) for n in names]
    scale = {k: _UNIT_SCALE for k in kinds}
    for k, x in zip(kinds, d.tolist(), strict=True):
        if math.isfinite(x):
            scale[k] = max(scale[k], x)
    bound = torch.tensor([UNDETERMINED_FACTOR * scale[k] for k in kinds], dtype=torch.float64)
    return ~torch.isfinite(v) | (v.abs() > bound)


def verdict(c: ConsistencyReport) -> str:
    """One verdict, the consistency table's own ("yes"/"no", bodies failing of all), with why."""
    n = len(c.joint_names)
    if c.ok:
        return f"yes (all {n} bodies: pseudo-inertia positive definite, friction >= 0)"
    n_bad = int((~c.body_ok).sum())
    if c.weakly_ok:
        return (
            f"no ({n_bad} of {n} bodies fail: the triangle inequalities or a positive "
            "definite pseudo-inertia; mass > 0 and inertia PSD, the paper's eq. 5, hold; "
            "--parametrization log-cholesky enforces all)"
        )
    return f"no ({n_bad} of {n} bodies fail)"


def _noise_mode(settings: Mapping[str, object], estimator) -> str:
    """``"; input noise: ..."`` from the settings' input-noise mode ("" without one)."""
    mode = settings.get("input_noise")
    if not mode:
        return ""
    text = _NOISE_MODES.get(str(mode), str(mode))
    if not hasattr(estimator, "input_noise"):  # OLS, ridge, ...: projection only
        return f"; input noise ({text}) used in the projection's metric only"
    return f"; input noise: {text}"


def cutoff_hz(settings: Mapping[str, object]) -> float | None:
    """The low-pass cut-off the training data were filtered at, Hz, or None when unknown."""
    prep = settings.get("prepare")
    if isinstance(prep, Mapping) and prep.get("cutoff_hz") is not None:
        return float(prep["cutoff_hz"])
    return None


def _filtered(settings: Mapping[str, object]) -> str:
    """``"filtered at 13.8 Hz"``, or how else the training data were prepared."""
    hz = cutoff_hz(settings)
    if hz is not None:
        return f"filtered at {hz:.3g} Hz"
    return "as prepared" if settings.get("preparation") else "as given"


def consistency_table(c: ConsistencyReport, *, failing_only: bool = False) -> list[str]:
    """The consistency check per body as a Markdown table (full joint names), the failing
    bodies alone with ``failing_only``."""
    lines = [
        "| body (its joint) | mass, kg | smallest principal moment, kg m^2 | triangle margin, "
        "kg m^2 | smallest pseudo-inertia eigenvalue | friction >= 0 | consistent |",
        "|---|---|---|---|---|---|---|",
    ]
    for j, name in enumerate(c.joint_names):
        flags = [
            ("mass", c.mass_ok[j]),
            ("inertia", c.inertia_ok[j]),
            ("triangle", c.triangle_ok[j]),
            ("pseudo-inertia", c.pseudo_inertia_ok[j]),
            ("friction", c.friction_ok[j]),
        ]
        failed = [k for k, v in flags if not bool(v)]
        if failing_only and not failed:
            continue
        lines.append(
            f"| {name} | {float(c.mass[j]):.4g} | {float(c.principal_moments[j, 0]):.3g} | "
            f"{float(c.triangle_margin[j]):.3g} | {float(c.pseudo_inertia_min_eig[j]):.3g} | "
            f"{'yes' if bool(c.friction_ok[j]) else 'no'} | "
            + ("yes" if not failed else "no: " + ", ".join(failed))
            + " |"
        )
    return lines
