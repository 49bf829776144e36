"""How an identification report reads: the Markdown of `IdentificationReport.markdown`.

One function per section of ``report.md`` (header, held-out torques, noise, physical
consistency, what the data determine, parameters, figures, reproduce), and the wording they
share with ``report.json`` and the figures: `estimator_text`, `verdict` and the rule of what
reads "undetermined" (`undetermined`). `torchjfa.report` re-exports the public names; use it,
not this module. The section functions take the `IdentificationReport` and read only its
attributes and methods (this module imports nothing from `torchjfa.report`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from ._result import PRIOR_TOLERANCE
from .physical import ConsistencyReport
from .physical._base import parameter_kind

__all__ = ["UNDETERMINED_FACTOR", "estimator_text", "report_markdown", "undetermined", "verdict"]


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
        return f"{value:g}"
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


def _convergence(est) -> tuple[str, str | None]:
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
        f"**Warning: {name} did not converge**: it stopped at its iteration cap"
        + (f" (max_iter={cap})" if cap is not None else "")
        + " before its stopping rule held, so its estimates may be far from the optimum; "
        "compare the held-out errors with `--estimator ols`, or raise `--max-iter`.",
    )


# the unit value of each parameter kind (kg, kg m, kg m^2, N m s/rad, N m): a floor under the
# description's scale, so that a description with (near-)zero masses still has a scale
_UNIT_SCALE = 1.0
UNDETERMINED_FACTOR = 1e6  # |value| above this x the kind's scale is beyond any physical scale


def undetermined(values, names, description) -> torch.Tensor:
    """Which ``values`` lie beyond any physical scale: not finite, or larger in magnitude than
    `UNDETERMINED_FACTOR` times their kind's scale, the largest ``|description|`` value of that
    kind (at least 1 in SI units, so that a description with near-zero masses does not make
    every value look unphysical).

    Args:
        values: ``(n_params,)`` values (unconstrained estimates, spreads), NaN allowed.
        names: the ``n_params`` parameter names (``joint.m``, ``joint.Ixx``, ``joint.fv``, ...).
        description: ``(n_params,)`` the description's parameters.

    Returns:
        ``(n_params,)`` bool, True where the value should read "undetermined".
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
            "definite pseudo-inertia; mass > 0 and inertia PSD, the seed's eq. 5, hold; "
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


# ---------------------------------------------------------------------------------- sections
def report_markdown(report, images: Mapping[str, str] | None = None) -> str:
    """The whole report as Markdown.

    Args:
        report: an `IdentificationReport`.
        images: caption -> relative PNG path of each figure (no figures section when empty).

    Returns:
        The text of ``report.md``, ending with a newline.
    """
    summary = report.summary()
    lines = [
        *_header(report, summary),
        *_torques_section(report.fits, report.model.joint_names),
        *_logs_section(report.settings),
        *_noise_section(report.noise),
        *_consistency_section(report.consistency),
        *_base_section(report),
        *_parameters_section(summary["parameters"], report.undetermined_entries()),
        *_figures_section(images),
        *_reproduce_section(report.settings),
    ]
    return "\n".join(lines) + "\n"


def _header(report, s: Mapping[str, object]) -> list[str]:
    """The title and the list of what was identified from what, and how."""
    model, settings = report.model, report.settings
    convergence, warning = _convergence(report.result.estimator)
    return [
        f"# Identification report: {s['robot'] or Path(model.source_path or 'robot').name}",
        "",
        f"- log: `{settings.get('log', '-')}`; {s['train_samples']} samples for "
        f"identification, {s['validation_samples']} held out"
        + (f" ({settings['validation']})" if settings.get("validation") else ""),
        *([f"- data: {settings['preparation']}"] if settings.get("preparation") else []),
        *([f"- cut-off: {settings['cutoff']}"] if settings.get("cutoff") else []),
        *([f"- armature: {settings['armature']}"] if settings.get("armature") else []),
        *(
            [f"- the description with the identified parameters: {settings['description_file']}"]
            if settings.get("description_file")
            else []
        ),
        *(
            [f"- bias correction: {settings['bias_correction']}"]
            if settings.get("bias_correction")
            else []
        ),
        f"- model: {model.n_dof} joints, {model.n_params} parameters, friction "
        f"{', '.join(model.friction) or 'none'}"
        + (
            f" (Coulomb as tanh(qd / {model.coulomb_velocity:g} rad/s))"
            if model.coulomb_velocity and "coulomb" in model.friction
            else ""
        )
        + _transmission_line(model),
        f"- estimator: `{s['estimator']}`" + _noise_mode(settings, report.result.estimator),
        f"- convergence: {convergence}",
        *([f"- {warning}"] if warning else []),
        *(f"- warning: {w}" for w in settings.get("warnings", ())),
        f"- physically consistent, identified: {verdict(report.consistency)}; "
        f"unconstrained estimate: {verdict(report.consistency_unconstrained)}",
        (
            f"- training RMS torque error: {s['train_rmse']:.4g} N m"
            if report.result.joint_weights is None
            else "- training RMS of the weighted equations (each joint's residual times its "
            f"weight): {s['train_rmse']:.4g}"
        ),
        "",
    ]


def _torques_section(fits: Mapping[str, object], joints: list[str]) -> list[str]:
    """The section "Held-out torque prediction": nMSE and RMS per joint of each `TorqueFit`."""
    lines = [
        "## Held-out torque prediction",
        "",
        "nMSE = mean squared error / variance of the measured torque (0 is perfect, 1 is "
        "no better than the mean); RMS in N m.",
        "",
    ]
    names = list(fits)
    head = "| joint | " + " | ".join(f"{n} nMSE | {n} RMS" for n in names) + " |"
    lines += [head, "|---" * (1 + 2 * len(names)) + "|"]
    for j, jn in enumerate(joints):
        cells = []
        for n in names:
            f = fits[n]
            cells += [f"{float(f.nmse[j]):.4g}", f"{float(f.rms[j]):.4g}"]
        lines.append(f"| {jn} | " + " | ".join(cells) + " |")
    means = []
    for n in names:
        f = fits[n]
        means += [f"**{f.mean_nmse:.4g}**", f"**{float(f.rms.pow(2).mean().sqrt()):.4g}**"]
    lines.append("| all | " + " | ".join(means) + " |")
    return lines + [
        "",
        "all: nMSE is the mean over the joints; RMS is the quadratic mean over the joints, "
        "sqrt(mean of the squared per-joint RMS), in N m.",
    ]


def _logs_section(settings: Mapping[str, object]) -> list[str]:
    """The held-out target, and with several logs a table of each log's samples, rest dropped
    and held-out error of the identified model."""
    lines = []
    if settings.get("held_out_target"):
        lines += ["", f"Held-out target: {settings['held_out_target']}."]
    logs = settings.get("logs") or []
    if len(logs) < 2 and not any(any(r.get("rest_dropped_s") or ()) for r in logs):
        return lines
    lines += [
        "",
        "### Logs",
        "",
        "| log | training samples | held out | rest dropped, s (start, end) | held-out nMSE | "
        "held-out RMS, N m |",
        "|---|---|---|---|---|---|",
    ]
    for r in logs:
        rest = ", ".join(f"{x:.3g}" for x in r.get("rest_dropped_s") or (0.0, 0.0))
        nmse = f"{r['mean_nmse']:.4g}" if "mean_nmse" in r else "-"
        rms = f"{r['mean_rms']:.4g}" if "mean_rms" in r else "-"
        lines.append(
            f"| `{r['log']}` | {r['train_samples']} | {r['held_out_samples']} | {rest} | "
            f"{nmse} | {rms} |"
        )
    return lines + ["", "nMSE: the mean over the joints; RMS: the mean of the joints' RMS."]


def _noise_section(noise: Mapping[str, object]) -> list[str]:
    """The section "Noise": one line per noise estimate (lists per joint, None as "-")."""
    lines = ["", "## Noise", ""]
    for k, v in noise.items():
        if isinstance(v, list):
            v = ", ".join("-" if x is None else f"{x:.3g}" for x in v)
        lines.append(f"- {k}: {v}")
    return lines


def _consistency_section(consistency: ConsistencyReport) -> list[str]:
    """The section "Physical consistency of the identified parameters": the check's table."""
    lines = ["", "## Physical consistency of the identified parameters", "", "```"]
    return lines + [consistency.table(), "```", ""]


def _base_section(report) -> list[str]:
    """The section "What the data determine" (`base_parameters` of the training data): the
    counts, the base parameters that combine several parameters, and the description prior's
    weight."""
    b = report.base
    lines = ["## What the data determine", ""]
    if b is None:
        return lines + ["The training data excite no parameter.", ""]
    c = b.counts()
    lines += [
        f"- base (identifiable) parameters: **{b.rank}** of {b.n_params}; "
        f"{b.n_determined} of them determined to {b.resolution:g} of their physical scale "
        f"by this log (residual noise std {math.sqrt(max(b.noise_var, 0.0)):.3g} per row)",
        f"- condition number of the column-scaled base regression: {b.condition_number:.3g}",
        f"- parameters: {c['determined']} determined alone, {c['combination']} only in "
        f"combination with others (their single values are not determined: read the "
        f"combinations below), {c['poorly excited']} poorly excited (identifiable, but this "
        f"log leaves them to the noise), {c['not excited']} not excited (zero regressor "
        "column)",
        "",
        "Base parameters that combine several parameters (each is `first + sum coef x "
        "other`; the data determine the combination, not its terms); jackknife std: the "
        f"delete-one-block spread of the unconstrained value ({SPREAD_NOTE}).",
        "",
        "| base parameter | identified | unconstrained | jackknife std |",
        "|---|---|---|---|",
    ]
    n = 0
    for k, row in enumerate(report.base_rows()):
        if " + " not in row["combination"] and " - " not in row["combination"]:
            continue
        n += 1
        # beyond any physical scale (as in the parameter table): the first term's scale
        bound = UNDETERMINED_FACTOR * max(float(b.scales[b.independent[k]]), _UNIT_SCALE)
        lines.append(f"| {row['combination']} | " + " | ".join(_base_cells(row, bound)) + " |")
    if not n:
        lines.append("| (none: every base parameter is a single parameter) | | | |")
    return lines + _prior_note(report.result) + [""]


def _base_cells(row: Mapping[str, object], bound: float) -> list[str]:
    """One combination's identified, unconstrained and jackknife std cells; beyond
    ``bound`` or not finite reads "undetermined"."""
    cells = []
    for key, fmt in (("identified", ".4g"), ("unconstrained", ".4g"), ("jackknife_std", ".3g")):
        v = row[key]
        if v is None:
            cells.append("-")
        elif not math.isfinite(v) or abs(v) > bound:
            cells.append("undetermined")
        else:
            cells.append(format(v, fmt))
    return cells


def _prior_note(r) -> list[str]:
    """The description prior's weight (and how it was chosen) of an `IdentificationResult`;
    nothing without a prior."""
    if r.prior_weight is None:
        return []
    how = ""
    if r.prior_choice:
        how = (
            " (chosen by cross-validation over the training blocks, each predicted by the"
            " prior's closed-form fit on the others; held-out RMS of the joint-weighted torque"
            " equations per weight: "
            + ", ".join(f"{w:g}: {v:.4g}" for w, v in r.prior_choice.items())
            + ")"
        )
    edge = ""
    values = list(r.prior_choice.values()) if r.prior_choice else []
    if values and max(values) <= min(values) * (1.0 + PRIOR_TOLERANCE):
        edge = (
            f" The held-out blocks cannot tell the weights apart (all within "
            f"{PRIOR_TOLERANCE:.0%} of each other): the rule takes the largest, so the "
            "description decides wherever the data are silent."
        )
    elif r.prior_choice and r.prior_weight == max(r.prior_choice) > 0:
        edge = (
            " The largest weight tried won: the held-out blocks prefer the description "
            "even where the data have a say (prior std = each kind's typical size / "
            f"{math.sqrt(r.prior_weight):.3g})."
        )
    return [
        "",
        f"Where the data are silent the projection was pulled towards the description "
        f"with weight {r.prior_weight:g}{how}.{edge}",
    ]


#: the parameter table's value columns. Bayesian JFA's posterior std and relevance stay in
#: report.json and parameters.csv, not in the table: in simulation +-1.96 posterior stds cover
#: the truth 2 % of the time, not 95 % (scripts/spread_coverage.py, docs/report.md),
#: and a large relevance (the relevance prior's precision) does not mean the data find the
#: parameter insignificant (the real Panda log's Coulomb friction: about 25 jackknife stds from
#: 0 with <alpha> ~ 4e3)
_VALUE_COLUMNS = ("identified", "unconstrained", "jackknife_std")

#: what the jackknife's coverage is in simulation (scripts/spread_coverage.py, 2026-12-02:
#: 50 logs per robot, the bias-corrected estimate, 20 blocks)
SPREAD_NOTE = (
    "in simulation +-1 and +-1.96 of the 20-block jackknife cover the truth 72-74 % and 94 % of "
    "the time about the bias-corrected estimate (nominal 68 % and 95 %), 59-72 % and 83-94 % "
    "without the correction; 5 blocks cover 68 % and 89-90 % (docs/report.md)"
)


def _parameters_section(
    rows: list[Mapping[str, object]], flagged: Mapping[str, torch.Tensor]
) -> list[str]:
    """The section "Parameters": one row per parameter (``rows``:
    `IdentificationReport.parameter_rows`), ``flagged`` entries
    (`IdentificationReport.undetermined_entries`) read "undetermined", and a note on each kind
    of entry that is not a number."""
    lines = [
        "## Parameters",
        "",
        "identified: the physically consistent parameters (saved in `model.npz`); "
        "unconstrained: the estimator's (less the sensor noise's bias where the header's bias "
        "correction line says so); jackknife std: spread of the unconstrained "
        f"estimate over delete-one-block refits ({SPREAD_NOTE}); description: the robot "
        "file's value; data: what the data determine (see above: determined, combination, "
        "poorly excited, zero column). Units: kg, kg m, "
        "kg m^2, N m s/rad, N m.",
        "",
        "| parameter | identified | unconstrained | jackknife std | description | data |",
        "|---|---|---|---|---|---|",
    ]
    n_flagged = n_silent = 0
    for i, row in enumerate(rows):
        cells = _parameter_cells(row, i, flagged)
        n_flagged += cells.count("undetermined")
        n_silent += not row["excited"]
        # "zero column": the data column's word for base_parameters' "not excited" (which
        # also counts columns that are zero up to rounding)
        cells.append({"not excited": "zero column"}.get(row["data"], row["data"] or "-"))
        lines.append(f"| {row['parameter']} | " + " | ".join(cells) + " |")
    if n_silent:
        lines += [
            "",
            f"not excited ({n_silent} parameters): the parameter's regressor column is zero "
            "in the data (the motion does not move its torque), so the data say nothing "
            "about it; its identified value is the projection's alone.",
        ]
    if n_flagged:
        lines += [
            "",
            f"undetermined ({n_flagged} entries): a value or spread beyond any physical "
            f"scale, more than {UNDETERMINED_FACTOR:.0e} times the largest |value| of that "
            "kind in the description (at least 1 kg, kg m, kg m^2, N m s/rad or N m), or "
            "not finite: the data do not determine this parameter, only combinations of it "
            "with others. Read no physical meaning into the value; the held-out errors above "
            "say how well the model predicts torques.",
        ]
    return lines


def _parameter_cells(
    row: Mapping[str, object], i: int, flagged: Mapping[str, torch.Tensor]
) -> list[str]:
    """Parameter ``i``'s value, spread and description cells: "not excited" / "-" for a zero
    column, "undetermined" where flagged, "-" where there is no value."""
    cells = []
    for k in (*_VALUE_COLUMNS, "description"):
        v = row[k]
        if not row["excited"] and k in ("unconstrained", "jackknife_std"):
            cells.append("not excited" if k == "unconstrained" else "-")
        elif k in flagged and bool(flagged[k][i]):
            cells.append("undetermined")
        elif v is None:
            cells.append("-")
        else:
            cells.append(f"{v:.4g}")
    return cells


def _figures_section(images: Mapping[str, str] | None) -> list[str]:
    """The section "Figures": each image under its caption; nothing without images."""
    if not images:
        return []
    lines = ["", "## Figures", ""]
    for caption, rel in images.items():
        lines += [f"![{caption}]({rel})", ""]
    return lines


def _reproduce_section(settings: Mapping[str, object]) -> list[str]:
    """The section "Reproduce": the command line that wrote the report; nothing without one."""
    if not settings.get("command"):
        return []
    return ["", "## Reproduce", "", "```", str(settings["command"]), "```"]


def _transmission_line(model) -> str:
    """How a transmission carries the joint terms, for the model's line ("" without one)."""
    t = model.transmission
    if t is None or not model.friction:
        return ""
    coupled = t.coupled
    return (
        f"; the joint terms of {', '.join(t.joints)} act per motor through the transmission "
        f"(motor side: kg m^2, N m s/rad, N m; {', '.join(t.motors)})"
        + (f", coupled: {', '.join(coupled)}" if coupled else "")
    )
