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

from .data import JointLog
from .physical import ConsistencyReport, check
from .pipeline import IdentificationResult

__all__ = [
    "TorqueFit",
    "IdentificationReport",
    "make_report",
    "predicted_torques",
    "torque_errors",
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

    nMSE is ``mean((tau - predicted)^2) / var(tau)`` (population variance) per joint.
    """
    tau = torch.as_tensor(tau, dtype=torch.float64)
    err = torch.as_tensor(predicted, dtype=torch.float64) - tau
    mse = err.pow(2).mean(0)
    return mse / tau.var(0, correction=0), mse.sqrt()


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


def _figure(path, rows: int, **kw):
    """A figure with ``rows`` stacked axes: through pyplot for display, or, when it is only
    saved to ``path``, a bare `matplotlib.figure.Figure` (pyplot's backend is left alone, so
    inline figures in a notebook keep working)."""
    if path is None:
        import matplotlib.pyplot as plt

        return plt.subplots(rows, 1, squeeze=False, **kw)
    from matplotlib.figure import Figure

    fig = Figure(figsize=kw.pop("figsize"))
    return fig, fig.subplots(rows, 1, squeeze=False, **kw)


def _verdict(c: ConsistencyReport) -> str:
    if c.ok:
        return "yes (fully: pseudo-inertia positive definite)"
    if c.weakly_ok:
        return (
            "mass > 0 and inertia PSD (the seed's eq. 5) yes, triangle inequalities no "
            "(--parametrization log-cholesky enforces them)"
        )
    return "NO"


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
    """

    result: IdentificationResult
    validation: JointLog
    fits: dict[str, TorqueFit]
    consistency: ConsistencyReport
    consistency_unconstrained: ConsistencyReport
    noise: dict[str, object]
    settings: dict[str, object]

    @property
    def model(self):
        return self.result.model

    def parameter_rows(self) -> list[dict[str, object]]:
        """One dict per parameter: name, identified, unconstrained, jackknife_std,
        posterior_std, relevance, description (None where not available)."""
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
        cols = {k: None if v is None else _numbers(v) for k, v in cols.items()}
        rows = []
        for i, name in enumerate(self.model.parameter_names):
            row: dict[str, object] = {"parameter": name}
            row.update({k: None if v is None else v[i] for k, v in cols.items()})
            rows.append(row)
        return rows

    def summary(self) -> dict[str, object]:
        """The report's numbers as plain JSON-ready values."""
        r = self.result
        return {
            "robot": self.settings.get("robot"),
            "joint_names": list(self.model.joint_names),
            "n_params": self.model.n_params,
            "estimator": repr(r.estimator),
            "train_samples": r.n_samples,
            "validation_samples": self.validation.n_samples,
            "train_rmse": r.rmse(),
            "converged": bool(getattr(r.estimator, "converged_", True)),
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
        }

    # ------------------------------------------------------------------------- figures
    def plot_torques(self, path=None, *, seconds: float | None = 10.0):
        """Measured and predicted held-out torque per joint (the first ``seconds``)."""
        log = self.validation
        t = (log.t - log.t[0]).numpy()
        n = log.n_samples if seconds is None else int(np.searchsorted(t, seconds, side="right"))
        n = max(n, 2)
        n_dof = log.n_dof
        fig, axes = _figure(path, n_dof, figsize=(9, 1.7 * n_dof + 0.6), sharex=True)
        styles = {
            "identified": {"color": "C1", "lw": 1.2},
            "unconstrained": {"color": "C2", "lw": 0.9, "ls": "--"},
            "description": {"color": "C7", "lw": 0.9, "ls": ":"},
        }
        for j, ax in enumerate(axes[:, 0]):
            ax.plot(t[:n], log.tau[:n, j].numpy(), color="k", lw=0.8, label="measured")
            for name, fit in self.fits.items():
                label = f"{name} (nMSE {float(fit.nmse[j]):.3g})"
                ax.plot(t[:n], fit.predicted[:n, j].numpy(), label=label, **styles.get(name, {}))
            ax.set_ylabel(f"{log.joint_names[j]}\n[N m]", fontsize=8)
            ax.legend(fontsize=6, loc="upper right", ncol=4)
        axes[-1, 0].set_xlabel("time into the held-out data [s]")
        fig.suptitle("Held-out torque: measured and predicted", fontsize=10)
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=110)
        return fig

    def plot_parameters(self, path=None):
        """Per parameter: |value| over its jackknife spread, and the relevance when known."""
        rows = self.parameter_rows()
        names = [r["parameter"] for r in rows]
        x = np.arange(len(rows))
        panels = []
        if self.result.theta_hat_std is not None:
            ratio = [
                abs(r["unconstrained"]) / r["jackknife_std"] if r["jackknife_std"] else np.nan
                for r in rows
            ]
            panels.append(("|unconstrained| / jackknife std", ratio, 2.0))
        if any(r["relevance"] is not None for r in rows):
            rel = [np.nan if r["relevance"] is None else r["relevance"] for r in rows]
            panels.append(("relevance <alpha> (large: irrelevant)", rel, None))
        if not panels:
            panels.append(("|identified|", [abs(r["identified"]) for r in rows], None))
        width = max(8, 0.12 * len(rows))
        fig, axes = _figure(path, len(panels), figsize=(width, 2.6 * len(panels)))
        for ax, (title, vals, line) in zip(axes[:, 0], panels, strict=True):
            vals = np.asarray(vals, dtype=float)
            ax.bar(x, np.where(np.isfinite(vals) & (vals > 0), vals, np.nan), color="C0")
            ax.set_yscale("log")
            ax.set_title(title, fontsize=9)
            if line is not None:
                ax.axhline(line, color="C3", lw=0.8, ls="--")
            ax.set_xticks(x, names, rotation=90, fontsize=5)
            ax.set_xlim(-1, len(rows))
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=110)
        return fig

    # ------------------------------------------------------------------------- writing
    def markdown(self, images: Mapping[str, str] | None = None) -> str:
        """The report as Markdown (``images``: caption -> relative PNG path)."""
        s = self.summary()
        joints = self.model.joint_names
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
            f"- model: {self.model.n_dof} joints, {self.model.n_params} parameters, friction "
            f"{', '.join(self.model.friction) or 'none'}",
            f"- estimator: `{s['estimator']}`"
            + (
                ""
                if s["converged"]
                else f" **did not converge** ({s['stop_reason']}): raise --max-iter"
            ),
            f"- physically consistent, identified: {_verdict(self.consistency)}; "
            f"unconstrained estimate: {_verdict(self.consistency_unconstrained)}",
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
        lines += ["", "## Noise", ""]
        for k, v in self.noise.items():
            if isinstance(v, list):
                v = ", ".join("-" if x is None else f"{x:.3g}" for x in v)
            lines.append(f"- {k}: {v}")
        lines += ["", "## Physical consistency of the identified parameters", "", "```"]
        lines += [self.consistency.table(), "```", ""]
        lines += [
            "## Parameters",
            "",
            "identified: the physically consistent parameters (saved in `model.npz`); "
            "unconstrained: the estimator's; jackknife std: spread of the unconstrained "
            "estimate over delete-one-block refits; posterior std: Bayesian JFA's mean-field "
            "spread (a lower bound, see docs/report.md); relevance: Bayesian JFA's <alpha> "
            "(large means the data call the parameter irrelevant); description: the robot "
            "file's value. Units: kg, kg m, kg m^2, N m s/rad, N m.",
            "",
            "| parameter | identified | unconstrained | jackknife std | posterior std | "
            "relevance | description |",
            "|---|---|---|---|---|---|---|",
        ]

        def fmt(v):
            return "-" if v is None else f"{v:.4g}"

        for row in s["parameters"]:
            lines.append(
                f"| {row['parameter']} | "
                + " | ".join(
                    fmt(row[k])
                    for k in (
                        "identified",
                        "unconstrained",
                        "jackknife_std",
                        "posterior_std",
                        "relevance",
                        "description",
                    )
                )
                + " |"
            )
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
                "Parameters: value over spread, relevance": "parameters.png",
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
        period_noise: a `torchjfa.sim.PeriodNoise` of the training data (the spread between
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
    return IdentificationReport(
        result=result,
        validation=validation,
        fits=fits,
        consistency=check(result.theta, model),
        consistency_unconstrained=check(result.theta_hat, model),
        noise=noise,
        settings=dict(settings or {}),
    )
