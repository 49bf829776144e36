"""The input noise of a floating-base regression (`propagated_legged_noise`): the sensors' noise
read from the raw log's spectra and pushed through the flow, checked against what the noise
actually did to the rows of a simulated log whose noise-free signals are known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.cli import main
from torchjfa.data import LogError
from torchjfa.data._spectrum import floor_variance
from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import (
    IdentificationError,
    IdentificationWarning,
    Options,
    identify_legged,
)
from torchjfa.identification._contacts import contact_equations
from torchjfa.identification._legged import prepared_log
from torchjfa.identification._legged_noise import (
    legged_signal_noise,
    propagated_legged_noise,
)
from torchjfa.sim import LEGGED_NOISE, simulate_legged

CUTOFF = 10.0


@pytest.fixture(scope="module")
def go2():
    """A perturbed Go2 standing and swaying, 12 s at 200 Hz, noise-free and with 3x the
    default sensor noise."""
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, GO2_FEET, GO2_STANCE, seconds=12.0, perturb=0.2, seed=3)
    clean = replace(log, v=None, a=None)  # as a log holds it: the pose, no derivatives
    return {"path": path, "clean": clean, "noisy": log.noisy(scale=3.0, seed=5)}


def test_the_spectra_floors_give_the_sensors_noise(go2):
    stds = legged_signal_noise(go2["noisy"])
    # the Welch floor's median over ~100 bins of ~20 segments each: a few per cent on the
    # variance, so 15 % on the standard deviation is loose; the noise-free log's own floor
    # (the 1 kHz integrator's, far below) adds nothing at this level
    truth = {"base_position": 3 * LEGGED_NOISE["base_position"],
             "joint_position": 3 * LEGGED_NOISE["joint_position"]}  # fmt: skip
    for name, sd in truth.items():
        np.testing.assert_allclose(stds[name], sd, rtol=0.15, err_msg=name)
    # the quaternion is normalised after the noise: the three components across the
    # orientation keep their noise, the one along it (w, for a base that stays nearly level)
    # loses it to first order
    quat = np.sort(stds["base_quaternion"])
    np.testing.assert_allclose(quat[1:], 3 * LEGGED_NOISE["base_quaternion"], rtol=0.15)
    assert quat[0] < 0.2 * 3 * LEGGED_NOISE["base_quaternion"]


def test_the_propagated_noise_matches_what_the_noise_did_to_the_rows(go2):
    """The Monte Carlo's per-column noise, from the noisy log alone, against the mean square
    difference between the rows of the noisy log and of its noise-free original, both
    prepared alike."""
    model = FloatingBaseModel.from_urdf(go2["path"], friction=())
    noisy, clean = go2["noisy"], go2["clean"]
    r = 6 + model.n_dof
    weights = torch.linspace(0.5, 2.0, r, dtype=torch.float64)
    t0, t1 = float(noisy.t[0]) + 1.0, float(noisy.t[-1]) - 1.0

    def prepare(raw):
        return prepared_log(raw, CUTOFF)

    got = propagated_legged_noise(model, [(noisy, t0, t1)], prepare, rows="all",
                                  weights=weights, n_draws=6, max_samples=600)  # fmt: skip
    keep = np.flatnonzero((noisy.t >= t0) & (noisy.t <= t1))
    a, b = (prepare(x).select(keep) for x in (noisy, replace(clean, wrench=noisy.wrench)))
    Y = [contact_equations(model, x.q, x.v, x.a, x.tau, wrenches=x.wrench)[0] for x in (a, b)]
    actual = torch.einsum("brp,r->p", (Y[0] - Y[1]) ** 2, weights) / (len(keep) * weights.sum())
    # the columns the noise reaches (round-off elsewhere)
    live = actual > 1e-6 * actual.max()
    ratio = got.input_noise[live] / actual[live]
    # one draw of the actual noise against the Monte Carlo's mean over six: each column's mean
    # square over ~2000 correlated filtered samples scatters by tens of per cent, the total
    # over columns far less
    assert 0.5 < float(ratio.median()) < 2.0
    assert float(got.input_noise.sum() / actual.sum()) == pytest.approx(1.0, rel=0.35)
    assert got.n_samples == len(keep[:: int(np.ceil(len(keep) / 600))])
    assert "base position" in got.describe()


def test_bayesian_jfa_gets_the_propagated_noise_and_least_squares_none(go2):
    log = go2["noisy"]
    ols = identify_legged(go2["path"], log, Options(cutoff=CUTOFF))
    assert ols.settings["input_noise"].startswith("none given")
    # 3x the default noise on a body that sways by centimetres: the propagated noise swamps
    # many columns, and the warning says so (one start of the bound's optimiser: a check)
    bayes = Options(cutoff=CUTOFF, estimator="bayes-jfa", estimator_options={"n_starts": 1})
    with pytest.warns(IdentificationWarning, match="at least half the signal"):
        bjfa = identify_legged(go2["path"], log, bayes)
    assert bjfa.settings["input_noise"].startswith("propagated by Monte Carlo")
    assert bjfa.settings["estimator"] == "BayesianJFA"
    learned = identify_legged(go2["path"], log, bayes.replace(input_noise="learn"))
    assert learned.settings["input_noise"].startswith("none given")
    assert not torch.equal(learned.theta_hat, bjfa.theta_hat)


def test_input_noise_choices_a_legged_log_cannot_serve_are_refused(go2):
    path, log = go2["path"], go2["noisy"]
    with pytest.raises(IdentificationError, match="repeated excitation periods"):
        identify_legged(path, log, Options(cutoff=CUTOFF, input_noise="periods"))
    with pytest.raises(IdentificationError, match="bayes-jfa"):
        identify_legged(path, log, Options(cutoff=CUTOFF, input_noise="propagated"))
    with pytest.raises(IdentificationError, match="shape"):
        identify_legged(path, log, Options(cutoff=CUTOFF, estimator="bayes-jfa",
                                            input_noise=[1e-6, 1e-6]))  # fmt: skip


def test_the_command_line_names_the_flag(go2, tmp_path, capsys):
    csv = tmp_path / "go2.csv"
    go2["noisy"].save(csv)
    rc = main(["identify", go2["path"], str(csv), "--out", str(tmp_path / "out"),
               "--input-noise", "periods", "--cutoff", str(CUTOFF)])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert "--input-noise periods" in err and "Traceback" not in err


def test_a_signal_without_a_noise_floor_is_named(go2):
    """A signal whose spectrum peaks at the Nyquist frequency (a vibration at 99 Hz sampled at
    200 Hz) has no floor above its band to read: `floor_variance` gives NaN, and the legged
    log's error names the signal."""
    rng = np.random.default_rng(0)
    t = np.arange(4000) / 200.0
    white = 0.01 * rng.standard_normal((4000, 2))
    var, _ = floor_variance(white, 200.0, 256)
    np.testing.assert_allclose(var, 1e-4, rtol=0.2)  # white noise: its floor
    hum = white + np.sin(2 * np.pi * 99.0 * t)[:, None]
    var, _ = floor_variance(hum, 200.0, 256)
    assert np.isnan(var).all()
    log = go2["noisy"]
    q = log.q.copy()
    q[:, 8] += 1e-2 * np.sin(2 * np.pi * 99.0 * log.t)
    with pytest.raises(LogError, match=r"joint position \(column 1\) does not flatten"):
        legged_signal_noise(replace(log, q=q))
