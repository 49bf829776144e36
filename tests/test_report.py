"""The report's numbers and files, without the command line."""

import copy
import csv
import dataclasses
import math
import re
from pathlib import Path

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


def test_parameter_rows_and_the_appendix_without_settings(report):
    rows = report.parameter_rows()
    assert len(rows) == report.model.n_params
    assert any(r["relevance"] is not None for r in rows)
    assert all(r["jackknife_std"] is not None for r in rows)
    short, md = report.markdown(), report.markdown(appendix=True)
    body = short.splitlines()[:-1]  # the last line points to the appendix or says how to get it
    assert md.splitlines()[: len(body)] == body
    assert "## Appendix" in md and "## Appendix" not in short
    # the posterior std and the relevance stay in the rows (report.json, parameters.csv) but
    # not in the table: neither measures the error
    assert any(r["posterior_std"] is not None for r in rows)
    header = next(line for line in md.splitlines() if line.startswith("| parameter |"))
    assert header.split(" | ")[1:5] == ["identified", "source", "unconstrained", "jackknife std"]
    assert "posterior" not in header and "relevance" not in header
    base_header = next(line for line in md.splitlines() if line.startswith("| base parameter"))
    assert base_header == "| base parameter | identified | unconstrained | jackknife std |"
    for text in (short, md):
        assert not re.search(r"\| None \||: None\b|\bnan\b|\(None\)", text)
    assert md.startswith("# Identification report: sarcos_head.xml\n\n## Verdict\n")
    assert md.count("\n| ") >= report.model.n_dof + report.model.n_params
    assert short.count("\n| ") < report.model.n_params  # the short one has no parameter table


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


def _not_excited(report):
    """The parameters the report calls not excited (`base_parameters`' status)."""
    return np.array([s == "not excited" for s in report.statuses()])


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
    silent = _not_excited(report)
    assert _zero_columns(report).sum() > 0  # the head's first body turns about a fixed axis
    assert f"not excited ({int(silent.sum())})" in " ".join(texts)  # the report's one count
    lo, hi = ax.get_ylim()
    assert 1e-3 <= lo <= 0.1 and 30 <= hi <= 1e5  # not 1e-11 .. 1e8, a bar per raw ratio
    scatters = [c for c in ax.collections if isinstance(c, PathCollection)]
    marks = np.concatenate([c.get_offsets()[:, 1] for c in scatters])
    assert ((marks >= lo) & (marks <= hi)).all()  # every mark on the axes, none beyond the edge
    assert len(fig.axes[0].get_title()) > 0


def test_parameter_rows_mark_the_parameters_the_data_do_not_excite(report):
    zero, silent = _zero_columns(report), _not_excited(report)
    rows = report.parameter_rows()
    assert [not r["excited"] for r in rows] == silent.tolist()
    assert (silent >= zero).all()  # every exactly zero column, and those zero up to rounding
    for r in rows:
        assert r["determined"] == (r["data"] == "determined")
        # no description prior in this fit: the projection alone fixes what the data leave
        assert r["source"] == {"determined": "data", "not excited": "projection"}.get(
            r["data"], "data+projection"
        )
    md = report.markdown(appendix=True)
    assert md.count("| not excited |") == int(silent.sum())
    assert f"{int(silent.sum())} not excited" in report.markdown()


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
    return dataclasses.replace(report, result=dataclasses.replace(report.result, estimator=est))


def _section(md: str, title: str) -> list[str]:
    """The lines of the section ``## title`` (up to the next ``## ``)."""
    lines = md.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"## {title}"))
    stop = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), None)
    return lines[start:stop]


def test_markdown_states_convergence_and_warns_when_not_converged(report):
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
    (warning,) = _section(md, "Warnings")[2:-1]  # the one warning, in full
    assert "did not converge" in warning and "max_iter=2000" in warning
    verdict = _section(md, "Verdict")
    assert '- Warnings: 1 (section "Warnings"): BayesianJFA did not converge' in "\n".join(verdict)
    from torchjfa.estimators import OLS

    md = _with_estimator(report, OLS(fit_intercept=False)).markdown()
    assert "- convergence: closed form (no iterations)" in md


def test_the_torque_table_gives_both_errors_and_a_quadratic_mean(report):
    from torchjfa.report._words import g3

    md = report.markdown()
    table = [line for line in _section(md, "Held-out torque error") if line.startswith("| ")]
    assert table[0] == (
        "| joint | RMS error identified, N m | RMS error description, N m | nMSE identified | "
        "nMSE description |"
    )
    assert [row.split(" | ")[0][2:] for row in table[1:]] == [*report.model.joint_names, "all"]
    rms = report.fits["identified"].rms.numpy()
    assert f"**{g3(np.sqrt(np.mean(rms**2)))}**" in table[-1]  # sqrt(mean(rms^2)), not mean(rms)
    assert "the quadratic mean of the joints' RMS" in md
    assert "Target: the validation log's torque as given" in md  # no settings: as given


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


def _off_scale_counts(report, tmp_path):
    """``(entries in the appendix, parameters in the figure's legend)`` called off scale."""
    md = report.markdown(appendix=True)
    m = re.search(r"off scale \((\d+) entries\)", md)
    texts = [t.get_text() for t in report.plot_parameters(tmp_path / "p.png").axes[0]
             .get_legend().get_texts()]  # fmt: skip
    f = [int(re.match(r"off scale \((\d+)\)", t).group(1)) for t in texts
         if t.startswith("off scale (")]  # fmt: skip
    return (int(m.group(1)) if m else 0), (f[0] if f else 0)


def test_the_appendix_prints_off_scale_not_unphysical_numbers(report, tmp_path):
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
    md = bad.markdown(appendix=True)
    assert "e+29" not in md and "inf" not in md
    rows = {line.split(" | ")[0][2:]: line.split(" | ") for line in md.splitlines()
            if line.startswith("| neck_") and "." in line.split(" | ")[0]
            and " " not in line.split(" | ")[0][2:]}  # fmt: skip
    # (a base combination's row also starts with "| neck_", its first cell has spaces)
    assert rows["neck_tilt.Ixx"][3] == "off scale"  # unconstrained
    assert rows["neck_roll.mcz"][4] == "off scale"  # jackknife std
    assert rows["neck_tilt.Ixx"][4] != "off scale"  # its spread stays a number
    base_md, base_fig = _off_scale_counts(report, tmp_path)
    assert _off_scale_counts(bad, tmp_path) == (base_md + 2, base_fig + 2)
    # every number printed in the value columns is within 1e6 x the largest scale of any kind
    bound = 1e6 * max(1.0, float(report.model.nominal_theta.abs().max()))
    for cells in rows.values():
        for cell in (cells[1], cells[3], cells[4]):
            if cell not in ("off scale", "-"):
                assert abs(float(cell)) <= bound


def test_parameters_figure_without_any_spread_shows_the_identified_values(report, tmp_path):
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
    md = report.markdown(appendix=True)
    assert "## What the data determine" in md
    assert (
        f"base parameters (the independent combinations the data can determine): **{b.rank}** "
        f"of {report.model.n_params}" in md
    )
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


def test_training_rms_says_filtered_and_when_it_is_of_the_weighted_equations():
    """Unweighted, the training residual is the torque's, in N m (by hand from the rows); with
    joint weights it is that of the weighted equations and says so (not N m). The fits are not
    projected: the projection is not what this checks (the training error of a projected theta
    is in tests/identification/test_default_report.py's golden file)."""
    from torchjfa.estimators import OLS
    from torchjfa.report._words import g3

    model = RigidBodyModel.from_mjcf(model_path("head"))
    sim = generate_log("head", n_samples=1500, seed=6)
    log = JointLog(
        t=sim.t, q=sim.q, qd=sim.qd, qdd=sim.qdd, tau=sim.tau, joint_names=sim.joint_names
    )
    train, valid = log.split(0.25)
    plain = fit_logs(model, train, estimator=OLS(fit_intercept=False), project=False)
    settings = {"prepare": {"cutoff_hz": 20.0}}
    md = make_report(plain, valid, settings=settings).markdown()
    t = train.reorder(model.joint_names)
    res = t.tau - model.regressor(t.q, t.qd, t.qdd) @ plain.theta
    by_hand = float(res.pow(2).mean().sqrt())
    assert f"- training residual RMS, N m (torque filtered at 20 Hz): {g3(by_hand)}" in md
    weights = torch.linspace(0.5, 2.0, model.n_dof, dtype=torch.float64)
    weighted = fit_logs(
        model, train, estimator=OLS(fit_intercept=False), joint_weights=weights, project=False
    )
    md = make_report(weighted, valid, settings=settings).markdown()
    assert "- training residual RMS of the weighted equations (torque filtered at 20 Hz" in md
    assert "- joint weights (weighted least squares, mean 1): neck_pan 0.500," in md
    assert "training residual RMS, N m" not in md


# ------------------------------------------------------------------ the verdict
def test_the_verdict_opens_the_report_and_its_counts_agree(report, tmp_path):
    """The report starts with the verdict; one count of what the data do not determine in the
    verdict, the section, the figure, the rows and parameters.csv; the ratio is the table's."""
    md = report.markdown()
    lines = md.splitlines()
    assert lines[:3] == ["# Identification report: sarcos_head.xml", "", "## Verdict"]
    v = report.judge()
    counts = report.base.counts()
    m = re.search(
        r"Not determined by the data alone: (\d+) of (\d+) parameters \((\d+) only in "
        r"combinations, (\d+) poorly excited, (\d+) not excited\)",
        md,
    )
    n_not, n, comb, poor, silent = (int(x) for x in m.groups())
    assert n == report.model.n_params and n_not == comb + poor + silent
    assert (comb, poor, silent) == (
        counts["combination"], counts["poorly excited"], counts["not excited"]
    )  # fmt: skip
    m = re.search(
        r"- parameters: (\d+) determined by the data alone, (\d+) only in combinations with "
        r"others, (\d+) poorly excited .*, (\d+) not excited .*: (\d+) in all",
        md,
    )
    det, comb2, poor2, silent2, n2 = (int(x) for x in m.groups())
    assert (comb2, poor2, silent2, n2) == (comb, poor, silent, n) and det + n_not == n
    rows = report.parameter_rows()
    assert sum(not r["determined"] for r in rows) == n_not == v.n_not_determined
    assert sum(not r["excited"] for r in rows) == silent
    report.write(tmp_path, plots=False)
    with open(tmp_path / "parameters.csv") as fh:
        csv_rows = list(csv.DictReader(fh))
    assert sum(r["determined"] == "False" for r in csv_rows) == n_not
    assert sum(r["data"] == "not excited" for r in csv_rows) == silent
    texts = " ".join(t.get_text() for t in report.plot_parameters().axes[0].get_legend()
                     .get_texts())  # fmt: skip
    assert f"not excited ({silent})" in texts
    ratio = v.rms_description / v.rms
    assert ratio > 1.1 and f"**Better than the description by {ratio:#.2g}x" in md
    summary = report.summary()["verdict"]
    assert summary["n_not_determined"] == n_not and summary["counts"] == counts
    assert summary["ratio_to_description"] == pytest.approx(ratio)


def test_parameters_csv_marks_what_the_data_do_not_determine(report, tmp_path):
    """parameters.csv: `determined` and `source` columns; a parameter not excited has no
    unconstrained value or spread (empty, not 0.0); every value is a number or empty."""
    report.write(tmp_path, plots=False)
    with open(tmp_path / "parameters.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:5] == ["parameter", "identified", "determined", "source", "data"]
    assert any(r["data"] == "not excited" for r in rows)
    for r in rows:
        assert r["determined"] == str(r["data"] == "determined")
        if r["data"] == "not excited":
            assert r["unconstrained"] == r["jackknife_std"] == r["posterior_std"] == ""
            assert r["source"] == "projection" and r["identified"] != ""
        else:
            assert r["unconstrained"] != ""
        assert r["source"] == "data" if r["determined"] == "True" else r["source"] != "data"
        for k in ("identified", "unconstrained", "jackknife_std", "description"):
            assert r[k] == "" or math.isfinite(float(r[k]))


def test_a_7_joint_report_is_short_and_says_what_each_number_is(report):
    """The head's report with its figures: under 80 lines, full joint names, no full-precision
    float, the noise figures said to be after filtering, no dates or issue numbers."""
    images = {"Held-out torques": "torques.png", "Parameters": "parameters.png"}
    settings = {"prepare": {"cutoff_hz": 13.8}, "command": "torchjfa identify head head.csv"}
    md = dataclasses.replace(report, settings=settings).markdown(images)
    assert report.model.n_dof == 7 and len(md.splitlines()) < 80
    _no_truncated_names(md, report.model.joint_names)
    assert max_significant_digits(md) <= 4
    assert "filtered at 13.8 Hz" in md
    _no_dates_or_issues(md)
    assert md.count("jackknife") <= 1  # no repeated notes on the spreads


def max_significant_digits(text: str) -> int:
    """The most significant digits of any decimal number in ``text`` (0.007552: 4)."""
    most = 0
    for m in re.finditer(r"(?<![\w.])-?(\d+\.\d+)(?:e[+-]?\d+)?(?![\w.])", text):
        digits = m.group(1).replace(".", "").lstrip("0")
        most = max(most, len(digits))
    return most


def _no_truncated_names(md: str, joints) -> None:
    """Every joint named in full: a row per joint, and no cut-off joint name anywhere."""
    for joint in joints:
        assert f"| {joint} |" in md
        for k in range(6, len(joint)):
            part = joint[:k]
            if any(j.startswith(part) and j != part for j in joints) and part in joints:
                continue
            assert not re.search(rf"(?<![\w.]){re.escape(part)}(?![\w])", md), part


DATE_OR_ISSUE = re.compile(
    r"\b(19|20)\d\d-\d\d-\d\d\b|\bissue\s*#?\d+|(?<![\w&])#\d+\b|\bsession\b|\bthe seed's\b",
    re.IGNORECASE,
)


def _no_dates_or_issues(text: str) -> None:
    found = DATE_OR_ISSUE.search(text)
    assert found is None, text[max(0, found.start() - 60) : found.end() + 60]


def test_the_report_templates_hold_no_dates_or_issue_numbers():
    import torchjfa

    files = sorted((Path(torchjfa.__file__).parent / "report").glob("*.py"))
    assert len(files) >= 6
    for path in files:
        _no_dates_or_issues(path.read_text())


# ------------------------------------------------------------------ the next-step rules
def _ok_consistency(c):
    ones = torch.ones_like(c.mass_ok)
    return dataclasses.replace(c, triangle_ok=ones, pseudo_inertia_ok=ones, mass_ok=ones,
                               inertia_ok=ones, friction_ok=ones)  # fmt: skip


def _fit(nmse, rms, predicted):
    from torchjfa.report import TorqueFit

    return TorqueFit(nmse=nmse, rms=rms, predicted=predicted)


@pytest.fixture(scope="module")
def good(report):
    """The report made into one no rule objects to: 5x better than the description on every
    joint (nMSE 0.02), consistent, every identifiable parameter determined, no warning."""
    fits = dict(report.fits)
    desc = fits["description"]
    fits["identified"] = _fit(torch.full_like(desc.nmse, 0.02), desc.rms / 5, desc.predicted)
    status = tuple("determined" if s == "poorly excited" else s for s in report.base.status)
    return dataclasses.replace(
        report,
        fits=fits,
        consistency=_ok_consistency(report.consistency),
        base=dataclasses.replace(report.base, status=status),
        settings={"robot": "head", "warnings": []},
    )


def _steps(report, path="model.npz"):
    return list(report.judge(path).next_steps)


def test_a_good_result_is_loaded(good):
    (step,) = _steps(good, "out/model.npz")
    assert step.startswith("load the model") and 'load_identified("out/model.npz")' in step
    md = good.markdown(folder="out")
    assert f"- **Next step**: {step}" in md and "- Warnings: none" in md
    assert "**Better than the description by 5.0x** on held-out data" in md
    assert "(better on every joint)" in md


def test_torques_in_another_unit_ask_for_drive_gains(good):
    v = good.validation
    scaled = dataclasses.replace(good, validation=dataclasses.replace(v, tau=v.tau * 10.0))
    steps = _steps(scaled)
    assert "about 10" in steps[0] and "--drive-gains" in steps[0]
    assert not any(s.startswith("load") for s in steps)
    flipped_tau = v.tau.clone()
    j = good.model.joint_names.index("neck_tilt")
    flipped_tau[:, j] *= -1
    flipped = dataclasses.replace(good, validation=dataclasses.replace(v, tau=flipped_tau))
    steps = _steps(flipped)
    assert steps[0].startswith("the measured torque of neck_tilt runs against")
    assert "sign" in steps[0]


def test_worse_than_the_description_says_check_the_torques_and_not_load(good):
    fits = dict(good.fits)
    fits["identified"], fits["description"] = fits["description"], fits["identified"]
    worse = dataclasses.replace(good, fits=fits)
    steps = _steps(worse)
    assert steps[0].startswith("the held-out error is worse than the description's")
    assert not any(s.startswith("load") for s in steps)
    assert "**Worse than the description** on held-out data (5.0x its error)" in worse.markdown()
    d = fits["identified"]
    useless = dict(good.fits, identified=_fit(torch.full_like(d.nmse, 1.5), d.rms, d.predicted))
    steps = _steps(dataclasses.replace(good, fits=useless))
    assert "no better than their mean" in steps[0]
    assert not any(s.startswith("load") for s in steps)


def test_no_convergence_asks_for_more_iterations(good):
    capped = copy.copy(good.result.estimator)
    capped.converged_, capped.n_iter_, capped.stop_reason_ = False, 2000, "max_iter"
    steps = _steps(_with_estimator(good, capped))
    assert steps[0].startswith("BayesianJFA did not converge") and "--max-iter" in steps[0]
    assert "read the warning" in steps[1] and steps[2].startswith("load")


def test_inconsistent_bodies_ask_for_log_cholesky_or_the_projection(good, report):
    triangle = dataclasses.replace(good, consistency=report.consistency)  # triangle fails
    steps = _steps(triangle)
    assert "violate the triangle inequalities" in steps[0]
    assert "--parametrization log-cholesky" in steps[0] and steps[-1].startswith("load")
    c = report.consistency
    mass = dataclasses.replace(c, mass_ok=torch.zeros_like(c.mass_ok))
    r = dataclasses.replace(good.result, projection=None)
    raw = dataclasses.replace(good, consistency=mass, result=r)
    steps = _steps(raw)
    assert "are not physical" in steps[0] and "leave out `--no-project`" in steps[0]
    assert not any(s.startswith("load") for s in steps)  # no description file, no model


def test_badly_explained_or_poorly_excited_joints_ask_for_excitation(good, report):
    d = good.fits["identified"]
    nmse = d.nmse.clone()
    nmse[4] = 0.8  # left_eye_tilt: the model explains 20 % of its torque
    bad = dataclasses.replace(good, fits=dict(good.fits, identified=_fit(nmse, d.rms,
                                                                         d.predicted)))  # fmt: skip
    steps = _steps(bad)
    assert steps[0].startswith("excite left_eye_tilt more (the model explains less than half")
    assert "`torchjfa excite head --out traj`" in steps[0] and steps[1].startswith("load")
    poor = dataclasses.replace(good, base=report.base)  # 15 poorly excited parameters
    joints = {n.rsplit(".", 1)[0] for n, s in zip(report.base.names, report.base.status,
                                                  strict=True) if s == "poorly excited"}  # fmt: skip
    steps = _steps(poor)
    named = steps[0].split(" more (")[0].removeprefix("excite ").split(", ")
    assert set(named) == joints and "leaves some of their parameters to the noise" in steps[0]


def test_warnings_are_counted_ranked_and_read(good):
    warnings = [
        "--cutoff auto: /data/run1.csv: 2.8 s are too short to choose a cut-off; 20 Hz used",
        "/data/run1.csv: the torque of joint(s) neck_roll (scale -1, viscous -0.1, Coulomb "
        "-0.2) runs against the description's prediction: check its sign convention",
        "the held-out data move beyond the identification data, so their errors measure "
        "extrapolation: neck_pan q beyond its training range",
    ]
    warned = dataclasses.replace(good, settings={"warnings": warnings})
    v = warned.judge()
    assert v.warnings[0].startswith("/data/run1.csv: the torque")  # the sign first
    assert v.warnings[1].startswith("the held-out data move beyond")
    steps = _steps(warned)
    assert steps == ['read the 3 warnings (section "Warnings") and act on each', steps[1]]
    md = warned.markdown()
    verdict = _section(md, "Verdict")
    assert '- Warnings: 3 (all in the section "Warnings"); the most urgent:' in verdict
    assert "  - the torque of joint(s) neck_roll (scale -1, viscous -0.1, Coulomb -0.2) runs " \
        "against the description's prediction" in verdict  # fmt: skip
    assert "  - the held-out data move beyond the identification data, so their errors " \
        "measure extrapolation" in verdict  # fmt: skip
    assert len(_section(md, "Warnings")) == 2 + 3 + 1


def test_at_most_three_steps_most_urgent_first(good, report):
    capped = copy.copy(good.result.estimator)
    capped.converged_ = False
    v = good.validation
    everything = dataclasses.replace(
        _with_estimator(good, capped),
        consistency=report.consistency,
        base=report.base,
        validation=dataclasses.replace(v, tau=v.tau * 10.0),
        settings={"warnings": ["something"]},
    )
    steps = _steps(everything)
    assert len(steps) == 3
    assert "--drive-gains" in steps[0] and "did not converge" in steps[1]
    assert "triangle" in steps[2]


def test_a_joint_no_fit_predicts_is_named_with_what_to_check(good):
    """One joint's held-out nMSE at 1.4 for the identified model and 1.2 for the unconstrained
    estimate, every other joint explained: that channel does not follow the motion."""
    fits = dict(good.fits)
    j = good.model.joint_names.index("neck_roll")
    for name, value in (("identified", 1.4), ("unconstrained", 1.2)):
        f = fits[name]
        nmse = f.nmse.clone()
        nmse[j] = value
        fits[name] = _fit(nmse, f.rms, f.predicted)
    steps = _steps(dataclasses.replace(good, fits=fits))
    channel = [s for s in steps if "no better than its mean" in s]
    assert len(channel) == 1 and "neck_roll (nMSE 1.4, unconstrained 1.2)" in channel[0]
    assert "sign" in channel[0] and "offset" in channel[0]
    # the unconstrained estimate explains it: the consistent model is at fault, not the channel
    fits["unconstrained"] = good.fits["unconstrained"]
    steps = _steps(dataclasses.replace(good, fits=fits))
    assert not any("no better than its mean" in s for s in steps)
