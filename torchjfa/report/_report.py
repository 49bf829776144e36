"""`make_report` and `IdentificationReport`: the numbers behind the verdict, and the folder
`IdentificationReport.write` fills."""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .._util import output_folder
from ..data import JointLog
from ..metrics import nmse, rms
from ..physical import BaseParameters, ConsistencyReport, base_parameters, check
from ._appendix import appendix as appendix_lines
from ._descriptions import write_descriptions
from ._figures import parameters_figure, torques_figure
from ._markdown import report_markdown
from ._result import IdentificationResult
from ._verdict import Verdict, make_verdict
from ._words import (
    convergence,
    estimator_text,
    undetermined,
)

__all__ = ["IdentificationReport", "TorqueFit", "make_report", "predicted_torques", "torque_errors"]


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
    errors = nmse(predicted, tau, per_joint=True, allow_constant=True)  # inf: no variance
    return errors, rms(predicted, tau, per_joint=True)


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


#: the columns of ``parameters.csv``, in order (`IdentificationReport.csv_rows`)
_CSV_COLUMNS = (
    "parameter",
    "identified",
    "determined",
    "source",
    "data",
    "description",
    "unconstrained",
    "jackknife_std",
    "posterior_std",
    "relevance",
    "excited",
)


def _numbers(v) -> list:
    """A tensor as a JSON list (NaN and inf become None)."""
    out = []
    for x in torch.as_tensor(v, dtype=torch.float64).reshape(-1).tolist():
        out.append(x if math.isfinite(x) else None)
    return out


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
        data (zero up to rounding: `base_parameters`' "not excited", so that every count of
        the report agrees). Where it is, the data say nothing about the parameter (its
        unconstrained value is 0 by convention and the identified one comes from the
        projection alone)."""
        if self.base is not None:
            return torch.tensor([s != "not excited" for s in self.base.status])
        return torch.diagonal(self.result.moments.xtx).cpu() > 0

    def statuses(self) -> tuple[str, ...]:
        """Per parameter, what the data determine (`torchjfa.physical.BaseParameters.status`:
        ``"determined"``, ``"combination"``, ``"poorly excited"``, ``"not excited"``)."""
        if self.base is not None:
            return tuple(self.base.status)
        return ("not excited",) * self.model.n_params

    def sources(self) -> list[str]:
        """Per parameter, what fixes its identified value: ``"data"`` (determined by the data
        alone); for a parameter in a combination or poorly excited, ``"data+description"``
        (the data fix the combination, the description prior the rest), ``"data+projection"``
        (no description prior) or ``"estimator"`` (no projection); for a parameter not
        excited, ``"description"`` (pulled towards it by the description prior),
        ``"projection"`` (the consistency projection alone) or ``"none"`` (no projection: no
        value)."""
        r = self.result
        projected, prior = r.projection is not None, bool(r.prior_weight)
        silent = "description" if prior else "projection"
        words = {
            "determined": "data",
            "not excited": silent if projected else "none",
        }
        partly = f"data+{silent}" if projected else "estimator"
        return [words.get(s, partly) for s in self.statuses()]

    def warnings(self) -> list[str]:
        """Everything the user should know: the identification's warnings
        (``settings["warnings"]``) and the estimator's when it did not converge."""
        _, late = convergence(self.result.estimator)
        return [str(w) for w in self.settings.get("warnings", ())] + ([late] if late else [])

    def judge(self, model_path: str = "model.npz") -> Verdict:
        """The verdict (`torchjfa.report._verdict.make_verdict`): held-out error against the
        description's, consistency, what the data leave undetermined, the warnings and the
        next steps (the load step names ``model_path``)."""
        return make_verdict(self, model_path)

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
        `excited`), data (`statuses`), determined (the data determine it alone) and source
        (`sources`). The numbers are the estimators' as they are (0 for a parameter not
        excited); ``parameters.csv`` leaves those empty."""
        cols = {k: None if v is None else _numbers(v) for k, v in self._columns().items()}
        excited = self.excited.tolist()
        sources = self.sources()
        rows = []
        for i, name in enumerate(self.model.parameter_names):
            row: dict[str, object] = {"parameter": name}
            row.update({k: None if v is None else v[i] for k, v in cols.items()})
            row["excited"] = bool(excited[i])
            row["data"] = None if self.base is None else self.base.status[i]
            row["determined"] = row["data"] == "determined"
            row["source"] = sources[i]
            rows.append(row)
        return rows

    def csv_rows(self) -> list[dict[str, object]]:
        """The rows of ``parameters.csv``: `parameter_rows` with what the data do not give
        left empty (None): the estimates and spreads of a parameter not excited, and its
        identified value where nothing fixed it (source ``"none"``)."""
        rows = []
        for row in self.parameter_rows():
            row = {k: row[k] for k in _CSV_COLUMNS}
            if not row["excited"]:
                for k in ("unconstrained", "jackknife_std", "posterior_std", "relevance"):
                    row[k] = None
            if row["source"] == "none":
                row["identified"] = None
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
            "verdict": self.judge().summary(),
        }

    # ------------------------------------------------------------------------- figures
    def plot_torques(self, path=None, *, seconds: float | None = 10.0):
        """Measured and predicted held-out torque per joint (the first ``seconds``): one axes
        per joint titled with each prediction's nMSE, one legend below the axes
        (`torchjfa.report._figures.torques_figure`). Returns the `matplotlib.figure.Figure`,
        written to ``path`` when given."""
        kinds = dict(zip(self.model.joint_names, self.model.joint_types, strict=True))
        return torques_figure(self.validation, self.fits, kinds, path, seconds=seconds)

    def plot_parameters(self, path=None):
        """How far each unconstrained estimate lies from 0 in its spreads, grouped by body,
        every mark explained in a legend right of the axes
        (`torchjfa.report._figures.parameters_figure`). Returns the `matplotlib.figure.Figure`,
        written to ``path`` when given."""
        return parameters_figure(self.parameter_rows(), self.undetermined_entries(), path)

    # ------------------------------------------------------------------------- writing
    def _write_description(self, out: Path) -> dict[str, Path]:
        """The robot's description with the identified parameters, when they are consistent:
        ``identified.xml`` (MJCF: inertials, armature, damping, friction loss, a motor's terms
        on a fixed tendon) and, for a URDF robot, ``identified.urdf`` (inertials, ``<dynamics
        damping friction>``). Records in ``settings["description_file"]`` what was written or
        why not. Returns ``"description"`` (the file in the description's own format) and
        ``"mjcf"``."""
        if not self.consistency.weakly_ok:
            self.settings["description_file"] = "not written: the parameters are not consistent"
            return {}
        urdf = self.model.source_format == "urdf"
        written, what = write_descriptions(self.model, self.result.theta, out, urdf=urdf)
        if not urdf and "mjcf" in written:
            written["description"] = written["mjcf"]
        self.settings["description_file"] = what
        return written

    def markdown(
        self,
        images: Mapping[str, str] | None = None,
        *,
        folder: str | os.PathLike | None = None,
        appendix: bool = False,
    ) -> str:
        """The report as Markdown: the verdict, then one short section after the other
        (`torchjfa.report._markdown.report_markdown`).

        Args:
            images: caption -> relative PNG path of each figure.
            folder: the report's folder (the verdict's load step names its ``model.npz``).
            appendix: end with the long tables (every parameter, the base-parameter
                combinations, each log, each body; `torchjfa.report._appendix.appendix`).
        """
        text = report_markdown(self, images, folder=folder, appendix=appendix)
        if appendix:
            text += "\n".join(appendix_lines(self)) + "\n"
        return text

    def write(
        self,
        out_dir: str | os.PathLike,
        *,
        plots: bool = True,
        appendix: bool = False,
        overwrite: bool = False,
        inputs: Iterable[str | os.PathLike] = (),
        command: str = "",
    ) -> dict[str, Path]:
        """Write the model, data, tables, figures and Markdown report into ``out_dir``
        (``appendix``: the long tables at the end of ``report.md``, see `markdown`), as one
        unit (`torchjfa.io.output_folder`): a run killed while writing leaves the earlier
        folder as it was, and no file of an earlier result stays beside the new ones.

        Args:
            overwrite: replace ``out_dir`` even where it holds files the library did not write.
            inputs, command: the logs and the description it came from, and the command line,
                for the folder's ``manifest.json``.

        Returns:
            name -> path of each file written.

        Raises:
            torchjfa.io.OutputError: ``out_dir`` is a file or a symbolic link, holds files the
                library did not write (without ``overwrite``), or another run is writing it.
        """
        out = Path(out_dir)
        with output_folder(out, overwrite=overwrite, inputs=inputs, command=command) as stage:
            written = self._write_files(stage, out, plots=plots, appendix=appendix)
        return {key: out / path.name for key, path in written.items()}

    def _write_files(self, stage: Path, out: Path, *, plots: bool, appendix: bool):
        """Every file of `write` into ``stage`` (``out``: the folder they will be read from)."""
        from ..io import save_identified

        paths = {
            "model": stage / "model.npz",
            "validation": stage / "validation.npz",
            "parameters": stage / "parameters.csv",
            "json": stage / "report.json",
            "markdown": stage / "report.md",
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
        prep = self.settings.get("prepare") or {}
        if isinstance(prep, Mapping) and prep.get("cutoff_hz") is not None:
            extras["cutoff_hz"] = float(prep["cutoff_hz"])  # `torchjfa evaluate` prepares with it
        save_identified(paths["model"], self.model, self.result.theta, **extras)
        paths.update(self._write_description(stage))
        v = self.validation
        np.savez_compressed(
            paths["validation"],
            t=v.t.numpy(),
            joint_names=np.array(v.joint_names, dtype=np.str_),
            **{k: x.numpy() for k, x in v.signals().items()},
        )
        with open(paths["parameters"], "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(_CSV_COLUMNS))
            w.writeheader()
            w.writerows({k: "" if x is None else x for k, x in r.items()} for r in self.csv_rows())
        images = {}
        if plots:
            paths["torques"] = stage / "torques.png"
            paths["parameters_png"] = stage / "parameters.png"
            self.plot_torques(paths["torques"])
            self.plot_parameters(paths["parameters_png"])
            images = {
                "Held-out torques, measured and predicted": "torques.png",
                "Parameters: how many spreads each estimate lies from 0": "parameters.png",
            }
        with open(paths["json"], "w") as fh:
            json.dump(self.summary(), fh, indent=1, default=str)
        paths["markdown"].write_text(self.markdown(images, folder=out, appendix=appendix))
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
    nominal = model.description_theta  # its inertials, damping and friction as it states them
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
