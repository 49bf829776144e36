"""`torchjfa.data.signal_noise` (sensor noise from the spectrum) and `propagated_noise` (that
noise pushed through the preparation and the regressor), checked against noise that is known:
synthetic white noise, and simulated logs whose sensor noise and noiseless signals are known."""

import math

import numpy as np
import pytest
import torch
from scipy import stats

from torchjfa.data import (
    JointLog,
    LogError,
    prepare,
    propagated_noise,
    regressor_noise,
    signal_noise,
)
from torchjfa.identification import load_model
from torchjfa.sim import SensorNoise, generate_log

RATE = 1000.0
STDS = np.array([1e-3, 3e-3, 2e-2])  # per joint


def _synthetic(n=20000, seed=0, top_hz=8.0):
    """Three joints: sinusoids up to ``top_hz`` plus white noise of `STDS`, and the noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    f = np.linspace(0.5, top_hz, 6)
    signal = np.stack([np.sin(2 * np.pi * f[:, None] * t + k).sum(0) for k in range(3)], 1)
    noise = rng.standard_normal((n, 3)) * STDS
    x = torch.from_numpy(signal + noise)
    log = JointLog(t=torch.from_numpy(t), q=x, tau=10.0 * x, joint_names=("a", "b", "c"))
    return log, noise


def _median_rel_std(n, segment, n_bins):
    """Relative std of the bias-corrected median of ``n_bins`` Welch bins: each bin is
    ``chi^2_nu / nu`` (Welch's nu for Hann at half overlap, c_1 = 1/6 at large segments),
    the median of m independent ones has std ``sqrt(pi / 2) * sqrt(2 / nu) / sqrt(m)`` (the
    normal limit); Hann's neighbouring bins overlap, so m is taken as half the bins."""
    K = (n - segment) // (segment // 2) + 1
    nu = 2 * K / (1 + 2 * (1 / 6) ** 2)
    return math.sqrt(math.pi / 2) * math.sqrt(2 / nu) / math.sqrt(n_bins / 2)


def test_signal_noise_recovers_white_noise_under_a_low_band_signal():
    log, noise = _synthetic()
    est = signal_noise(log)
    realised = torch.from_numpy(noise.var(0))
    assert set(est.variance) == {"q", "tau"} and est.detected and est.segment == 256
    for name, scale in (("q", 1.0), ("tau", 100.0)):
        band = est.band_hz[name]
        # above the signal (and its window leakage, 70 Hz for 1e-3 noise under 1 rad)
        assert bool((band > 8.0).all()) and bool((band < 150.0).all())
        n_bins = int((RATE / 2 - float(band.max())) / (RATE / 256))
        tol = 5 * _median_rel_std(20000, 256, n_bins)  # about 7 %
        torch.testing.assert_close(est.variance[name] / scale, realised, rtol=tol, atol=0)
    # a given band's edge gives the same floor to the same tolerance, and says it was given
    given = signal_noise(log, band_hz=100.0)
    assert not given.detected and bool((given.band_hz["q"] >= 100.0).all())
    torch.testing.assert_close(given.variance["q"], realised, rtol=tol, atol=0)
    assert "q 0.0" in est.describe() and "detected" in est.describe()


def test_median_bias_correction_matches_chi_square():
    """Pure white noise over many seeds: the corrected median is unbiased to its own error."""
    from torchjfa.data._spectrum import _median_bias

    # the helper's nu against Welch's formula with the Hann overlap correlation c_1 = 1/6
    b = _median_bias(256, 20000)
    K = (20000 - 256) // 128 + 1
    nu = 2 * K / (1 + 2 * (1 - 1 / K) * (1 / 6) ** 2)
    assert abs(b - stats.chi2.median(nu) / nu) < 2e-3
    rng = np.random.default_rng(1)
    ratios = []
    for _ in range(20):
        x = torch.from_numpy(rng.standard_normal((20000, 1)))
        t = torch.arange(20000, dtype=torch.float64) / RATE
        log = JointLog(t=t, q=x, tau=x, joint_names=("a",))
        ratios.append(float(signal_noise(log, band_hz=20.0).variance["q"][0]))
    # 20 seeds of 2 % each: the mean within 4 x 2 % / sqrt(20) of the true variance 1
    assert abs(np.mean(ratios) - 1.0) < 4 * _median_rel_std(20000, 256, 240) / math.sqrt(20)


def test_signal_noise_rejects_what_it_cannot_read():
    log, _ = _synthetic(n=2000)
    with pytest.raises(LogError, match="too few"):
        signal_noise(log.select(slice(0, 40)))
    with pytest.raises(LogError, match="band_hz must lie"):
        signal_noise(log, band_hz=600.0)
    with pytest.raises(LogError, match="segment must lie"):
        signal_noise(log, segment=4)
    with pytest.raises(LogError, match="does not flatten"):
        signal_noise(log, band_hz=490.0)  # three bins left


# ------------------------------------------------------------------------------ propagation
PERIODS = 5
PREP = {"cutoff_hz": 20.0, "method": "butterworth", "period_s": 4.0, "skip_start_s": 0.0}


@pytest.fixture(scope="module")
def head_logs():
    """The head on one trajectory twice with independent sensor noise and once without (the
    controller sees the true state, so the motion is the same), and its model."""
    n = 420 * 4 * PERIODS
    one = generate_log("head", n_samples=n, noise=SensorNoise(), seed=1)
    two = generate_log("head", n_samples=n, noise=SensorNoise(), seed=2, trajectory=one.trajectory)
    zero = generate_log("head", n_samples=n, noise=SensorNoise.zero(), trajectory=one.trajectory)
    assert torch.equal(one.q_true, two.q_true) and not torch.equal(one.q, two.q)
    assert torch.equal(one.q_true, zero.q)
    return load_model("head"), one, two, zero


def _raw(log):
    """The log as a raw recording (q, qd, tau)."""
    return JointLog(t=log.t, q=log.q, qd=log.qd, tau=log.tau, joint_names=log.joint_names)


def test_propagated_noise_matches_the_periods_and_the_truth(head_logs):
    """On the smooth columns the propagated column noise agrees with the spread between the
    periods and with the truth (the noisy logs' regressors against the noiseless one's).

    Tolerance, per column: one Monte Carlo draw has relative spread s = err * sqrt(n_draws) /
    noise (one draw is one realisation of the log's noise); the truth averages two
    realisations (s / sqrt 2), the periods estimate K - 1 degrees of freedom of the K whole
    periods' rows (s * sqrt(K / (K - 1) * n / (K P)) for n prepared samples, P per period); the
    Monte Carlo mean has err / noise. Four standard
    deviations of the difference, plus the largest relative error of the spectrum's q and qd
    variances against the simulator's (the column noise is a positive mix of them). The
    Coulomb columns (sign of qd) are left out: a discontinuous column's spread between two
    noisy draws and between a noisy and the noiseless one differ (no first-order equivalence).
    """
    model, one, two, noiseless = head_logs
    prop = propagated_noise(model, _raw(one), PREP, n_draws=8, seed=0)
    known = SensorNoise()
    r = max(
        float((prop.signal_noise.variance[k] / std**2 - 1.0).abs().max())
        for k, std in (("q", known.position_std), ("qd", known.velocity_std))
    )
    assert r < 0.1  # the spectrum's own check (test above), here on a simulated robot

    def Y(log):
        p = prepare(log, **PREP)
        return p, model.regressor(p.q, p.qd, p.qdd)

    p1, Y1 = Y(_raw(one))
    _, Y2 = Y(_raw(two))
    _, Y0 = Y(_raw(noiseless))
    truth = 0.5 * ((Y1 - Y0).pow(2) + (Y2 - Y0).pow(2)).mean(dim=(0, 1))
    periods = regressor_noise(model, p1)
    K, P = periods.n_periods, periods.period_samples  # the filter's edges cost one period
    assert K == PERIODS - 1 and prop.n_rows == p1.n_samples * model.n_dof

    noise, err = prop.input_noise, prop.input_noise_error
    zero = truth <= 1e-24 * float(truth.max())  # constant or absent columns: no noise at all
    assert bool((noise[zero] <= 1e-24 * float(noise.max())).all())
    names = model.layout.parameter_names
    smooth = ~zero & torch.tensor([not n.endswith(".fc") for n in names])
    assert int(smooth.sum()) > 0.8 * model.n_params - int(zero.sum())
    rel = err[smooth] / noise[smooth]
    s = rel * math.sqrt(prop.n_draws)
    per = s * math.sqrt(K / (K - 1) * p1.n_samples / (K * P))  # fewer rows, K - 1 dof
    for ref, spread in ((truth, s / math.sqrt(2)), (periods.input_noise, per)):
        tol = 4 * torch.sqrt(rel**2 + spread**2) + r
        dev = (ref[smooth] / noise[smooth] - 1.0).abs()
        assert bool((dev <= tol).all()), (dev / tol).max()
    # the torque: the prepared noise's variance against the noiseless log's, to 5 % (about
    # 8000 x 7 samples of a 20 Hz band: thousands of independent ones)
    tau0 = prepare(_raw(noiseless), **PREP).tau
    torch.testing.assert_close(
        prop.output_noise, (p1.tau - tau0).pow(2).mean(), rtol=0.05 + r, atol=0
    )


def test_propagated_noise_weights_seed_rows_and_fixed_choices(head_logs):
    model, one, *_ = head_logs
    raw = _raw(one).select(slice(0, 420 * 4 * 3))
    a = propagated_noise(model, raw, PREP, n_draws=2, seed=3)
    b = propagated_noise(model, raw, PREP, n_draws=2, seed=3, noise=a.signal_noise)
    assert torch.equal(a.input_noise, b.input_noise)  # the seed fixes the draws
    # uniform joint weights c scale every column's noise and power by c (rows weighted by c)
    w = propagated_noise(
        model, raw, PREP, n_draws=2, seed=3, noise=a.signal_noise, joint_weights=[3.0] * 7
    )
    torch.testing.assert_close(w.input_noise, 3.0 * a.input_noise, rtol=1e-12, atol=0)
    torch.testing.assert_close(w.column_power, 3.0 * a.column_power, rtol=1e-12, atol=0)
    # a detected period and start-up transient are held at the log's own choice: rows line up
    auto = {**PREP, "period_s": "auto", "skip_start_s": "auto"}
    c = propagated_noise(model, raw, auto, n_draws=2, noise=a.signal_noise)
    assert c.n_rows == prepare(raw, **auto).n_samples * model.n_dof
    head = propagated_noise(model, raw, PREP, n_draws=2, seed=3, noise=a.signal_noise, samples=99)
    assert head.n_rows == 99 * model.n_dof
    assert "Monte Carlo (2 draws" in a.describe()
    with pytest.raises(ValueError, match="n_draws"):
        propagated_noise(model, raw, PREP, n_draws=1)
    with pytest.raises(ValueError, match="samples must lie"):
        propagated_noise(model, raw, PREP, n_draws=2, samples=10**7)
