"""What the robot experiments return and how it reads: `RobotResult`, the paper's tables, the goal.

`Identified` and `RobotResult` hold one robot's run of `experiments.robots.run_robot`;
`format_table` prints it in the paper's layout (Tables I and II), `goal_check` tests the issue's
goal over the robots and `plot_tracking` draws the per-joint tracking errors. All of them are
re-exported by `experiments.robots`; import them from there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch

from torchjfa.sim import ControlResult, PeriodNoise

__all__ = [
    "LABELS",
    "METHODS",
    "REFERENCE",
    "Identified",
    "RobotResult",
    "format_table",
    "goal_check",
    "plot_tracking",
]

METHODS = ("ridge", "bjfa", "bjfa-noise", "lasso", "stepwise")
REFERENCE = "true"
LABELS = {
    "ridge": "Ridge regression + GD (virtual)",
    "bjfa": "Bayesian JFA (seed) + projection",
    "bjfa-noise": "Bayesian JFA (noise-informed) + proj.",
    "lasso": "LASSO regression + projection",
    "stepwise": "Stepwise regression + projection",
    REFERENCE: "True parameters (reference)",
}


@dataclass
class Identified:
    """One method's identification.

    Attributes:
        method: key in `METHODS`.
        theta_hat: ``(n_params,)`` the unconstrained estimate, float64.
        theta: ``(n_params,)`` the projected, physically consistent estimate.
        estimator: the fitted estimator.
        fit_s, project_s: wall time of the fit and of the projection, s.
        consistent_before: theta_hat passes `check` (full physical consistency).
        consistent_after: theta passes eq. 5's conditions (mass, PSD I_c, friction).
        projection_cost: eq. 8 at theta (growth of the training residual sum of squares, N^2 m^2).
        projection_converged: the projection's stopping test was met.
        warnings: the estimator's warnings (e.g. LASSO not converged), recorded not raised.
    """

    method: str
    theta_hat: torch.Tensor
    theta: torch.Tensor
    estimator: object
    fit_s: float
    project_s: float
    consistent_before: bool
    consistent_after: bool
    projection_cost: float
    projection_converged: bool
    warnings: tuple[str, ...] = ()


@dataclass
class RobotResult:
    """Everything `run_robot` measured for one robot.

    Attributes:
        robot: ``"head"`` or ``"arm"``.
        rows: one dict per method and the reference, in table order (keys: ``robot, method,
            label, success, reason, rms_position`` (rad), ``rms_velocity`` (rad/s),
            ``rms_feedback`` (N m), each averaged over joints, ``nmse_clean, nmse_measured,
            fit_s, project_s, consistent_before, consistent_after, projection_cost``).
        identified: method -> `Identified`.
        control: method (and `REFERENCE`) -> `ControlResult`.
        noise: the `PeriodNoise` estimated from the training log.
        settings: the run's sizes and choices. timings: wall time per stage, s.
    """

    robot: str
    rows: list[dict]
    identified: dict[str, Identified]
    control: dict[str, ControlResult]
    noise: PeriodNoise
    settings: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def _fmt(v: float, ok: bool) -> str:
    return f"{v:>10.4f}" if ok else f"{'FAILURE':>10}"


def format_table(result: RobotResult) -> str:
    """The paper's layout: rows = methods, columns = RMS position (rad), velocity (rad/s),
    feedback command (N m) averaged over joints (FAILURE where the run failed), then held-out
    torque nMSE (noiseless and measured test signals) and fit + projection time."""
    s = result.settings
    head = (
        f"{'method':<40} {'pos (rad)':>10} {'vel (rad/s)':>11} {'fb (N m)':>10} "
        f"{'nMSE clean':>10} {'nMSE meas':>10} {'fit s':>7} {'proj s':>7}"
    )
    lines = [
        f"{result.robot}: {s['n_params']} parameters, {s['n_samples']} training samples at "
        f"{s['control_rate']:g} Hz, held-out computed-torque run of {s['test_duration']:g} s, "
        f"unmodeled effects {'on' if s['unmodeled'] else 'off'}",
        head,
        "-" * len(head),
    ]
    for r in result.rows:
        ok = bool(r["success"])
        lines.append(
            f"{r['label']:<40} {_fmt(r['rms_position'], ok)} {_fmt(r['rms_velocity'], ok):>11} "
            f"{_fmt(r['rms_feedback'], ok)} {r['nmse_clean']:>10.4g} {r['nmse_measured']:>10.4g} "
            f"{r['fit_s']:>7.2f} {r['project_s']:>7.2f}"
        )
    failed = [f"  {r['label']}: {r['reason']}" for r in result.rows if r["success"] is False]
    if failed:
        lines += ["FAILURE reasons:", *failed]
    return "\n".join(lines)


def goal_check(results: Mapping[str, RobotResult], *, threshold: float = 0.10) -> dict:
    """The issue's goal: the best Bayesian pipeline has at least ``threshold`` lower RMS feedback
    command than ridge + GD on every robot, and does not fail on any robot (the paper's
    Bayesian method ran on both robots).

    Returns:
        ``{"met": bool, "robots": {robot: {"ridge", "best_bayes", "best_bayes_feedback",
        "reduction", "bayes_failed", "met"}}}``; ``reduction`` is ``1 - bayes / ridge`` (inf
        when ridge failed and a Bayesian pipeline did not, NaN when both failed).
    """
    per = {}
    for robot, res in results.items():
        rows = {r["method"]: r for r in res.rows}
        ridge = rows["ridge"]["rms_feedback"] if rows["ridge"]["success"] else math.inf
        bayes = [(r["rms_feedback"], m) for m, r in rows.items() if m.startswith("bjfa")]
        good = [(v, m) for v, m in bayes if rows[m]["success"]]
        best_v, best_m = min(good) if good else (math.inf, None)
        reduction = 1 - best_v / ridge if math.isfinite(ridge) else math.inf * (best_m is not None)
        failed = best_m is None
        per[robot] = {
            "ridge": ridge, "best_bayes": best_m, "best_bayes_feedback": best_v,
            "reduction": reduction, "bayes_failed": failed,
            "met": (not failed) and reduction >= threshold,
        }  # fmt: skip
    return {"met": all(p["met"] for p in per.values()), "robots": per}


def plot_tracking(result: RobotResult, path=None):
    """Per-joint RMS position, velocity and feedback errors of each successful run (grouped bars,
    log scale). Saves a PNG at ``path`` when given; returns the matplotlib figure."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    runs = {m: r for m, r in result.control.items() if r.success}
    fig, axes = plt.subplots(3, 1, figsize=(11, 9), sharex=True)
    names = next(iter(result.control.values())).joint_names if result.control else ()
    x = np.arange(len(names))
    width = 0.8 / max(len(runs), 1)
    panels = (("rms_position", "position (rad)"), ("rms_velocity", "velocity (rad/s)"),
              ("rms_feedback", "feedback (N m)"))  # fmt: skip
    for ax, (attr, unit) in zip(axes, panels, strict=True):
        for k, (m, r) in enumerate(runs.items()):
            ax.bar(x + (k - (len(runs) - 1) / 2) * width, getattr(r, attr), width, label=LABELS[m])
        ax.set_yscale("log")
        ax.set_ylabel(f"RMS {unit}")
    failed = [LABELS[m] for m, r in result.control.items() if not r.success]
    title = f"{result.robot}: computed-torque tracking on the held-out trajectory"
    axes[0].set_title(title + (f"\nFAILURE: {', '.join(failed)}" if failed else ""), fontsize=9)
    axes[0].legend(fontsize=7, ncol=2)
    axes[-1].set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
