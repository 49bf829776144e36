"""Preparing logs: resampling, period detection, transients, filtering, decimation."""

import math

import numpy as np
import pytest
import torch

from torchjfa.data import (
    JointLog,
    LogError,
    detect_period,
    is_uniform,
    prepare,
    resample,
    transient_periods,
)

RATE = 200.0
PERIOD = 2.5  # s: 500 samples at 200 Hz


def _signal(t):
    """Two joints of a periodic excitation (harmonics of 1/PERIOD Hz, up to 2 Hz)."""
    w = 2 * math.pi / PERIOD
    q = np.stack(
        [
            0.5 * np.sin(w * t) + 0.2 * np.sin(3 * w * t + 1.0),
            0.3 * np.cos(2 * w * t) + 0.1 * np.sin(5 * w * t),
        ],
        axis=1,
    )
    qd = np.stack(
        [
            0.5 * w * np.cos(w * t) + 0.6 * w * np.cos(3 * w * t + 1.0),
            -0.6 * w * np.sin(2 * w * t) + 0.5 * w * np.cos(5 * w * t),
        ],
        axis=1,
    )
    qdd = np.stack(
        [
            -0.5 * w**2 * np.sin(w * t) - 1.8 * w**2 * np.sin(3 * w * t + 1.0),
            -1.2 * w**2 * np.cos(2 * w * t) - 2.5 * w**2 * np.sin(5 * w * t),
        ],
        axis=1,
    )
    return q, qd, qdd


def _log(t, noise=0.0, seed=0):
    q, _, qdd = _signal(t)
    rng = np.random.default_rng(seed)
    return JointLog(
        t=t,
        q=q + noise * rng.standard_normal(q.shape),
        tau=2.0 * qdd + 0.01 * rng.standard_normal(q.shape),
        joint_names=("a", "b"),
    )


def test_period_of_a_noisy_sum_of_sinusoids_to_a_fraction_of_a_sample():
    t = np.arange(int(20 * PERIOD * RATE)) / RATE
    log = _log(t, noise=1e-3)
    est = detect_period(log.q, RATE)
    assert est is not None
    assert abs(est - PERIOD) * RATE < 0.01  # in samples


def test_period_of_the_simulated_robot_and_none_for_noise(head_sim):
    sim = head_sim  # 12 s at 420 Hz
    est = detect_period(sim.q, sim.control_rate)
    assert est is not None
    assert abs(est * sim.control_rate - sim.period_samples) < 0.05
    rng = np.random.default_rng(0)
    assert detect_period(rng.standard_normal((4000, 3)), RATE) is None
    chirp = np.sin(2 * np.pi * np.cumsum(np.linspace(0.2, 3.0, 4000)) / RATE)
    assert detect_period(chirp, RATE) is None


def test_uneven_time_is_resampled_onto_a_uniform_grid():
    rng = np.random.default_rng(1)
    n = 2000
    t = np.arange(n) / RATE + rng.uniform(-0.2, 0.2, n) / RATE  # 20 % jitter
    t = np.sort(t)
    log = _log(t)
    assert not is_uniform(log.t)
    r = resample(log)
    assert is_uniform(r.t)
    q, _, _ = _signal(r.t.numpy())
    assert float((r.q - torch.from_numpy(q)).abs().max()) < 1e-4


def test_prepare_gives_accurate_derivatives_on_an_uneven_log_with_a_gap():
    rng = np.random.default_rng(2)
    t = np.arange(4000) / RATE + rng.uniform(-0.1, 0.1, 4000) / RATE
    keep = np.ones(4000, bool)
    keep[1000:1004] = False  # four dropped rows (e.g. NaN rows dropped)
    log = _log(t[keep], noise=2e-5)
    out = prepare(log, cutoff_hz=10.0, period_s=None)
    assert out.info["resampled"] and is_uniform(out.t)
    _, qd, qdd = _signal(out.t.numpy())
    err_qd = float((out.qd - torch.from_numpy(qd)).abs().max() / np.abs(qd).max())
    err_qdd = float((out.qdd - torch.from_numpy(qdd)).abs().max() / np.abs(qdd).max())
    assert err_qd < 5e-3 and err_qdd < 2e-2
    # the torques got the same zero-phase filter: their noise is smaller
    assert float((out.tau - 2 * torch.from_numpy(qdd)).std()) < 0.01


def test_prepare_makes_the_period_whole_and_trims_the_ends():
    rate = 203.7  # a period of 509.25 samples: resampled to 509
    t = np.arange(int(10 * PERIOD * rate)) / rate
    log = _log(t, noise=1e-4)
    out = prepare(log, cutoff_hz=10.0)
    assert out.period_samples == 509
    assert out.info["resampled"]
    assert abs(out.period_samples / out.info["rate_hz"] - PERIOD) < 1e-4
    # 4 / cutoff seconds dropped at each end
    assert out.info["dropped_start_s"] == pytest.approx(0.4, abs=1.5 / rate)
    assert float(out.t[0] - log.t[0]) == pytest.approx(0.4, abs=1.5 / rate)


def test_start_up_transient_is_found_from_the_periods():
    t = np.arange(int(8 * PERIOD * RATE)) / RATE
    log = _log(t, noise=1e-4)
    ramp = np.clip(t / (1.5 * PERIOD), 0.0, 1.0)[:, None]  # the robot eases into the motion
    log.q = log.q * torch.from_numpy(ramp)
    P = int(PERIOD * RATE)
    assert transient_periods(log.q, P) == 2
    assert transient_periods(_log(t, noise=1e-4).q, P) == 0
    out = prepare(log, cutoff_hz=10.0, skip_start_s="auto")
    assert out.info["dropped_start_s"] == pytest.approx(0.4 + 2 * PERIOD, abs=2 / RATE)
    with pytest.raises(LogError, match="no period was found"):
        prepare(log, cutoff_hz=10.0, period_s=None, skip_start_s="auto")


def test_decimation_checks_the_cut_off():
    t = np.arange(4000) / RATE
    log = _log(t)
    out = prepare(log, cutoff_hz=10.0, decimate=4)
    assert out.info["rate_hz"] == pytest.approx(RATE / 4)
    assert out.period_samples == int(PERIOD * RATE) // 4
    full = prepare(log, cutoff_hz=10.0)
    torch.testing.assert_close(out.qdd, full.qdd[::4])
    with pytest.raises(LogError, match="aliasing"):
        prepare(log, cutoff_hz=30.0, decimate=4)


def test_measured_velocity_is_used_when_present():
    t = np.arange(3000) / RATE
    log = _log(t)
    _, qd, _ = _signal(t)
    log.qd = torch.from_numpy(qd) + 0.5  # an offset that differentiating q would not show
    out = prepare(log, cutoff_hz=10.0)
    assert out.info["velocity"] == "measured"
    _, qd_true, _ = _signal(out.t.numpy())
    assert float((out.qd - torch.from_numpy(qd_true)).mean()) == pytest.approx(0.5, abs=1e-3)
    out = prepare(log, cutoff_hz=10.0, velocity="differentiate")
    assert abs(float((out.qd - torch.from_numpy(qd_true)).mean())) < 1e-3


def test_too_short_for_the_filter():
    t = np.arange(30) / RATE
    with pytest.raises(LogError, match="samples"):
        prepare(_log(t), cutoff_hz=10.0, period_s=None)
