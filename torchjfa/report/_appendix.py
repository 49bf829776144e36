"""The long tables of ``report.md``, at its end with ``appendix=True``
(`IdentificationReport.markdown`, ``write``): the held-out error of every parameter set, the
consistency check per body, each log's samples and error, the base parameters that combine
several parameters, and every parameter. By default they are only in ``parameters.csv`` and
``report.json``. The functions read only the `IdentificationReport`'s attributes and methods.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from ._verdict import quadratic_mean
from ._words import _UNIT_SCALE, UNDETERMINED_FACTOR, consistency_table, g3

__all__ = ["appendix"]

#: the parameter table's value columns. Bayesian JFA's posterior std and relevance stay in
#: report.json and parameters.csv: neither measures the error (see the user guide)
_VALUE_COLUMNS = ("identified", "unconstrained", "jackknife_std")

#: what the jackknife spread is, once, under the tables that show it
SPREAD_NOTE = (
    "jackknife std: the spread of the unconstrained value over delete-one-block refits; it "
    "sees the noise, not a bias from model error"
)


def appendix(report) -> list[str]:
    """The appendix's lines: one subsection per long table."""
    return [
        "",
        "## Appendix",
        "",
        *_fits_table(report.fits, report.model.joint_names),
        "### Physical consistency per body",
        "",
        *consistency_table(report.consistency),
        "",
        *_logs_table(report.settings),
        *_combinations_table(report),
        *_parameters_table(report.parameter_rows(), report.undetermined_entries()),
    ]


def _fits_table(fits: Mapping[str, object], joints) -> list[str]:
    """Held-out RMS and nMSE per joint of every parameter set (identified, unconstrained,
    description)."""
    names = list(fits)
    lines = [
        "### Held-out torque error of every parameter set",
        "",
        "| joint | " + " | ".join(f"RMS {n}, N m | nMSE {n}" for n in names) + " |",
        "|---" * (1 + 2 * len(names)) + "|",
    ]
    for j, joint in enumerate(joints):
        cells = []
        for n in names:
            cells += [g3(float(fits[n].rms[j])), g3(float(fits[n].nmse[j]))]
        lines.append(f"| {joint} | " + " | ".join(cells) + " |")
    cells = []
    for n in names:
        cells += [g3(quadratic_mean(fits[n].rms)), g3(fits[n].mean_nmse)]
    return lines + ["| all | " + " | ".join(cells) + " |", ""]


def _logs_table(settings: Mapping[str, object]) -> list[str]:
    """Each log's samples, rest dropped and held-out error of the identified model."""
    logs = settings.get("logs") or []
    if not logs:
        return []
    lines = [
        "### Logs",
        "",
        "| log | training samples | held out | rest dropped at the start, s | at the end, s | "
        "held-out nMSE | held-out RMS, N m |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in logs:
        start, end = r.get("rest_dropped_s") or (0.0, 0.0)
        nmse = g3(r["mean_nmse"]) if "mean_nmse" in r else "-"
        rms = g3(quadratic_mean(torch.tensor(r["rms"]))) if r.get("rms") else "-"
        lines.append(
            f"| `{r['log']}` | {r['train_samples']} | {r['held_out_samples']} | {start:.3g} | "
            f"{end:.3g} | {nmse} | {rms} |"
        )
    return lines + [
        "",
        "nMSE: the mean over the joints; RMS: the quadratic mean over the joints.",
        "",
    ]


def _combinations_table(report) -> list[str]:
    """The base parameters that combine several parameters, with their values and spreads."""
    b = report.base
    if b is None:
        return []
    lines = [
        "### Base parameters that combine several parameters",
        "",
        "Each is `first + sum coef x other`: the data determine the combination, not its "
        f"terms. {SPREAD_NOTE}.",
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
    return lines + [""]


def _base_cells(row: Mapping[str, object], bound: float) -> list[str]:
    """One combination's identified, unconstrained and jackknife std cells; beyond ``bound``
    or not finite reads "off scale"."""
    cells = []
    for key in ("identified", "unconstrained", "jackknife_std"):
        v = row[key]
        if v is None:
            cells.append("-")
        elif not math.isfinite(v) or abs(v) > bound:
            cells.append("off scale")
        else:
            cells.append(f"{v:.4g}")
    return cells


def _parameters_table(
    rows: list[Mapping[str, object]], flagged: Mapping[str, torch.Tensor]
) -> list[str]:
    """Every parameter (``rows``: `IdentificationReport.parameter_rows`); ``flagged`` entries
    (`IdentificationReport.undetermined_entries`) read "off scale"."""
    lines = [
        "### Parameters",
        "",
        "identified: the physically consistent parameters (saved in `model.npz`); source: what "
        "fixes the identified value (data, data+description, description, ...); "
        "unconstrained: the estimator's; "
        f"{SPREAD_NOTE}; description: the robot file's value. Units: kg, kg m, kg m^2, "
        "N m s/rad, N m.",
        "",
        "| parameter | identified | source | unconstrained | jackknife std | description | data |",
        "|---|---|---|---|---|---|---|",
    ]
    n_flagged = 0
    for i, row in enumerate(rows):
        cells = _parameter_cells(row, i, flagged)
        n_flagged += cells.count("off scale")
        cells.append(str(row["data"] or "-"))
        lines.append(f"| {row['parameter']} | " + " | ".join(cells) + " |")
    if n_flagged:
        lines += [
            "",
            f"off scale ({n_flagged} entries): a value or spread beyond any physical scale, "
            f"more than {UNDETERMINED_FACTOR:.0e} times the largest |value| of that kind in "
            "the description (at least 1 kg, kg m, kg m^2, N m s/rad or N m), or not finite.",
        ]
    return lines


def _parameter_cells(
    row: Mapping[str, object], i: int, flagged: Mapping[str, torch.Tensor]
) -> list[str]:
    """Parameter ``i``'s identified, source, unconstrained, spread and description cells: "-"
    where the data give no value (not excited) or there is none, "off scale" where flagged."""
    cells = []
    for k in ("identified", "source", "unconstrained", "jackknife_std", "description"):
        v = row[k]
        if k == "source":
            cells.append(str(v))
        elif not row["excited"] and k in ("unconstrained", "jackknife_std"):
            cells.append("-")
        elif row["source"] == "none" and k == "identified":
            cells.append("-")
        elif k in flagged and bool(flagged[k][i]):
            cells.append("off scale")
        elif v is None:
            cells.append("-")
        else:
            cells.append(f"{v:.4g}")
    return cells
