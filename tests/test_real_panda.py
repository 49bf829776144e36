"""The real Panda log (../shared/data/panda_gaz2019): the data-chosen cut-off and the script's
smoke run. Skipped where the log is absent (it is not shipped with the package)."""

import importlib.util
import io
from pathlib import Path

import pytest
import torch

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "panda_gaz2019"
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "real_panda.py"

pytestmark = pytest.mark.skipif(
    not (DATA / "torques.txt").is_file(), reason=f"no real Panda log in {DATA}"
)


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("real_panda", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_cut_off_chosen_on_the_training_part_is_inside_the_grid(script):
    from torchjfa.cli import load_model
    from torchjfa.data import choose_cutoff

    model = load_model("panda_arm", ("viscous", "coulomb", "offset"))
    log = script.load_panda(DATA)
    train = log.select(log.t < log.t[0] + 0.8 * log.duration)
    choice = choose_cutoff(model, train)
    # the real torques hold both filter-removable signal (2 Hz loses it) and noise (30 Hz
    # differentiates it twice into the accelerations): neither end of the grid wins
    assert choice.grid_hz[0] < choice.cutoff_hz < choice.grid_hz[-1]
    assert choice.scores[choice.grid_hz.index(choice.best_hz)] == min(choice.scores)
    assert min(choice.scores) < min(choice.scores[0], choice.scores[-1])
    # the real joints' dry friction changes sign over a band of velocities: at the chosen
    # cut-off a smoothed Coulomb term predicts the held-out blocks better than sign(qd)
    assert choice.coulomb_velocity > 0.0
    assert min(choice.coulomb_scores) < choice.coulomb_scores[choice.coulomb_grid.index(0.0)]


def test_the_script_runs_in_smoke_size(script):
    out = io.StringIO()
    rows = script.run(DATA, smoke=True, out=out)
    text = out.getvalue()
    assert set(rows) == {"defaults", "ols", "description"}
    for row in rows.values():
        assert row["rms"].shape == (7,) and bool(torch.isfinite(row["rms"]).all())
    # the description's parameters (no friction) predict the real torques far worse than any
    # identified row: the README measures about 1.5 N m against about 0.1-0.3 identified
    assert float(rows["defaults"]["rms"].mean()) < 0.5 * float(rows["description"]["rms"].mean())
    assert "defaults vs hand-tuned OLS" in text and "link masses" in text
    # the defaults pull the projection towards the description where the data are silent
    # (description_prior="auto"): every link mass plausible, within [0.3x, 3x] of the URDF's
    # (without the prior, on the whole training part, links 1, 2 and 7 fell outside it)
    model, theta = rows["defaults"]["model"], rows["defaults"]["theta"]
    lo, hi = script.MASS_BAND
    masses = script._masses(model, theta), script._masses(model, model.nominal_theta)
    for m, m0 in zip(*masses, strict=True):
        assert lo * m0 <= m <= hi * m0
    assert sum(line.startswith("  panda_joint") for line in text.splitlines()) == 7


def test_the_script_says_so_without_the_log(script, tmp_path):
    out = io.StringIO()
    assert script.run(tmp_path, out=out) is None
    assert "no Panda log" in out.getvalue()


def test_the_split_points_table_judges_each_row_on_its_window(script):
    out = io.StringIO()
    (r,) = script.origins(DATA, times=(6.0,), window_s=1.0, cutoffs=(8.0,), out=out)
    text = out.getvalue()
    assert r["t"] == pytest.approx(6.0, abs=2e-3)  # the first sample at or after 6 s
    assert 0.0 <= r["inside"] <= 1.0 and set(r["ols"]) == {8.0}
    assert 0.0 < r["defaults"] < 1.0 and 0.0 < r["ols"][8.0] < 1.0  # N m, identified rows
    assert r["cutoff_hz"] > 0
    # the printed comparison is the returned one
    assert f"{100 * (1 - r['defaults'] / r['ols'][8.0]):+.1f} %" in text
    assert "mean over the 1 splits" in text
    # a split point past the log's end is skipped with a line, not a traceback
    out = io.StringIO()
    assert script.origins(DATA, times=(60.0,), window_s=1.0, cutoffs=(8.0,), out=out) == []
    assert "skipped" in out.getvalue()


def test_the_default_projection_on_the_real_log_is_certified(script):
    """The default identification's projection reaches the optimum of its convex problem
    (cvxpy, Clarabel, over the closure of the consistent set: a lower bound) to 1e-6."""
    import warnings

    import torchjfa
    from torchjfa.identification import IdentificationWarning
    from torchjfa.identification._prior import prior_options
    from torchjfa.physical import certify, project_convex

    pytest.importorskip("cvxpy")
    log = script.load_panda(DATA)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(script.ROBOT, log, torchjfa.Options(jackknife=0))
    r = ident.result
    extra = prior_options(r.model, r.moments, r.theta_hat, float(r.prior_weight))
    convex = project_convex(
        r.theta_hat, layout=r.model, moments=r.moments, input_noise=r.input_noise,
        parametrization="log-cholesky", ridge=0.0, **extra,
    )  # fmt: skip
    ok, gap = certify(r.projection, convex)
    assert ok, gap
