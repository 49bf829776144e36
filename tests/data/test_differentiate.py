"""torchjfa.data.differentiate against written-out derivatives, scipy's causal filter and noise."""

import numpy as np
import pytest
import torch
from scipy import signal

from torchjfa.data import DEFAULT_CUTOFF_HZ, differentiate, savgol_window

RATE = 420.0


def _t(n, rate=RATE):
    return torch.arange(n, dtype=torch.float64) / rate


def _interior(n, rate=RATE, seconds=0.5):
    k = int(seconds * rate)
    return slice(k, n - k)


# Butterworth: flat passband, central-difference error (w h)^2 / 6 = 2.5e-4 at 4 Hz;
# Savitzky-Golay (order 4, 20 Hz window): errors up to 0.23 % at 4 Hz in the first derivative.
@pytest.mark.parametrize("method, tol", [("butterworth", 1e-3), ("savgol", 5e-3)])
def test_sinusoid_below_cutoff_is_differentiated(method, tol):
    t = _t(2000)
    f = np.array([0.5, 2.0, 4.0])  # Hz, well below the 20 Hz cut-off
    w = 2 * np.pi * torch.as_tensor(f)
    x = torch.sin(w * t[:, None] + 0.3)  # (n, 3)
    d = differentiate(t, x, method=method)
    inner = _interior(len(t))
    scale1 = w.max()
    scale2 = w.max() ** 2
    assert (d.value - x)[inner].abs().max() < tol
    assert ((d.first - w * torch.cos(w * t[:, None] + 0.3))[inner].abs().max() / scale1) < tol
    assert ((d.second + w**2 * torch.sin(w * t[:, None] + 0.3))[inner].abs().max() / scale2) < tol


def test_cubic_is_exact_in_the_interior_butterworth():
    t = _t(1500)
    x = (1.0 + 0.5 * t - 0.7 * t**2 + 0.2 * t**3)[:, None]
    d = differentiate(t, x)
    inner = _interior(len(t), seconds=1.0)
    # the zero-phase Butterworth is flat to order 8 at DC: cubics pass untouched; central
    # differences are exact for the derivatives of a cubic up to round-off
    assert torch.allclose(d.value[inner], x[inner], rtol=0, atol=1e-8)
    # central differences of a cubic: f' + h^2 f''' / 6 exactly, and f'' exactly
    h = 1.0 / RATE
    first = 0.5 - 1.4 * t + 0.6 * t**2 + h**2 * 1.2 / 6
    assert torch.allclose(d.first[inner, 0], first[inner], rtol=0, atol=1e-8)
    assert torch.allclose(d.second[inner, 0], (-1.4 + 1.2 * t)[inner], rtol=0, atol=1e-5)


def test_cubic_is_exact_everywhere_savgol_and_unfiltered():
    t = _t(300)
    x = torch.stack([2.0 - t + 3 * t**3, t**2], -1)
    first = torch.stack([-1 + 9 * t**2, 2 * t], -1)
    second = torch.stack([18 * t, 2 + 0 * t], -1)
    d = differentiate(t, x, method="savgol", polyorder=3)
    assert torch.allclose(d.value, x, atol=1e-10)
    assert torch.allclose(d.first, first, atol=1e-8)
    assert torch.allclose(d.second, second, atol=1e-6)
    raw = differentiate(t, x, cutoff_hz=None)  # plain central differences, exact on cubics
    assert torch.allclose(raw.second, second, atol=1e-6)
    assert torch.allclose(raw.first[:, 1], first[:, 1], atol=1e-9)


def _phase(y, t, w):
    """Phase of the sinusoid of frequency w in y, by least squares on sin and cos."""
    A = np.stack([np.sin(w * t), np.cos(w * t)], 1)
    a, b = np.linalg.lstsq(A, y, rcond=None)[0]
    return np.arctan2(b, a)


def test_zero_phase_no_lag_where_a_causal_filter_lags():
    t = _t(3000)
    w = 2 * np.pi * 8.0  # 8 Hz, close enough to the cut-off for a causal filter to lag
    x = torch.sin(w * t)
    d = differentiate(t, x, cutoff_hz=20.0)
    inner = _interior(len(t))
    tn = t.numpy()[inner]
    assert abs(_phase(d.value.numpy()[inner], tn, w)) < 1e-4
    # velocity leads by exactly pi/2
    assert abs(_phase(d.first.numpy()[inner], tn, w) - np.pi / 2) < 1e-3
    b, a = signal.butter(4, 20.0, fs=RATE)
    causal = signal.lfilter(b, a, x.numpy())
    assert abs(_phase(causal[inner], tn, w)) > 0.1  # the same filter run causally lags


def test_noise_variance_is_reduced():
    gen = torch.Generator().manual_seed(0)
    n = 20000
    t = _t(n)
    noise = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    d = differentiate(t, noise)
    var = d.value[500:-500].var().item()
    # an ideal low-pass of white noise keeps 2 fc / fs of its variance (0.095 here)
    expected = 2 * DEFAULT_CUTOFF_HZ / RATE
    assert 0.8 * expected < var < 1.2 * expected
    sg = differentiate(t, noise, method="savgol")
    assert sg.value[500:-500].var().item() < 0.3


def test_shapes_dtype_and_batch_dims():
    t = _t(400).to(torch.float32)
    x = torch.randn(400, 2, 3, dtype=torch.float32)
    d = differentiate(t, x)
    for v in d:
        assert v.shape == (400, 2, 3)
        assert v.dtype == torch.float64
    one = differentiate(t, x[:, 1, 2])
    assert torch.allclose(one.second, d.second[:, 1, 2])
    arr = differentiate(t.numpy(), x.numpy())
    assert torch.allclose(arr.first, d.first)


def test_savgol_window_matches_schafer():
    w = savgol_window(20.0, 420.0, 3)
    assert w % 2 == 1
    # Schafer: fc/fs = (N + 1) / (3.2 M - 4.6); the window's cut-off lies near 20 Hz
    fc = (3 + 1) / (3.2 * w - 4.6) * 420.0
    assert 17.0 < fc <= 20.5


@pytest.mark.parametrize(
    "t, x, kw, match",
    [
        (np.r_[0.0, 0.1, 0.3, 0.4], np.zeros(4), {"cutoff_hz": None}, "uniform"),
        (np.r_[0.0, 0.2, 0.1, 0.3], np.zeros(4), {"cutoff_hz": None}, "increasing"),
        (np.arange(10) / 420.0, np.zeros(10), {}, "samples"),
        (np.arange(3) / 420.0, np.zeros(3), {"cutoff_hz": None}, "at least 4"),
        (np.arange(100) / 420.0, np.zeros(100), {"cutoff_hz": 300.0}, "Nyquist"),
        (np.arange(100) / 420.0, np.zeros(99), {}, "must match"),
        (np.arange(100) / 420.0, np.zeros(100), {"method": "spline"}, "method"),
        (np.arange(20) / 420.0, np.zeros(20), {"method": "savgol", "window": 31}, "window"),
        (np.arange(100) / 420.0, np.zeros(100), {"method": "savgol", "window": 30}, "odd"),
        (np.arange(100) / 420.0, np.full(100, np.nan), {}, "NaN"),
        (np.zeros((5, 2)), np.zeros(5), {}, "1-D"),
    ],
)
def test_bad_input_raises(t, x, kw, match):
    with pytest.raises(ValueError, match=match):
        differentiate(t, x, **kw)
