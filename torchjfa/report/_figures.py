"""The report's figures, as pure functions of its numbers (`torchjfa.report` calls them).

`torques_figure`: measured and predicted held-out torques per joint; `parameters_figure`: how far
each unconstrained estimate lies from 0 in its spreads. Both return a `matplotlib.figure.Figure`
and, given a path, write it without touching pyplot's backend.
"""

from __future__ import annotations

import numpy as np

from ..physical._base import parameter_kind

__all__ = ["torques_figure", "parameters_figure"]


def _figure(path, rows: int, **kw):
    """A figure with ``rows`` stacked axes: through pyplot for display, or, when it is only
    saved to ``path``, a bare `matplotlib.figure.Figure` (pyplot's backend is left alone, so
    inline figures in a notebook keep working)."""
    if path is None:
        import matplotlib.pyplot as plt

        return plt.subplots(rows, 1, squeeze=False, layout="constrained", **kw)
    from matplotlib.figure import Figure

    fig = Figure(figsize=kw.pop("figsize"), layout="constrained")
    return fig, fig.subplots(rows, 1, squeeze=False, **kw)


_TOP = 1e5  # the parameters figure's highest y: above it, a mark at the top edge
# parameter kinds in the parameters figure: (label, colour, marker), by `_kind_group`
_KIND_STYLE = {
    "m": ("mass m", "C0", "o"),
    "mc": ("first moments m c", "C1", "s"),
    "I": ("inertia I (6 entries)", "C2", "D"),
    "friction": ("friction (fv, fc, fo)", "C4", "^"),
    "other": ("joint terms", "C5", "v"),
}


def _kind_group(kind: str) -> str:
    """The figure's group of a `_kind`: mass, first moments, inertia, friction or other."""
    if kind in ("m", "mc", "I"):
        return kind
    return "friction" if kind in ("fv", "fc", "fo") else "other"


def _body_groups(names) -> list[tuple[str, int, int]]:
    """``(body, first, stop)`` index ranges of the consecutive parameters of each joint's body."""
    groups: list[tuple[str, int, int]] = []
    for i, name in enumerate(names):
        body = name.rsplit(".", 1)[0]
        if groups and groups[-1][0] == body:
            groups[-1] = (body, groups[-1][1], i + 1)
        else:
            groups.append((body, i, i + 1))
    return groups


def torques_figure(validation, fits, joint_types, path=None, *, seconds: float | None = 10.0):
    """Measured and predicted held-out torque per joint (the first ``seconds``).

    One axes per joint, its title giving each prediction's nMSE; one legend for the figure,
    below the axes (it covers no curve).

    Args:
        validation: the held-out `JointLog` (q, qd, qdd, tau).
        fits: name -> `TorqueFit` on ``validation`` (``"identified"``, ...).
        joint_types: joint name -> ``"revolute"`` or ``"prismatic"``.
        path: write the figure there (PNG), through a bare `Figure` (pyplot left alone).
        seconds: the stretch shown from the start; None for all.

    Returns:
        The `matplotlib.figure.Figure` (written to ``path`` when given).
    """
    log = validation
    t = (log.t - log.t[0]).numpy()
    n = log.n_samples if seconds is None else int(np.searchsorted(t, seconds, side="right"))
    n = max(n, 2)
    n_dof = log.n_dof
    fig, axes = _figure(path, n_dof, figsize=(9, 1.5 * n_dof + 0.9), sharex=True)
    styles = {
        "identified": {"color": "C1", "lw": 1.2, "zorder": 3},  # the saved model: on top
        "unconstrained": {"color": "C2", "lw": 0.9, "ls": "--"},
        "description": {"color": "C7", "lw": 0.9, "ls": ":"},
    }
    labels = {
        "identified": "identified (physically consistent, saved)",
        "unconstrained": "unconstrained estimate",
        "description": "description's parameters",
    }
    for j, ax in enumerate(axes[:, 0]):
        ax.plot(t[:n], log.tau[:n, j].numpy(), color="k", lw=0.8, label="measured")
        for name, fit in fits.items():
            ax.plot(
                t[:n],
                fit.predicted[:n, j].numpy(),
                label=labels.get(name, name),
                **styles.get(name, {}),
            )
        errors = ", ".join(f"{name} {float(f.nmse[j]):.3g}" for name, f in fits.items())
        ax.set_title(f"{log.joint_names[j]}: nMSE {errors}", fontsize=8, loc="left")
        ax.set_ylabel("N" if joint_types[log.joint_names[j]] == "prismatic" else "N m", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[-1, 0].set_xlabel("time into the held-out data [s]")
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=len(names), fontsize=8)
    fig.suptitle("Held-out torque: measured and predicted", fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def parameters_figure(rows, flags, path=None):
    """How far each unconstrained estimate stands from 0, in its own spreads.

    One marker per parameter at ``|unconstrained| / spread`` (the jackknife spread, else
    Bayesian JFA's posterior spread) on a log axis, parameters grouped by body (one tick and
    a separator per body), colour and marker by kind (mass, first moments, inertia,
    friction); a line at 2 spreads (below it the data do not tell the value from 0);
    parameters without a ratio marked at the foot of the axes (not excited: a zero regressor
    column, `IdentificationReport.excited`; off scale: a value or spread beyond any physical
    scale, `torchjfa.report.undetermined`); parameters Bayesian JFA calls irrelevant
    (``<alpha>`` above 100 times the median) ringed. Without any spread: ``|identified|``. Every mark is
    explained in the legend, right of the axes.

    Args:
        rows: `IdentificationReport.parameter_rows`.
        flags: `IdentificationReport.undetermined_entries`.
        path: write the figure there (PNG), through a bare `Figure` (pyplot left alone).

    Returns:
        The `matplotlib.figure.Figure` (written to ``path`` when given).
    """
    from matplotlib.lines import Line2D

    names = [r["parameter"] for r in rows]
    n = len(rows)
    x = np.arange(n)
    excited = np.array([r["excited"] for r in rows])
    y, bad, floor, ylabel, title, has_spread = _spread_ratios(rows, flags)
    plotted = excited & ~bad
    low, top = _y_range(y, plotted, floor)
    foot = low * 1.6  # where the marks of parameters without a ratio sit

    fig, axes = _figure(path, 1, figsize=(max(8.0, 0.09 * n + 4.0), 4.2))
    ax = axes[0, 0]
    groups = _body_groups(names)
    for _, first, _ in groups[1:]:
        ax.axvline(first - 0.5, color="0.8", lw=0.8, zorder=0)
    kinds = np.array([_kind_group(parameter_kind(nm)) for nm in names])
    handles = []
    for kind, (label, color, marker) in _KIND_STYLE.items():
        sel = plotted & (kinds == kind)
        if not sel.any():
            continue
        ax.vlines(x[sel], low, np.clip(y[sel], low, top), color=color, lw=1.0, alpha=0.5)
        yk = np.clip(y[sel], low, top)
        ax.scatter(
            x[sel], yk, color=color, marker=marker, s=22, zorder=3, clip_on=False, label=label
        )
        handles.append(Line2D([], [], color=color, marker=marker, ls="", markersize=5, label=label))
    above = plotted & (y > top)
    if above.any():
        label = f"beyond the axis ({int(above.sum())}): above {top:.0e}"
        _mark(ax, handles, x, above, top, label, "k", 6, 40, zorder=4, clip_on=False)
    if has_spread:
        label = "2 spreads: below it, not told from 0"
        ax.axhline(2.0, color="C3", lw=0.9, ls="--", label=label)
        handles.append(Line2D([], [], color="C3", lw=0.9, ls="--", label=label))
    silent = ~excited
    if silent.any():
        label = f"not excited ({int(silent.sum())}): zero regressor column, no data"
        _mark(ax, handles, x, silent, foot, label, "0.55", "x", 18, zorder=3)
    flagged = excited & bad
    if flagged.any():
        label = f"off scale ({int(flagged.sum())}): beyond any physical scale"
        _mark(ax, handles, x, flagged, foot, label, "k", "$?$", 30, zorder=3)
    rel = np.array([np.nan if r["relevance"] is None else r["relevance"] for r in rows])
    if np.isfinite(rel).any():
        at = np.where(plotted, np.clip(y, low, top), foot)
        _ring_irrelevant(ax, handles, x, at, rel, excited)
    _label_axes(ax, groups, n, (low, top), ylabel, title)
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False
    )
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def _spread_ratios(rows, flags):
    """The parameters figure's heights: ``(y, bad, floor, ylabel, title, has_spread)``.

    ``y``: ``(n_params,)`` ``|unconstrained| / spread`` (the jackknife spread, else the
    posterior's), or ``|identified|`` without any spread; NaN (0 / 0) and a zero spread read 0
    (an estimate pruned to ~0, drawn at the foot). ``bad``: ``(n_params,)`` bool, the entries
    `undetermined` flags; ``floor``: the lowest height the axis goes down to.
    """
    value = np.array([np.nan if r["unconstrained"] is None else r["unconstrained"] for r in rows])
    spread, spread_name = None, None
    for key, label in (("jackknife_std", "jackknife"), ("posterior_std", "posterior")):
        if any(r[key] is not None for r in rows):
            spread = np.array([np.nan if r[key] is None else r[key] for r in rows])
            spread_name, spread_key = label, key
            break
    if spread is not None:
        bad = flags["unconstrained"].numpy() | flags[spread_key].numpy()
        with np.errstate(divide="ignore", invalid="ignore"):
            y = np.abs(value) / spread
        ylabel = f"|unconstrained| / {spread_name} spread"
        title = f"How far each unconstrained estimate lies from 0, in {spread_name} spreads"
        if spread_name == "posterior":  # 2-3x too narrow even on the model's own data
            title += "\n(the posterior spread is a lower bound: the ratios come out too large)"
        floor = 1e-3
    else:
        bad = flags["identified"].numpy()
        floor = 1e-12
        y = np.abs(np.array([r["identified"] for r in rows], dtype=float))
        ylabel = "|identified value| (SI units)"
        title = "Identified parameters (no spread: run with a jackknife for one)"
    # 0 / 0, or x / 0 (every refit the same): an estimate pruned to ~0, drawn at the foot
    y = np.where(np.isnan(y) | (spread == 0 if spread is not None else False), 0.0, y)
    return y, bad, floor, ylabel, title, spread is not None


def _y_range(y, plotted, floor: float) -> tuple[float, float]:
    """``(low, top)`` of the log axis: decades around the plotted positive heights, at least
    0.1 to 30 (1.5 x the largest), at most `_TOP`."""
    sized = plotted & np.isfinite(y) & (y > 0)
    if not sized.any():
        return 0.1, 100.0
    top = 10 ** np.ceil(np.log10(max(y[sized].max() * 1.5, 30.0)))
    top = min(top, _TOP)  # a ratio of two numbers near 0 (a pruned parameter) is noise
    low = 10 ** np.floor(np.log10(max(y[sized].min(), floor)))
    return min(low, 0.1), top


def _mark(ax, handles, x, where, at, label, color, marker, size, **kw) -> None:
    """Scatter a marker at height ``at`` for the parameters ``where``, with a legend entry."""
    from matplotlib.lines import Line2D

    ax.scatter(x[where], np.full(where.sum(), at), color=color, marker=marker, s=size,
               label=label, **kw)  # fmt: skip
    handles.append(Line2D([], [], color=color, marker=marker, ls="", label=label))


def _ring_irrelevant(ax, handles, x, at, rel, excited) -> None:
    """Ring the parameters whose relevance ``rel`` (Bayesian JFA's ``<alpha>``) is above 100
    times the median (of the excited ones), at their heights ``at``; always a legend entry."""
    from matplotlib.lines import Line2D

    median = np.nanmedian(rel[excited]) if excited.any() else np.nanmedian(rel)
    called = excited & np.isfinite(rel) & (rel > 100 * median)
    label = f"called irrelevant by Bayesian JFA ({int(called.sum())}): <alpha> > 100 x median"
    if called.any():
        ax.scatter(
            x[called],
            at[called],
            facecolors="none",
            edgecolors="k",
            s=90,
            lw=1.0,
            zorder=4,
            label=label,
        )
    handles.append(
        Line2D([], [], color="k", marker="o", mfc="none", ls="", markersize=8, label=label)
    )


def _label_axes(ax, groups, n: int, ylim: tuple[float, float], ylabel: str, title: str) -> None:
    """The log y axis over ``ylim``, one x tick per body group, the labels and the title."""
    ax.set_yscale("log")
    ax.set_ylim(*ylim)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xticks(
        [(first + stop - 1) / 2 for _, first, stop in groups],
        [body for body, _, _ in groups],
        rotation=30 if len(groups) > 10 else 0,
        ha="right" if len(groups) > 10 else "center",
        fontsize=8,
    )
    ax.tick_params(axis="x", length=0)
    ax.set_xlabel("parameters, grouped by the body each joint moves", fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title(title, fontsize=9)
