"""The report's numbers and files, without the command line."""

import math

import matplotlib
import numpy as np
import pytest
import torch
from _flow import fit_logs
from matplotlib.collections import PathCollection

from torchjfa.data import JointLog
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import BayesianJFA
from torchjfa.report import make_report, torque_errors
from torchjfa.sim import generate_log, model_path


def test_torque_errors_by_hand():
    rng = np.random.default_rng(0)
    tau = rng.standard_normal((200, 3)) * [1.0, 2.0, 0.1]
    pred = tau + rng.standard_normal((200, 3)) * 0.1
    nmse, rms = torque_errors(torch.from_numpy(tau), torch.from_numpy(pred))
    err = pred - tau
    np.testing.assert_allclose(rms.numpy(), np.sqrt((err**2).mean(0)))
    np.testing.assert_allclose(nmse.numpy(), (err**2).mean(0) / tau.var(0))


@pytest.fixture(scope="module")
def report():
    model = RigidBodyModel.from_mjcf(model_path("head"))
    sim = generate_log("head", n_samples=3000, seed=5)
    log = JointLog(
        t=sim.t, q=sim.q, qd=sim.qd, qdd=sim.qdd, tau=sim.tau, joint_names=sim.joint_names
    )
    train, valid = log.split(0.25)
    est = BayesianJFA(fit_intercept=False, max_iter=2000)
    result = fit_logs(model, train, estimator=est, jackknife=3)
    return make_report(result, valid.reorder(tuple(reversed(model.joint_names))))


def test_fits_are_on_the_models_joint_order(report):
    v = report.validation
    assert v.joint_names == report.model.joint_names
    Y = report.model.regressor(v.q, v.qd, v.qdd)
    nmse, _ = torque_errors(v.tau, Y @ report.result.theta)
    torch.testing.assert_close(report.fits["identified"].nmse, nmse)
    assert set(report.fits) == {"identified", "unconstrained", "description"}


def test_parameter_rows_and_markdown_without_settings(report):
    rows = report.parameter_rows()
    assert len(rows) == report.model.n_params
    assert any(r["relevance"] is not None for r in rows)
    assert all(r["jackknife_std"] is not None for r in rows)
    md = report.markdown()
    # the posterior std and the relevance stay in the rows (report.json, parameters.csv) but
    # not in the table: neither measures the error (scripts/spread_coverage.py, docs/report.md)
    assert any(r["posterior_std"] is not None for r in rows)
    header = next(line for line in md.splitlines() if line.startswith("| parameter |"))
    assert header.split(" | ")[1:4] == ["identified", "unconstrained", "jackknife std"]
    assert "posterior" not in header and "relevance" not in header
    base_header = next(line for line in md.splitlines() if line.startswith("| base parameter"))
    assert base_header == "| base parameter | identified | unconstrained | jackknife std |"
    assert "report: None" not in md and "(None)" not in md and "data: None" not in md
    assert md.startswith("# Identification report: sarcos_head.xml")
    assert md.count("\n| ") >= report.model.n_dof + report.model.n_params


def test_write_leaves_the_pyplot_backend_alone(report, tmp_path):
    before = matplotlib.get_backend()
    paths = report.write(tmp_path)
    assert matplotlib.get_backend() == before
    assert paths["torques"].read_bytes()[:4] == b"\x89PNG"
    assert "parameters.png" in paths["markdown"].read_text()


# ------------------------------------------------------------------ figures a person can read
def _drawn(fig):
    """Lay the figure out and draw it (Agg), so that window extents are final."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _zero_columns(report):
    """Parameters whose regressor column is zero on the held-out motion: computed from the
    regressor itself, not from the report's moments."""
    v = report.validation
    Y = report.model.regressor(v.q, v.qd, v.qdd).reshape(-1, report.model.n_params)
    return (Y.abs().amax(0) == 0).numpy()


def _labels(ax):
    """Labels of the axes' own artists (lines and marker collections), private ones left out."""
    arts = list(ax.lines) + list(ax.collections)
    return {a.get_label() for a in arts if not a.get_label().startswith("_")}


def test_parameters_figure_groups_by_body_and_explains_every_mark(report, tmp_path):
    fig = report.plot_parameters(tmp_path / "p.png")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    renderer = _drawn(fig)
    (ax,) = fig.axes  # one panel: the relevance panel (a flat band on a log axis) is gone
    ticks = [t for t in ax.get_xticklabels() if t.get_text()]
    assert [t.get_text() for t in ticks] == list(report.model.joint_names)  # one per body
    assert min(t.get_fontsize() for t in ticks) >= 7
    legend = ax.get_legend()
    texts = [t.get_text() for t in legend.get_texts()]
    box, lbox = ax.get_window_extent(renderer), legend.get_window_extent(renderer)
    assert lbox.x0 >= box.x1  # the legend is right of the axes: it covers no mark
    assert lbox.x1 <= fig.bbox.x1 + 1  # and inside the figure
    assert _labels(ax) <= set(texts)  # every line and marker set is in the legend
    assert any(t.startswith("2 spreads") for t in texts)  # the dashed line says what it is
    for kind in ("mass", "first moments", "inertia", "friction"):
        assert any(t.startswith(kind) for t in texts), kind
    zero = _zero_columns(report)
    assert zero.sum() > 0  # the head's first body turns about a fixed vertical axis
    assert f"not excited ({int(zero.sum())})" in " ".join(texts)
    lo, hi = ax.get_ylim()
    assert 1e-3 <= lo <= 0.1 and 30 <= hi <= 1e5  # not 1e-11 .. 1e8, a bar per raw ratio
    scatters = [c for c in ax.collections if isinstance(c, PathCollection)]
    marks = np.concatenate([c.get_offsets()[:, 1] for c in scatters])
    assert ((marks >= lo) & (marks <= hi)).all()  # every mark on the axes, none beyond the edge
    assert len(fig.axes[0].get_title()) > 0


def test_parameter_rows_mark_the_parameters_the_data_do_not_excite(report):
    zero = _zero_columns(report)
    assert [not r["excited"] for r in report.parameter_rows()] == zero.tolist()
    md = report.markdown()
    assert md.count("| not excited |") == int(zero.sum())
    assert f"not excited ({int(zero.sum())} parameters)" in md


def test_torques_figure_has_one_legend_outside_every_axes(report, tmp_path):
    fig = report.plot_torques(tmp_path / "t.png")
    renderer = _drawn(fig)
    assert len(fig.axes) == report.model.n_dof
    (legend,) = fig.legends
    lbox = legend.get_window_extent(renderer)
    texts = {t.get_text() for t in legend.get_texts()}
    for ax, joint in zip(fig.axes, report.model.joint_names, strict=True):
        assert ax.get_legend() is None
        assert not lbox.overlaps(ax.get_window_extent(renderer)), joint
        assert _labels(ax) <= texts and len(_labels(ax)) == 1 + len(report.fits)
        assert ax.get_title(loc="left").startswith(f"{joint}: nMSE")
        for name, fit in report.fits.items():  # each prediction's nMSE, from the fit itself
            j = report.model.joint_names.index(joint)
            assert f"{name} {float(fit.nmse[j]):.3g}" in ax.get_title(loc="left")


# ------------------------------------------------------------------ report.md
def test_estimator_line_summarises_arrays():
    from torchjfa.report import estimator_text

    noise = torch.tensor([0.0, 2.25e-34, 1e-4, 3e-4, 5e-4, 0.0, 2e-3], dtype=torch.float64)
    est = BayesianJFA(fit_intercept=False, input_noise=noise, max_iter=500)
    text = estimator_text(est)
    assert "tensor" not in text and "e-34" not in text
    median = float(np.median(noise.numpy()))  # 7 values: the 4th smallest, 1e-4
    assert f"input_noise=(given: 7 columns, median {median:.2g}, 2 of them 0)" in text
    assert text.startswith("BayesianJFA(") and "max_iter=500" in text
    assert "\n" not in text


def _with_estimator(report, est):
    import dataclasses

    return dataclasses.replace(report, result=dataclasses.replace(report.result, estimator=est))


def test_markdown_states_convergence_and_warns_when_not_converged(report):
    import copy

    est = report.result.estimator
    converged = copy.copy(est)
    converged.converged_, converged.n_iter_, converged.stop_reason_ = True, 123, "bound"
    md = _with_estimator(report, converged).markdown()
    assert "- convergence: 123 iterations, converged: yes (stopping rule: bound)" in md
    assert "did not converge" not in md
    capped = copy.copy(est)
    capped.converged_, capped.n_iter_, capped.stop_reason_ = False, 2000, "max_iter"
    md = _with_estimator(report, capped).markdown()
    assert "- convergence: 2000 iterations, converged: **no** (stopped by max_iter)" in md
    (warning,) = [line for line in md.splitlines() if "Warning" in line]
    assert "did not converge" in warning and "max_iter=2000" in warning
    from torchjfa.estimators import OLS

    md = _with_estimator(report, OLS(fit_intercept=False)).markdown()
    assert "- convergence: closed form (no iterations)" in md


def test_markdown_says_the_all_rms_is_a_quadratic_mean(report):
    md = report.markdown()
    (row,) = [line for line in md.splitlines() if line.startswith("| all |")]
    rms = report.fits["identified"].rms.numpy()
    assert f"**{np.sqrt(np.mean(rms**2)):.4g}**" in row  # sqrt(mean(rms^2)), not mean(rms)
    assert "RMS is the quadratic mean over the joints" in md


def test_undetermined_flags_values_beyond_any_physical_scale():
    from torchjfa.report import undetermined

    names = ["j.m", "j.mcx", "j.Ixx", "j.fv", "k.m", "k.mcx", "k.Ixx", "k.fv"]
    tiny = torch.tensor([1e-12, 0.0, 1e-15, 0.0] * 2, dtype=torch.float64)  # near-massless
    values = torch.tensor([5.0, 1e29, float("nan"), 0.3, -2e6, 0.5, float("inf"), 9e5])
    # the scale of each kind is at least 1 SI unit: 1e6 is the bound here
    expected = [False, True, True, False, True, False, True, False]
    assert undetermined(values, names, tiny).tolist() == expected
    heavy = torch.tensor([3.0, 0.1, 0.02, 0.5, 2.0, 0.2, 0.01, 0.1], dtype=torch.float64)
    values = torch.tensor([2.9e6, 2.1e5, 1.9e4, 4e5, -3.1e6, 1e5, 2.1e4, 5.1e5])
    # bounds 1e6 x max(|description| of the kind, 1): m 3e6, mc 1e6, I 1e6, fv 1e6
    expected = [False, False, False, False, True, False, False, False]
    assert undetermined(values, names, heavy).tolist() == expected


def _undetermined_counts(report, tmp_path):
    """``(entries in report.md, parameters in the figure's legend)`` called undetermined."""
    import re

    md = report.markdown()
    m = re.search(r"undetermined \((\d+) entries\)", md)
    texts = [t.get_text() for t in report.plot_parameters(tmp_path / "p.png").axes[0]
             .get_legend().get_texts()]  # fmt: skip
    f = [int(re.match(r"undetermined \((\d+)\)", t).group(1)) for t in texts
         if t.startswith("undetermined (")]  # fmt: skip
    return (int(m.group(1)) if m else 0), (f[0] if f else 0)


def test_markdown_prints_undetermined_not_unphysical_numbers(report, tmp_path):
    import dataclasses

    r = report.result
    theta_hat = r.theta_hat.clone()
    std = r.theta_hat_std.clone()
    names = report.model.parameter_names
    i, k = names.index("neck_tilt.Ixx"), names.index("neck_roll.mcz")
    assert abs(float(theta_hat[i])) < 1e3 and float(std[k]) < 1e3  # physical before
    theta_hat[i] = 3.7e29
    std[k] = float("inf")
    bad = dataclasses.replace(report, result=dataclasses.replace(r, theta_hat=theta_hat,
                                                                  theta_hat_std=std))  # fmt: skip
    md = bad.markdown()
    assert "e+29" not in md and "inf" not in md
    rows = {line.split(" | ")[0][2:]: line.split(" | ") for line in md.splitlines()
            if line.startswith("| neck_") and " " not in line.split(" | ")[0][2:]}  # fmt: skip
    # (a base combination's row also starts with "| neck_", its first cell has spaces)
    assert rows["neck_tilt.Ixx"][2] == "undetermined"  # unconstrained
    assert rows["neck_roll.mcz"][3] == "undetermined"  # jackknife std
    assert rows["neck_tilt.Ixx"][3] != "undetermined"  # its spread stays a number
    base_md, base_fig = _undetermined_counts(report, tmp_path)
    assert _undetermined_counts(bad, tmp_path) == (base_md + 2, base_fig + 2)
    # every number printed in the value columns is within 1e6 x the largest scale of any kind
    bound = 1e6 * max(1.0, float(report.model.nominal_theta.abs().max()))
    for cells in rows.values():
        for cell in cells[1:4]:
            if cell not in ("undetermined", "not excited", "-"):
                assert abs(float(cell)) <= bound


def test_parameters_figure_without_any_spread_shows_the_identified_values(report, tmp_path):
    import dataclasses

    from torchjfa.estimators import OLS

    r = dataclasses.replace(report.result, estimator=OLS(fit_intercept=False), theta_hat_std=None)
    bare = dataclasses.replace(report, result=r)
    fig = bare.plot_parameters(tmp_path / "p.png")
    renderer = _drawn(fig)
    (ax,) = fig.axes
    assert ax.get_title().startswith("Identified parameters (no spread")
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert not any(t.startswith("2 spreads") for t in texts)  # no spread, no spread line
    assert not any("Bayesian JFA" in t for t in texts)
    assert _labels(ax) <= set(texts)
    assert ax.get_legend().get_window_extent(renderer).x0 >= ax.get_window_extent(renderer).x1
    lo, hi = ax.get_ylim()
    theta = r.theta.abs()[bare.excited]
    shown = theta[theta > 1e-12]  # the axis reaches down to 1e-12; 0 and below sit at its foot
    assert lo <= float(shown.min()) and float(theta.max()) <= hi


def test_estimator_line_says_how_the_input_noise_was_set(report):
    import dataclasses

    from torchjfa.estimators import OLS

    bayes = dataclasses.replace(report, settings={"input_noise": "periods"})
    line = next(x for x in bayes.markdown().splitlines() if x.startswith("- estimator:"))
    assert line.endswith("; input noise: fixed to the spread between excitation periods")
    ols = _with_estimator(bayes, OLS(fit_intercept=False))
    line = next(x for x in ols.markdown().splitlines() if x.startswith("- estimator:"))
    assert line.endswith("used in the projection's metric only")
    line = next(x for x in report.markdown().splitlines() if x.startswith("- estimator:"))
    assert "input noise" not in line.split("`")[-1]  # no settings: nothing said


def test_what_the_data_determine_section(report):
    """The head's base parameters are in the report: their count, the condition number, each
    parameter's status in the table and the combinations with their spreads."""
    b = report.base
    assert b is not None and 0 < b.rank < report.model.n_params
    md = report.markdown()
    assert "## What the data determine" in md
    assert f"base (identifiable) parameters: **{b.rank}** of {report.model.n_params}" in md
    assert f"{b.condition_number:.3g}" in md
    rows = report.parameter_rows()
    assert [r["data"] for r in rows] == list(b.status)
    combos = [
        r for r in report.base_rows() if " + " in r["combination"] or " - " in r["combination"]
    ]
    assert combos, "a fixed-base head has regrouped parameters"
    for r in combos:
        assert r["combination"] in md
        assert r["jackknife_std"] is not None and math.isfinite(r["jackknife_std"])
    # the base values are what the data see: Y theta = Y_B b(theta) on the held-out data
    v = report.validation
    Y = report.model.regressor(v.q, v.qd, v.qdd).reshape(-1, report.model.n_params)
    theta = report.result.theta_hat
    pred = Y[:, list(b.independent)] @ b.values(theta)
    torch.testing.assert_close(
        pred, Y @ theta, rtol=1e-7, atol=1e-7 * float((Y @ theta).abs().max())
    )
    summary = report.summary()["base_parameters"]
    assert summary["rank"] == b.rank and summary["counts"] == b.counts()


def test_training_rms_says_when_it_is_of_the_weighted_equations():
    """Unweighted, the header's training RMS is the torque residual's, in N m (by hand from the
    rows); with joint weights it is that of the weighted equations and says so (not N m)."""
    from torchjfa.estimators import OLS

    model = RigidBodyModel.from_mjcf(model_path("head"))
    sim = generate_log("head", n_samples=1500, seed=6)
    log = JointLog(
        t=sim.t, q=sim.q, qd=sim.qd, qdd=sim.qdd, tau=sim.tau, joint_names=sim.joint_names
    )
    train, valid = log.split(0.25)
    plain = fit_logs(model, train, estimator=OLS(fit_intercept=False))
    md = make_report(plain, valid).markdown()
    t = train.reorder(model.joint_names)
    res = t.tau - model.regressor(t.q, t.qd, t.qdd) @ plain.theta
    by_hand = float(res.pow(2).mean().sqrt())
    assert f"- training RMS torque error: {by_hand:.4g} N m" in md
    weights = torch.linspace(0.5, 2.0, model.n_dof, dtype=torch.float64)
    weighted = fit_logs(model, train, estimator=OLS(fit_intercept=False), joint_weights=weights)
    md = make_report(weighted, valid).markdown()
    assert "- training RMS of the weighted equations" in md
    assert "training RMS torque error" not in md
