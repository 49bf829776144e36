"""The report of a floating-base identification (`torchjfa.identification.identify_legged`):
``report.md``, ``report.json``, ``parameters.csv``, ``identified.urdf`` (a URDF robot whose
bodies are all consistent) and two figures, written as one folder."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np

from .._util import output_folder
from ._descriptions import write_descriptions
from ._figures import _figure

__all__ = ["write_legged", "legged_markdown"]


def _rows_table(ident) -> list[str]:
    h = ident.held_out
    lines = [
        "| row | measured RMS | description | estimate | identified |",
        "|---|---:|---:|---:|---:|",
    ]
    for r, label in enumerate(ident.row_labels):
        if float(ident.weights[r]) == 0:
            continue
        cells = [f"{float(h[k][r]):.4g}" for k in ("measured", "description", "estimate",
                                                   "identified")]  # fmt: skip
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def _masses_table(ident) -> list[str]:
    desc = ident.masses(ident.model.nominal_theta)
    est = ident.masses(ident.theta_hat)
    got = ident.masses()
    seen = None if ident.mass_in_span is None else ident.mass_in_span.tolist()
    spread = ident.mass_spread
    lines = [
        "Seen by the rows: the mass lies in the span of the training rows. Across a revolute "
        "joint, mass on the joint's axis can move between the two bodies without changing any "
        "torque or force, so no single body's mass is seen: the description prior holds them. "
        "The rows see the total where they see the weight (measured contact forces, or a foot "
        "in the air). Spread: the jackknife over the training blocks of the data's own "
        "estimate, where the rows see the mass; it is the variance alone (the bias of noisy "
        "base accelerations is not in it).",
        "",
        "| body | description, kg | estimate, kg | identified, kg | seen by the rows "
        "| spread, kg | consistent |",
        "|---|---:|---:|---:|:---:|---:|:---:|",
    ]
    ok = None if ident.consistency is None else ident.consistency.body_ok.tolist()

    def seen_cells(k: int) -> str:
        if seen is None:
            return "- | -"
        sd = f"{float(spread[k]):.2g}" if seen[k] and math.isfinite(float(spread[k])) else "-"
        return f"{'yes' if seen[k] else 'no'} | {sd}"

    for k, body in enumerate(desc):
        flag = "-" if ok is None else ("yes" if ok[k] else "**no**")
        lines.append(f"| {body} | {desc[body]:.4g} | {est[body]:.4g} | {got[body]:.4g} | "
                     f"{seen_cells(k)} | {flag} |")  # fmt: skip
    lines.append(f"| **total** | {sum(desc.values()):.4g} | {sum(est.values()):.4g} | "
                 f"{sum(got.values()):.4g} | {seen_cells(len(desc))} | |")  # fmt: skip
    return lines


def legged_markdown(ident, images: dict[str, str] | None = None) -> str:
    """``report.md`` of a `torchjfa.identification.LeggedIdentification`."""
    s = ident.settings
    out = [f"# Identification of {s.get('robot')} (floating base)", ""]
    out += [f"- {line}" for line in ident.headline()]
    out += ["", "## Held-out prediction", ""]
    out += [
        "Each row's RMS residual on the held-out samples (base rows: N and N m, joint rows: "
        "N m or N), against the unfiltered torques and contact wrenches: the description "
        "with everything it states (its inertials, and its joints' damping and friction "
        "where it gives them), the unconstrained estimate, and the identified (physically "
        f"consistent) parameters. Rows: {s.get('rows')}.",
        "",
        *_rows_table(ident),
    ]
    if images and "rows" in images:
        out += ["", f"![held-out rows]({images['rows']})"]
    out += ["", "## Masses", "", *_masses_table(ident)]
    if images and "masses" in images:
        out += ["", f"![masses]({images['masses']})"]
    out += ["", "## Settings", "", "| setting | value |", "|---|---|"]
    out += [f"| {k} | {str(v).replace('|', '/')} |" for k, v in s.items()]
    if ident.warnings:
        out += ["", "## Warnings", "", *[f"- {w}" for w in ident.warnings]]
    return "\n".join(out) + "\n"


def _rows_figure(ident, path):
    keep = [r for r in range(len(ident.row_labels)) if float(ident.weights[r]) > 0]
    fig, axes = _figure(path, 1, figsize=(max(6.0, 0.45 * len(keep) + 2), 3.6))
    ax = axes[0, 0]
    x = np.arange(len(keep))
    for k, (name, colour) in enumerate((("description", "C7"), ("identified", "C0"))):
        ax.bar(x + (k - 0.5) * 0.4, ident.held_out[name][keep].numpy(), 0.4, label=name,
               color=colour)  # fmt: skip
    ax.set_xticks(x, [ident.row_labels[r] for r in keep], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("held-out RMS residual (N, N m)")
    ax.set_yscale("log")
    ax.legend()
    fig.savefig(path, dpi=110)


def _masses_figure(ident, path):
    desc = ident.masses(ident.model.nominal_theta)
    got = ident.masses()
    fig, axes = _figure(path, 1, figsize=(max(6.0, 0.4 * len(desc) + 2), 3.6))
    ax = axes[0, 0]
    x = np.arange(len(desc))
    ax.bar(x - 0.2, list(desc.values()), 0.4, label="description", color="C7")
    ax.bar(x + 0.2, list(got.values()), 0.4, label="identified", color="C0")
    ax.set_xticks(x, list(desc), rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("mass, kg")
    ax.legend()
    fig.savefig(path, dpi=110)


def _write_descriptions(ident, stage: Path) -> dict[str, str]:
    """``identified.xml`` (MJCF with a ``<freejoint>``) and, for a URDF robot,
    ``identified.urdf``, where every body is consistent (`write_descriptions`); records in
    ``settings["description_file"]`` what was written or why not."""
    if not ident.consistent:
        ident.settings["description_file"] = "not written: some bodies are not consistent"
        return {}
    urdf = ident.model.joints.source_format == "urdf"
    written, what = write_descriptions(ident.model, ident.theta, stage, urdf=urdf)
    ident.settings["description_file"] = what
    return {key: path.name for key, path in written.items()}


def write_legged(
    ident,
    out_dir: str | os.PathLike,
    *,
    plots: bool = True,
    overwrite: bool = False,
    inputs=(),
    command: str = "",
) -> dict[str, Path]:
    """Write a floating-base identification's folder as one unit (`torchjfa.io.output_folder`:
    a killed run leaves the earlier folder as it was).

    Files: ``model.npz`` (`torchjfa.io.read_identified`; ``torchjfa evaluate`` judges it on
    other legged logs); ``report.md``; ``report.json`` (the settings, the held-out RMS per row, the
    masses); ``parameters.csv`` (each parameter: description, estimate, identified);
    where every body is consistent, ``identified.xml`` (MJCF with a ``<freejoint>``) and, for
    a robot read from a URDF, ``identified.urdf``;
    ``held_out.png`` and ``masses.png`` with ``plots``.

    Returns:
        name -> path of each file written.

    Raises:
        torchjfa.io.OutputError: as `torchjfa.io.output_folder`.
    """
    out = Path(out_dir)
    written: dict[str, str] = {}
    with output_folder(out, overwrite=overwrite, inputs=inputs, command=command) as stage:
        model = ident.model
        with open(stage / "parameters.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["parameter", "description", "estimate", "identified"])
            for k, name in enumerate(model.parameter_names):
                w.writerow([name, repr(float(model.nominal_theta[k])),
                            repr(float(ident.theta_hat[k])), repr(float(ident.theta[k]))])  # fmt: skip
        written["parameters"] = "parameters.csv"
        from ..io import save_identified

        save_identified(stage / "model.npz", model, ident.theta, cutoff_hz=ident.cutoff_hz,
                        rows=ident.rows)  # fmt: skip
        written["model"] = "model.npz"
        written.update(_write_descriptions(ident, stage))
        images = {}
        if plots:
            _rows_figure(ident, stage / "held_out.png")
            _masses_figure(ident, stage / "masses.png")
            images = {"rows": "held_out.png", "masses": "masses.png"}
            written.update({"held_out_figure": "held_out.png", "masses_figure": "masses.png"})
        summary = {
            "settings": ident.settings,
            "rows": ident.rows,
            "row_labels": list(ident.row_labels),
            "weights": ident.weights.tolist(),
            "held_out_rms": {k: v.tolist() for k, v in ident.held_out.items()},
            "ratio_to_description": ident.ratio(),
            "masses": {
                "description": ident.masses(model.nominal_theta),
                "identified": ident.masses(),
                "spread": (
                    None
                    if ident.mass_spread is None
                    else dict(
                        zip([*ident.masses(), "total"], ident.mass_spread.tolist(), strict=True)
                    )
                ),
                "seen_by_the_rows": (
                    None
                    if ident.mass_in_span is None
                    else dict(
                        zip([*ident.masses(), "total"], ident.mass_in_span.tolist(), strict=True)
                    )
                ),
            },  # fmt: skip
            "total_mass": ident.total_mass,
            "consistent": ident.consistent,
            "cutoff_hz": ident.cutoff_hz,
            "n_train": ident.n_train,
            "n_held_out": ident.n_held,
            "warnings": ident.warnings,
        }
        (stage / "report.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
        (stage / "report.md").write_text(legged_markdown(ident, images), encoding="utf-8")
        written.update({"json": "report.json", "markdown": "report.md"})
    return {key: out / name for key, name in written.items()}
