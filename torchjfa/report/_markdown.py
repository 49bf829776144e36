"""How an identification report reads: the Markdown of `IdentificationReport.markdown`.

``report.md`` opens with the verdict (`torchjfa.report._verdict`), then one short section each:
the held-out torque error per joint, the warnings, what the data determine, physical
consistency, noise, how the model was identified, the figures, and where the long tables are
(`parameters.csv`, ``report.json``, or the appendix, `torchjfa.report._appendix`, with
``appendix=True``). The wording the report shares with ``report.json``, the figures and the
command's output is in `torchjfa.report._words`. The section functions read only the
`IdentificationReport`'s attributes and methods (no import of `torchjfa.report`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from ._result import PRIOR_TOLERANCE
from ._verdict import Verdict, quadratic_mean, short_warning
from ._words import (
    _filtered,
    _noise_mode,
    consistency_table,
    convergence,
    estimator_text,
    g3,
    verdict,
)

__all__ = ["report_markdown"]

#: the verdict's most urgent warnings shown at the top (all are in the section "Warnings")
TOP_WARNINGS = 2


# ---------------------------------------------------------------------------------- sections
def report_markdown(
    report,
    images: Mapping[str, str] | None = None,
    *,
    folder=None,
    appendix: bool = False,
) -> str:
    """The whole report as Markdown.

    Args:
        report: an `IdentificationReport`.
        images: caption -> relative PNG path of each figure (no figures section when empty).
        folder: the report's folder (the verdict's load step names ``folder/model.npz``).
        appendix: whether the appendix (`torchjfa.report._appendix.appendix`, which the
            caller appends) follows: the last section points to it.

    Returns:
        The text of ``report.md`` up to the appendix, ending with a newline.
    """
    model_path = "model.npz" if folder is None else str(Path(folder) / "model.npz")
    v = report.judge(model_path)
    robot = report.settings.get("robot") or Path(report.model.source_path or "robot").name
    lines = [
        f"# Identification report: {robot}",
        "",
        *_verdict_section(report, v),
        *_torques_section(report),
        *_warnings_section(v),
        *_base_section(report),
        *_consistency_section(report),
        *_noise_section(report),
        *_details_section(report),
        *_figures_section(images),
        "Every parameter (value, status, source, spread, description): `parameters.csv`; every "
        "number of this report, the base-parameter combinations among them: `report.json`; "
        + (
            "the long tables: the appendix below."
            if appendix
            else "the long tables (parameters, base-parameter combinations, per log, per body): "
            "`torchjfa identify ... --appendix` or `IdentificationReport.write(folder, "
            "appendix=True)`."
        ),
    ]
    return "\n".join(lines) + "\n"


def _verdict_section(report, v: Verdict) -> list[str]:
    """The section "Verdict": accuracy against the description, consistency, what the data
    do not determine, the warnings and the next steps."""
    lines = ["## Verdict", "", "- " + _accuracy(v)]
    if v.rms_description is not None and (v.same or v.worse):
        per_joint = f"per joint: better on {len(v.better)} of {len(report.model.joint_names)}"
        if v.same:
            per_joint += f"; about as good on {', '.join(v.same)}"
        if v.worse:
            per_joint += f"; worse on {', '.join(v.worse)}"
        lines.append(f"- {per_joint}")
    c = report.consistency
    n, n_bad = len(c.joint_names), int((~c.body_ok).sum())
    files = report.settings.get("description_file")
    lines.append(
        (
            f"- Physical consistency: yes, all {n} bodies"
            if c.ok
            else f"- Physical consistency: **no**, {n_bad} of {n} bodies fail"
        )
        + ' (section "Physical consistency")'
        + (f"; the description with these parameters: {files}" if files else "")
    )
    lines.append("- " + _determined(report, v))
    if len(v.warnings) == 1:
        lines.append(f'- Warnings: 1 (section "Warnings"): {short_warning(v.warnings[0])}')
    elif v.warnings:
        lines.append(
            f'- Warnings: {len(v.warnings)} (all in the section "Warnings"); the most urgent:'
        )
        lines += [f"  - {short_warning(w)}" for w in v.warnings[:TOP_WARNINGS]]
    else:
        lines.append("- Warnings: none")
    for k, step in enumerate(v.next_steps):
        lines.append(f"- **Next step**: {step}" if k == 0 else f"- then: {step}")
    return lines + [""]


def _accuracy(v: Verdict) -> str:
    """The verdict's first line: the held-out RMS error against the description's."""
    r = v.ratio
    rms = f"RMS torque error {g3(v.rms)} N m"
    if r is None:
        text = f"**No description to compare with**: held-out {rms}"
    else:
        stated = f" (with its own {v.description_terms})" if v.description_terms else ""
        desc = f"against the description's{stated} {g3(v.rms_description)} N m"
        text = {
            "better": f"**Better than the description by {_times(r)}** on held-out data: {rms} "
            f"{desc}",
            "about as good": f"**About as good as the description** on held-out data "
            f"({_times(r)}): {rms} {desc}",
            "worse": f"**Worse than the description** on held-out data ({_times(1 / r)} its "
            f"error): {rms} {desc}",
        }[v.rating]
        if not v.same and not v.worse:
            text += " (better on every joint)"
        elif v.rating == "better":
            text = text.replace("** on held-out data", " overall** on held-out data")
    if v.mean_nmse < 1.0:
        return (
            text + f"; the model explains {100 * (1 - v.mean_nmse):.3g} % of the held-out "
            f"torque variance (mean nMSE {g3(v.mean_nmse)})"
        )
    return text + f"; mean nMSE {g3(v.mean_nmse)}: no better than the torques' mean"


def _times(ratio: float) -> str:
    """A ratio as ``"1.0x"``, ``"4.9x"``, ``"12x"``, ``"150x"``: two significant digits (more
    above 100), no exponent."""
    if ratio >= 9.95:
        return f"{ratio:.0f}x"
    return f"{ratio:#.2g}x"


def _determined(report, v: Verdict) -> str:
    """The verdict's line on the parameters the data do not determine, and where their
    values come from."""
    if v.counts is None:
        return (
            f"Not determined by the data: all {v.n_params} parameters (the data excite none); "
            "no value is measured"
        )
    c = v.counts
    text = (
        f"Not determined by the data alone: {v.n_not_determined} of {v.n_params} parameters "
        f"({c['combination']} only in combinations, {c['poorly excited']} poorly excited, "
        f"{c['not excited']} not excited)"
    )
    if report.result.projection is None:
        text += "; their values are the estimator's, not physical"
    elif v.prior_weight:
        text += "; where the data are silent they follow the description's values (its prior)"
    else:
        text += "; where the data are silent the projection chose them (no description prior)"
    return text + "; `parameters.csv` marks them (columns `determined`, `source`)"


def _torques_section(report) -> list[str]:
    """The section "Held-out torque error": RMS and nMSE per joint, the identified model's and
    the description's."""
    s, fits = report.settings, report.fits
    names = [n for n in ("identified", "description") if n in fits]
    target = (
        "the measured torque, unfiltered"
        if s.get("held_out_target")
        else "the validation log's torque as given"
    )
    held = f"{report.validation.n_samples} samples" + (
        f", {s['validation']}" if s.get("validation") else ""
    )
    lines = [
        "## Held-out torque error",
        "",
        f"Held out: {held}. Target: {target}; predicted from q, qd, qdd {_filtered(s)}.",
        "",
        "| joint | "
        + " | ".join(f"RMS error {n}, N m" for n in names)
        + " | "
        + " | ".join(f"nMSE {n}" for n in names)
        + " |",
        "|---" * (1 + 2 * len(names)) + "|",
    ]
    for j, joint in enumerate(report.model.joint_names):
        cells = [g3(float(fits[n].rms[j])) for n in names]
        cells += [g3(float(fits[n].nmse[j])) for n in names]
        lines.append(f"| {joint} | " + " | ".join(cells) + " |")
    cells = [f"**{g3(quadratic_mean(fits[n].rms))}**" for n in names]
    cells += [f"**{g3(fits[n].mean_nmse)}**" for n in names]
    lines.append("| all | " + " | ".join(cells) + " |")
    return lines + [
        "",
        "RMS error: N m (N for prismatic joints); all: over every held-out sample, the quadratic "
        "mean of the joints' RMS. nMSE: mean squared error / variance of the measured torque "
        "(0 perfect, 1 no better than its mean); all: the mean over the joints. The "
        "unconstrained estimate's errors and each log's: `report.json` (`validation`, "
        "`settings.logs`).",
        "",
    ]


def _warnings_section(v: Verdict) -> list[str]:
    """The section "Warnings": every warning, most urgent first; nothing without any."""
    if not v.warnings:
        return []
    return ["## Warnings", "", *(f"- {w}" for w in v.warnings), ""]


def _base_section(report) -> list[str]:
    """The section "What the data determine" (`base_parameters` of the training data): the
    parameters per status, the base parameters and the description prior's weight."""
    b = report.base
    lines = ["## What the data determine", ""]
    if b is None:
        return lines + ["The training data excite no parameter.", ""]
    c = b.counts()
    lines += [
        f"- parameters: {c['determined']} determined by the data alone, {c['combination']} "
        f"only in combinations with others, {c['poorly excited']} poorly excited "
        f"(identifiable, but this log leaves them to the noise), {c['not excited']} not "
        f"excited (zero regressor column): {b.n_params} in all",
        f"- base parameters (the independent combinations the data can determine): "
        f"**{b.rank}** of {b.n_params}; {b.n_determined} of them determined to "
        f"{b.resolution:g} of their physical scale by this log (residual noise std "
        f"{math.sqrt(max(b.noise_var, 0.0)):.3g} per row); condition number of the "
        f"column-scaled base regression {b.condition_number:.3g}",
    ]
    prior = _prior_note(report.result)
    if prior:
        lines.append("- " + prior[-1])
    return lines + [""]


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


def _consistency_section(report) -> list[str]:
    """The section "Physical consistency": the verdicts of both estimates, the check's summary
    and the failing bodies (every body in the appendix)."""
    c = report.consistency
    n_bad = int((~c.body_ok).sum())
    lines = [
        "## Physical consistency",
        "",
        f"- physically consistent, identified: {verdict(c)}; unconstrained estimate: "
        f"{verdict(report.consistency_unconstrained)}",
        f"- per body (mass, inertia at the centre of mass, triangle inequalities, pseudo-inertia,"
        f" friction; relative tolerance {c.tol:g}): physically consistent: "
        f"{'yes' if c.ok else 'no'} ({n_bad} of {len(c.joint_names)} bodies fail)",
    ]
    if n_bad:
        lines += ["", *consistency_table(c, failing_only=True)]
    return lines + [""]


def _noise_section(report) -> list[str]:
    """The section "Noise": the spread between excitation periods per joint and signal (after
    filtering), the joint weights and the training residual, each labelled with what it is."""
    s, noise = report.settings, dict(report.noise)
    joints = list(report.model.joint_names)
    weights = noise.pop(_WEIGHTS_KEY, None)
    periods = noise.pop("excitation periods used", None)
    per_joint = {label: noise.pop(key) for key, label in _PER_JOINT.items() if key in noise}
    if per_joint:
        if weights is not None:
            per_joint["joint weight (mean 1)"] = weights
        lines = [
            f"## Noise: std between the {periods} excitation periods of the training data "
            f"({_filtered(s)}), and joint weights",
            "",
            "| joint | " + " | ".join(per_joint) + " |",
            "|---" * (1 + len(per_joint)) + "|",
        ]
        for j, joint in enumerate(joints):
            cells = ["-" if v[j] is None else g3(v[j]) for v in per_joint.values()]
            lines.append(f"| {joint} | " + " | ".join(cells) + " |")
        lines.append("")
    else:
        lines = ["## Noise", ""]
    if weights is not None and "joint weight (mean 1)" not in per_joint:
        listed = ", ".join(
            f"{j} {'-' if w is None else g3(w)}" for j, w in zip(joints, weights, strict=True)
        )
        lines.append(f"- joint weights (weighted least squares, mean 1): {listed}")
    for key, value in noise.items():
        lines.append(f"- {_noise_label(key, s, weights is not None)}: {_number(value)}")
    return lines + [""]


_WEIGHTS_KEY = "joint weights (weighted least squares, mean 1)"
#: ``report.json``'s per-joint noise keys -> the noise table's column headers
_PER_JOINT = {
    "q noise std per joint, rad": "q, rad",
    "qd noise std per joint, rad/s": "qd, rad/s",
    "qdd noise std per joint, rad/s^2": "qdd, rad/s^2",
    "torque noise std per joint, N m": "torque, N m",
}


def _noise_label(key: str, settings: Mapping[str, object], weighted: bool) -> str:
    """A noise entry's label with what it is of: filtered, weighted, units."""
    filtered = _filtered(settings)
    if key.startswith("training residual RMS"):
        if weighted:
            return (
                f"training residual RMS of the weighted equations (torque {filtered}, each "
                "joint's residual times its weight)"
            )
        return f"training residual RMS, N m (torque {filtered})"
    if key.startswith("estimator output noise"):
        return f"{key} (of the training equations{', weighted' if weighted else ''})"
    return key


def _number(value) -> str:
    """A noise value, 3 significant digits (lists joined, None as "-")."""
    if isinstance(value, list):
        return ", ".join("-" if x is None else g3(x) for x in value)
    if isinstance(value, float):
        return g3(value)
    return str(value)


def _details_section(report) -> list[str]:
    """The section "How it was identified": the log, the preparation, the model, the estimator
    and the command line."""
    model, s, r = report.model, report.settings, report.result
    line, _ = convergence(r.estimator)
    rest = [
        f"`{Path(str(x['log'])).name}` {x['rest_dropped_s'][0]:.3g} s at the start, "
        f"{x['rest_dropped_s'][1]:.3g} s at the end"
        for x in s.get("logs") or []
        if any(x.get("rest_dropped_s") or ())
    ]
    optional = [
        ("data", s.get("preparation")),
        ("cut-off", s.get("cutoff")),
        ("armature", s.get("armature")),
        ("rest dropped (the robot standing still)", "; ".join(rest)),
        ("bias correction", s.get("bias_correction")),
    ]
    return [
        "## How it was identified",
        "",
        (f"- log: `{s['log']}`; " if s.get("log") else "- ")
        + f"{r.n_samples} samples for identification, {report.validation.n_samples} held out",
        *(f"- {k}: {v}" for k, v in optional if v),
        f"- model: {model.n_dof} joints, {model.n_params} parameters, friction "
        f"{', '.join(model.friction) or 'none'}"
        + (
            f" (Coulomb as tanh(qd / {model.coulomb_velocity:g} rad/s))"
            if model.coulomb_velocity and "coulomb" in model.friction
            else ""
        )
        + _transmission_line(model),
        f"- estimator: `{estimator_text(r.estimator)}`" + _noise_mode(s, r.estimator),
        f"- convergence: {line}",
        *([f"- reproduce: `{s['command']}`"] if s.get("command") else []),
        "",
    ]


def _figures_section(images: Mapping[str, str] | None) -> list[str]:
    """The section "Figures": each image under its caption; nothing without images."""
    if not images:
        return []
    return ["## Figures", "", *(f"![{c}]({rel})" for c, rel in images.items()), ""]


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
