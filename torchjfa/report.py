"""A report a person can read: what was identified, how far to trust it, how well it predicts.

`make_report` takes an `IdentificationResult` and held-out data and measures what a user needs
before putting the identified model in a controller:

* per parameter: the consistent (projected) value, the estimator's unconstrained value, its
  spread (the delete-one-block jackknife, and Bayesian JFA's posterior standard deviation),
  Bayesian JFA's relevance, and the description's (CAD) value;
* the physical-consistency check (`torchjfa.physical.check`) of both estimates;
* held-out torque nMSE and RMS error per joint for the identified model, the unconstrained
  estimate and the description's parameters;
* noise: the estimator's output noise and, with a periodic excitation, the spread between
  periods of positions, velocities, accelerations and torques.

`IdentificationReport.write` puts it in a folder: ``model.npz`` (`torchjfa.io.load_identified`
reads it), ``validation.npz`` (the held-out q, qd, qdd, tau the figures were computed on),
``parameters.csv``, ``report.json``, ``report.md`` and the PNG figures.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ._report_figures import parameters_figure, torques_figure
from .data import JointLog
from .metrics import nmse, rms
from .physical import BaseParameters, ConsistencyReport, base_parameters, check
from .physical._base import parameter_kind
from .pipeline import IdentificationResult

__all__ = [
    "TorqueFit",
    "IdentificationReport",
    "make_report",
    "predicted_torques",
    "torque_errors",
    "estimator_text",
    "undetermined",
    "verdict",
    "UNDETERMINED_FACTOR",
]


@dataclass(frozen=True)
class TorqueFit:
    """How one parameter vector predicts held-out torques.

    Attributes:
        nmse: ``(n_dof,)`` mean squared error over the variance of the measured torque.
        rms: ``(n_dof,)`` RMS error, N m (N for prismatic joints).
        predicted: ``(n_samples, n_dof)`` predicted torques.
    """

    nmse: torch.Tensor
    rms: torch.Tensor
    predicted: torch.Tensor = field(repr=False)

    @property
    def mean_nmse(self) -> float:
        return float(self.nmse.mean())


def torque_errors(tau, predicted) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-joint ``(nMSE, RMS)`` of ``predicted`` against ``tau``, both ``(n_samples, n_dof)``.

    nMSE is ``mean((tau - predicted)^2) / var(tau)`` (population variance) per joint: the one
    definition, `torchjfa.metrics.nmse`; RMS in N m (`torchjfa.metrics.rms`). Array-likes are
    read as float64.
    """
    tau = torch.as_tensor(tau, dtype=torch.float64)
    predicted = torch.as_tensor(predicted, dtype=torch.float64)
    return nmse(predicted, tau, per_joint=True), rms(predicted, tau, per_joint=True)


def predicted_torques(model, theta, q, qd, qdd, tau) -> torch.Tensor:
    """``Y(q, qd, qdd) theta``, ``(n_samples, n_dof)``, formed chunk by chunk
    (`RigidBodyModel.regressor_chunks`: memory ``O(chunk * n_dof * n_params)``); ``tau`` only
    fixes the shapes."""
    theta = torch.as_tensor(theta, dtype=torch.float64)
    rows = [Y @ theta for Y, _ in model.regressor_chunks(q, qd, qdd, tau)]
    return torch.cat(rows).reshape(-1, model.n_dof)


def _fit(result: IdentificationResult, log: JointLog, theta: torch.Tensor) -> TorqueFit:
    pred = predicted_torques(result.model, theta, log.q, log.qd, log.qdd, log.tau)
    nmse, rms = torque_errors(log.tau, pred)
    return TorqueFit(nmse=nmse, rms=rms, predicted=pred)


def _numbers(v) -> list:
    """A tensor as a JSON list (NaN and inf become None)."""
    out = []
    for x in torch.as_tensor(v, dtype=torch.float64).reshape(-1).tolist():
        out.append(x if math.isfinite(x) else None)
    return out


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


@dataclass(eq=False)
class IdentificationReport:
    """Everything `make_report` measured; `write` saves it with figures and Markdown.

    Attributes:
        result: the `IdentificationResult`.
        validation: the held-out `JointLog` (prepared: q, qd, qdd, tau).
        fits: name -> `TorqueFit` on the validation data: ``"identified"`` (the consistent
            parameters, the saved model), ``"unconstrained"`` (the estimator's), and
            ``"description"`` (the description's inertials) when the description has mass.
        consistency: `ConsistencyReport` of the identified parameters.
        consistency_unconstrained: `ConsistencyReport` of the unconstrained estimate.
        noise: noise estimates (see `make_report`).
        settings: how the data were prepared and the model identified (for the record).
        base: `torchjfa.physical.BaseParameters` of the training moments (what the data
            determine), or None when they excite nothing.
    """

    result: IdentificationResult
    validation: JointLog
    fits: dict[str, TorqueFit]
    consistency: ConsistencyReport
    consistency_unconstrained: ConsistencyReport
    noise: dict[str, object]
    settings: dict[str, object]
    base: BaseParameters | None = None

    @property
    def model(self):
        return self.result.model

    @property
    def excited(self) -> torch.Tensor:
        """``(n_params,)`` bool: the parameter's regressor column is not zero in the training
        data. Where it is, the data say nothing about the parameter (its unconstrained value
        is 0 by convention and the identified one comes from the projection alone)."""
        return torch.diagonal(self.result.moments.xtx) > 0

    def _columns(self) -> dict[str, torch.Tensor | None]:
        """The parameter table's columns as float64 tensors (NaN and inf kept), None where the
        estimator has no such column."""
        r = self.result
        est = r.estimator
        cols = {
            "identified": r.theta,
            "unconstrained": r.theta_hat,
            "jackknife_std": r.theta_hat_std,
            "posterior_std": getattr(est, "coef_std_", None),
            "relevance": getattr(est, "relevance_", None),
            "description": self.model.nominal_theta,
        }
        return {
            k: None if v is None else torch.as_tensor(v, dtype=torch.float64).reshape(-1).cpu()
            for k, v in cols.items()
        }

    def undetermined_entries(self) -> dict[str, torch.Tensor]:
        """Column -> ``(n_params,)`` bool: where the identified value, the unconstrained value
        or a spread lies beyond any physical scale or is not finite (`undetermined`); only the
        columns the estimator has."""
        cols = self._columns()
        names = self.model.parameter_names
        nominal = cols["description"]
        return {
            k: undetermined(cols[k], names, nominal)
            for k in ("identified", "unconstrained", "jackknife_std", "posterior_std")
            if cols[k] is not None
        }

    def parameter_rows(self) -> list[dict[str, object]]:
        """One dict per parameter: name, identified, unconstrained, jackknife_std,
        posterior_std, relevance, description (None where not available), excited (see
        `excited`)."""
        cols = {k: None if v is None else _numbers(v) for k, v in self._columns().items()}
        excited = self.excited.tolist()
        rows = []
        for i, name in enumerate(self.model.parameter_names):
            row: dict[str, object] = {"parameter": name}
            row.update({k: None if v is None else v[i] for k, v in cols.items()})
            row["excited"] = bool(excited[i])
            row["data"] = None if self.base is None else self.base.status[i]
            rows.append(row)
        return rows

    def base_rows(self) -> list[dict[str, object]]:
        """One dict per base parameter (`torchjfa.physical.base_parameters`): the combination
        as text, its unconstrained and identified values, its least-squares std and its
        jackknife spread (None without ``identify(..., jackknife=K)``)."""
        b = self.base
        if b is None:
            return []
        r = self.result
        values = {
            "unconstrained": b.values(r.theta_hat.cpu()),
            "identified": b.values(r.theta.cpu()),
        }
        jack = (
            None if r.theta_hat_jackknife is None else b.jackknife_std(r.theta_hat_jackknife.cpu())
        )
        rows = []
        for k, text in enumerate(b.combinations()):
            rows.append(
                {
                    "combination": text,
                    "identified": float(values["identified"][k]),
                    "unconstrained": float(values["unconstrained"][k]),
                    "ls_std": float(b.std[k]),
                    "jackknife_std": None if jack is None else float(jack[k]),
                }
            )
        return rows

    def _base_markdown(self) -> list[str]:
        """The section "What the data determine" (`base_parameters` of the training data)."""
        b = self.base
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
            "other`; the data determine the combination, not its terms); std: least squares "
            "(white noise, a lower bound); jackknife: delete-one-block spread.",
            "",
            "| base parameter | identified | unconstrained | std | jackknife std |",
            "|---|---|---|---|---|",
        ]
        n = 0
        for k, row in enumerate(self.base_rows()):
            if " + " not in row["combination"] and " - " not in row["combination"]:
                continue
            n += 1
            # beyond any physical scale (as in the parameter table): the first term's scale
            bound = UNDETERMINED_FACTOR * max(float(b.scales[b.independent[k]]), _UNIT_SCALE)
            cells = []
            for key, fmt in (
                ("identified", ".4g"),
                ("unconstrained", ".4g"),
                ("ls_std", ".3g"),
                ("jackknife_std", ".3g"),
            ):
                v = row[key]
                if v is None:
                    cells.append("-")
                elif not math.isfinite(v) or abs(v) > bound:
                    cells.append("undetermined")
                else:
                    cells.append(format(v, fmt))
            lines.append(f"| {row['combination']} | " + " | ".join(cells) + " |")
        if not n:
            lines.append("| (none: every base parameter is a single parameter) | | | | |")
        r = self.result
        if r.prior_weight is not None:
            how = ""
            if r.prior_choice:
                how = (
                    " (chosen by cross-validation over the training blocks: "
                    + ", ".join(f"{w:g}: {v:.4g} N m" for w, v in r.prior_choice.items())
                    + ")"
                )
            edge = ""
            if r.prior_choice and r.prior_weight == max(r.prior_choice) > 0:
                edge = (
                    " The largest weight tried won: the held-out blocks prefer the description "
                    "even where the data have a say (prior std = each kind's typical size / "
                    f"{math.sqrt(r.prior_weight):.3g})."
                )
            lines += [
                "",
                f"Where the data are silent the projection was pulled towards the description "
                f"with weight {r.prior_weight:g}{how}.{edge}",
            ]
        return lines + [""]

    def summary(self) -> dict[str, object]:
        """The report's numbers as plain JSON-ready values."""
        r = self.result
        return {
            "robot": self.settings.get("robot"),
            "joint_names": list(self.model.joint_names),
            "n_params": self.model.n_params,
            "estimator": estimator_text(r.estimator),
            "train_samples": r.n_samples,
            "validation_samples": self.validation.n_samples,
            "train_rmse": r.rmse(),
            "converged": bool(getattr(r.estimator, "converged_", True)),
            "n_iter": int(r.estimator.n_iter_) if hasattr(r.estimator, "n_iter_") else None,
            "stop_reason": getattr(r.estimator, "stop_reason_", None),
            "validation": {
                name: {"nmse": _numbers(f.nmse), "rms": _numbers(f.rms), "mean_nmse": f.mean_nmse}
                for name, f in self.fits.items()
            },
            "consistent": self.consistency.ok,
            "consistent_weakly": self.consistency.weakly_ok,
            "unconstrained_consistent": self.consistency_unconstrained.ok,
            "unconstrained_consistent_weakly": self.consistency_unconstrained.weakly_ok,
            "noise": self.noise,
            "settings": self.settings,
            "parameters": self.parameter_rows(),
            "base_parameters": None
            if self.base is None
            else {
                "rank": self.base.rank,
                "n_determined": self.base.n_determined,
                "condition_number": self.base.condition_number,
                "counts": self.base.counts(),
                "combinations": self.base_rows(),
            },
            "prior_weight": self.result.prior_weight,
        }

    # ------------------------------------------------------------------------- figures
    def plot_torques(self, path=None, *, seconds: float | None = 10.0):
        """Measured and predicted held-out torque per joint (the first ``seconds``): one axes
        per joint titled with each prediction's nMSE, one legend below the axes
        (`torchjfa._report_figures.torques_figure`). Returns the `matplotlib.figure.Figure`,
        written to ``path`` when given."""
        kinds = dict(zip(self.model.joint_names, self.model.joint_types, strict=True))
        return torques_figure(self.validation, self.fits, kinds, path, seconds=seconds)

    def plot_parameters(self, path=None):
        """How far each unconstrained estimate lies from 0 in its spreads, grouped by body,
        every mark explained in a legend right of the axes
        (`torchjfa._report_figures.parameters_figure`). Returns the `matplotlib.figure.Figure`,
        written to ``path`` when given."""
        return parameters_figure(self.parameter_rows(), self.undetermined_entries(), path)

    # ------------------------------------------------------------------------- writing
    def _noise_mode(self) -> str:
        """``"; input noise: ..."`` from the settings' input-noise mode ("" without one)."""
        mode = self.settings.get("input_noise")
        if not mode:
            return ""
        text = _NOISE_MODES.get(str(mode), str(mode))
        if not hasattr(self.result.estimator, "input_noise"):  # OLS, ridge, ...: projection only
            return f"; input noise ({text}) used in the projection's metric only"
        return f"; input noise: {text}"

    def markdown(self, images: Mapping[str, str] | None = None) -> str:
        """The report as Markdown (``images``: caption -> relative PNG path)."""
        s = self.summary()
        joints = self.model.joint_names
        convergence, warning = _convergence(self.result.estimator)
        lines = [
            f"# Identification report: {s['robot'] or Path(self.model.source_path or 'robot').name}",
            "",
            f"- log: `{self.settings.get('log', '-')}`; {s['train_samples']} samples for "
            f"identification, {s['validation_samples']} held out"
            + (f" ({self.settings['validation']})" if self.settings.get("validation") else ""),
            *(
                [f"- data: {self.settings['preparation']}"]
                if self.settings.get("preparation")
                else []
            ),
            *([f"- cut-off: {self.settings['cutoff']}"] if self.settings.get("cutoff") else []),
            f"- model: {self.model.n_dof} joints, {self.model.n_params} parameters, friction "
            f"{', '.join(self.model.friction) or 'none'}",
            f"- estimator: `{s['estimator']}`" + self._noise_mode(),
            f"- convergence: {convergence}",
            *([f"- {warning}"] if warning else []),
            *(f"- warning: {w}" for w in self.settings.get("warnings", ())),
            f"- physically consistent, identified: {verdict(self.consistency)}; "
            f"unconstrained estimate: {verdict(self.consistency_unconstrained)}",
            f"- training RMS torque error: {s['train_rmse']:.4g} N m",
            "",
            "## Held-out torque prediction",
            "",
            "nMSE = mean squared error / variance of the measured torque (0 is perfect, 1 is "
            "no better than the mean); RMS in N m.",
            "",
        ]
        names = list(self.fits)
        head = "| joint | " + " | ".join(f"{n} nMSE | {n} RMS" for n in names) + " |"
        lines += [head, "|---" * (1 + 2 * len(names)) + "|"]
        for j, jn in enumerate(joints):
            cells = []
            for n in names:
                f = self.fits[n]
                cells += [f"{float(f.nmse[j]):.4g}", f"{float(f.rms[j]):.4g}"]
            lines.append(f"| {jn} | " + " | ".join(cells) + " |")
        means = []
        for n in names:
            f = self.fits[n]
            means += [f"**{f.mean_nmse:.4g}**", f"**{float(f.rms.pow(2).mean().sqrt()):.4g}**"]
        lines.append("| all | " + " | ".join(means) + " |")
        lines += [
            "",
            "all: nMSE is the mean over the joints; RMS is the quadratic mean over the joints, "
            "sqrt(mean of the squared per-joint RMS), in N m.",
        ]
        lines += ["", "## Noise", ""]
        for k, v in self.noise.items():
            if isinstance(v, list):
                v = ", ".join("-" if x is None else f"{x:.3g}" for x in v)
            lines.append(f"- {k}: {v}")
        lines += ["", "## Physical consistency of the identified parameters", "", "```"]
        lines += [self.consistency.table(), "```", ""]
        lines += self._base_markdown()
        lines += [
            "## Parameters",
            "",
            "identified: the physically consistent parameters (saved in `model.npz`); "
            "unconstrained: the estimator's; jackknife std: spread of the unconstrained "
            "estimate over delete-one-block refits; posterior std: Bayesian JFA's mean-field "
            "spread (a lower bound, see docs/report.md); relevance: Bayesian JFA's <alpha> "
            "(large means the data call the parameter irrelevant); description: the robot "
            "file's value; data: what the data determine (see above: determined, combination, "
            "poorly excited, zero column). Units: kg, kg m, "
            "kg m^2, N m s/rad, N m.",
            "",
            "| parameter | identified | unconstrained | jackknife std | posterior std | "
            "relevance | description | data |",
            "|---|---|---|---|---|---|---|---|",
        ]

        rows = s["parameters"]
        value_cols = ("identified", "unconstrained", "jackknife_std", "posterior_std")
        flagged = self.undetermined_entries()
        n_flagged = n_silent = 0
        for i, row in enumerate(rows):
            cells = []
            for k in (*value_cols, "relevance", "description"):
                v = row[k]
                if not row["excited"] and k in ("unconstrained", "jackknife_std", "posterior_std"):
                    cells.append("not excited" if k == "unconstrained" else "-")
                elif k in flagged and bool(flagged[k][i]):
                    cells.append("undetermined")
                    n_flagged += 1
                elif v is None:
                    cells.append("-")
                else:
                    cells.append(f"{v:.4g}")
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
        if images:
            lines += ["", "## Figures", ""]
            for caption, rel in images.items():
                lines += [f"![{caption}]({rel})", ""]
        if self.settings.get("command"):
            lines += ["", "## Reproduce", "", "```", str(self.settings["command"]), "```"]
        return "\n".join(lines) + "\n"

    def write(self, out_dir: str | os.PathLike, *, plots: bool = True) -> dict[str, Path]:
        """Write the model, data, tables, figures and Markdown report into ``out_dir``.

        Returns:
            name -> path of each file written.
        """
        from .io import save_identified

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        paths = {
            "model": out / "model.npz",
            "validation": out / "validation.npz",
            "parameters": out / "parameters.csv",
            "json": out / "report.json",
            "markdown": out / "report.md",
        }
        fit = self.fits["identified"]
        est = self.result.estimator
        extras = {
            "validation_nmse": fit.nmse.numpy(),
            "validation_rms": fit.rms.numpy(),
            "estimator": type(est).__name__,
        }
        if hasattr(est, "noise_y_"):
            extras["output_noise"] = float(est.noise_y_)
        save_identified(paths["model"], self.model, self.result.theta, **extras)
        v = self.validation
        np.savez_compressed(
            paths["validation"],
            t=v.t.numpy(),
            joint_names=np.array(v.joint_names, dtype=np.str_),
            **{k: x.numpy() for k, x in v.signals().items()},
        )
        rows = self.parameter_rows()
        with open(paths["parameters"], "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows({k: "" if x is None else x for k, x in r.items()} for r in rows)
        images = {}
        if plots:
            paths["torques"] = out / "torques.png"
            paths["parameters_png"] = out / "parameters.png"
            self.plot_torques(paths["torques"])
            self.plot_parameters(paths["parameters_png"])
            images = {
                "Held-out torques, measured and predicted": "torques.png",
                "Parameters: how many spreads each estimate lies from 0": "parameters.png",
            }
        with open(paths["json"], "w") as fh:
            json.dump(self.summary(), fh, indent=1, default=str)
        paths["markdown"].write_text(self.markdown(images))
        return paths


def make_report(
    result: IdentificationResult,
    validation: JointLog,
    *,
    period_noise=None,
    settings: Mapping[str, object] | None = None,
) -> IdentificationReport:
    """Measure an identification on held-out data.

    Args:
        result: from `torchjfa.identify` (``jackknife=K`` fills the spread column).
        validation: held-out prepared `JointLog` (q, qd, qdd, tau), joints in any order.
        period_noise: a `torchjfa.data.PeriodNoise` of the training data (the spread between
            excitation periods), or None.
        settings: free-form record of how the data were prepared and identified (JSON-ready).

    Returns:
        An `IdentificationReport`.
    """
    model = result.model
    validation = validation.reorder(model.joint_names)
    if validation.qd is None or validation.qdd is None:
        raise ValueError("the validation log needs q, qd, qdd and tau; prepare it first")
    fits = {
        "identified": _fit(result, validation, result.theta),
        "unconstrained": _fit(result, validation, result.theta_hat),
    }
    nominal = model.nominal_theta
    if bool((nominal != 0).any()):
        fits["description"] = _fit(result, validation, nominal)
    noise: dict[str, object] = {}
    est = result.estimator
    if hasattr(est, "noise_y_"):
        noise["estimator output noise std, N m"] = math.sqrt(max(float(est.noise_y_), 0.0))
    if result.joint_weights is None:
        noise["training residual RMS, N m"] = result.rmse()
    else:
        noise["joint weights (weighted least squares, mean 1)"] = _numbers(result.joint_weights)
        noise["training residual RMS of the weighted equations"] = result.rmse()
    if period_noise is not None:
        noise["excitation periods used"] = int(period_noise.n_periods)
        for k, unit in (("q", "rad"), ("qd", "rad/s"), ("qdd", "rad/s^2")):
            noise[f"{k} noise std per joint, {unit}"] = _numbers(
                period_noise.signal_noise[k].sqrt()
            )
        noise["torque noise std per joint, N m"] = _numbers(
            period_noise.output_noise_per_joint.sqrt()
        )
    try:
        base = base_parameters(result.moments, model)
    except ValueError:  # the data excite nothing: the report says so
        base = None
    return IdentificationReport(
        base=base,
        result=result,
        validation=validation,
        fits=fits,
        consistency=check(result.theta, model),
        consistency_unconstrained=check(result.theta_hat, model),
        noise=noise,
        settings=dict(settings or {}),
    )
