"""Velocities and accelerations from sampled joint signals, as on a real robot.

Use `differentiate` when a log has positions (and perhaps velocities) but the regressor needs
accelerations: the signal is low-pass filtered without phase lag, then differentiated. Two
methods:

* ``"butterworth"`` (default): a zero-phase Butterworth low-pass (``scipy.signal.filtfilt``,
  forward and backward, so the magnitude response is squared and the phase is zero), then
  second-order central differences (one-sided second-order stencils at the two ends). A
  digital Butterworth filter is maximally flat at zero frequency, so the zero-phase filter
  passes polynomials up to degree ``2 * filter_order - 1`` unchanged away from the ends;
  central differences are exact for the first derivative of quadratics and the second
  derivative of cubics, with relative error ``(2 pi f h)^2 / 6`` (first) and
  ``(2 pi f h)^2 / 12`` (second) on a sinusoid of frequency f sampled every h seconds.
* ``"savgol"``: Savitzky-Golay least-squares polynomial fits (``scipy.signal.savgol_filter``),
  which differentiate the fitted polynomial; exact for polynomials up to ``polyorder``,
  including at the ends.

The default cut-off, 20 Hz, keeps the 0-5 Hz motion of the paper's sinusoidal excitation
(and of `torchjfa.sim`) untouched at 420-480 Hz sampling while removing most white sensor
noise (the noise variance of a signal falls by about ``2 * cutoff / rate``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from scipy import signal

from .._validation import as_tensor, check_finite

__all__ = [
    "Derivatives",
    "differentiate",
    "savgol_window",
    "DEFAULT_CUTOFF_HZ",
    "EDGE_PERIODS",
    "edge_seconds",
]

DEFAULT_CUTOFF_HZ = 20.0
#: the filter's reach in periods of its cut-off (`edge_seconds`)
EDGE_PERIODS = 4.0
_METHODS = ("butterworth", "savgol")


def edge_seconds(cutoff_hz: float) -> float:
    """The zero-phase filter's reach, s: ``EDGE_PERIODS / cutoff_hz``.

    Within it of a log's end the filtered signal and its derivatives still carry the filter's
    start-up: the default order-4 Butterworth's impulse response has decayed to about 1e-4 of
    its peak four periods of its cut-off after the impulse. `prepare` drops that much at each end,
    and a log cut in two (training and held-out parts) leaves that gap between them, so that
    no filtered sample of one part saw the other.

    Args:
        cutoff_hz: the filter's cut-off, Hz (> 0).
    """
    return EDGE_PERIODS / cutoff_hz


class Derivatives(NamedTuple):
    """A filtered signal and its first two time derivatives, each ``(n_samples, *shape)``.

    Attributes:
        value: the low-pass filtered signal (units of x).
        first: its first derivative (units of x per second).
        second: its second derivative (units of x per second squared).
    """

    value: torch.Tensor
    first: torch.Tensor
    second: torch.Tensor


def savgol_window(cutoff_hz: float, rate_hz: float, polyorder: int) -> int:
    """The odd Savitzky-Golay window whose -3 dB frequency is about ``cutoff_hz``.

    Uses Schafer's (2011, IEEE Signal Processing Magazine 28(4)) approximation
    ``f_c / f_s = (polyorder + 1) / (3.2 * window - 4.6)``.
    """
    window = ((polyorder + 1) * rate_hz / cutoff_hz + 4.6) / 3.2
    window = max(int(np.ceil(window)), polyorder + 2)
    return window if window % 2 == 1 else window + 1


def _check_time(t, n: int) -> float:
    """Validate uniform, increasing sample times and return the step in seconds."""
    if t.ndim != 1:
        raise ValueError(f"t must be 1-D with shape (n_samples,), got shape {tuple(t.shape)}")
    if t.shape[0] != n:
        raise ValueError(f"t has {t.shape[0]} samples but x has {n}; they must match")
    check_finite(t, "t")
    tn = t.detach().cpu().numpy().astype(np.float64)
    dt = np.diff(tn)
    if np.any(dt <= 0):
        raise ValueError("t must be strictly increasing")
    h = float(np.mean(dt))
    # steps may differ by 0.1 % of a step plus the rounding of t's dtype
    tol = 1e-3 * h + 4.0 * float(torch.finfo(t.dtype).eps) * float(np.max(np.abs(tn)))
    if np.max(np.abs(dt - h)) > tol:
        raise ValueError(
            "t must be uniformly sampled (steps differ by up to "
            f"{float(np.max(np.abs(dt - h))):.3g} s around a mean of {h:.3g} s); resample first"
        )
    return h


def _central(x: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """First and second derivatives along axis 0, second order everywhere."""
    d1 = np.gradient(x, h, axis=0, edge_order=2)
    d2 = np.empty_like(x)
    d2[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / (h * h)
    # one-sided second-order stencils (exact for cubics): 2, -5, 4, -1
    d2[0] = (2.0 * x[0] - 5.0 * x[1] + 4.0 * x[2] - x[3]) / (h * h)
    d2[-1] = (2.0 * x[-1] - 5.0 * x[-2] + 4.0 * x[-3] - x[-4]) / (h * h)
    return d1, d2


def differentiate(
    t,
    x,
    *,
    method: str = "butterworth",
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    filter_order: int = 4,
    polyorder: int = 4,
    window: int | None = None,
) -> Derivatives:
    """Low-pass filter a sampled signal without lag and differentiate it twice.

    Args:
        t: ``(n_samples,)`` sample times, s; strictly increasing and uniform (steps equal to
            0.1 % and the rounding of t's dtype).
        x: ``(n_samples, *shape)`` signal (e.g. ``(n_samples, n_dof)`` joint positions); time
            runs along the first dimension.
        method: ``"butterworth"`` (zero-phase Butterworth then central differences) or
            ``"savgol"`` (Savitzky-Golay).
        cutoff_hz: the low-pass cut-off, Hz (default 20 Hz); must lie below the Nyquist
            frequency. None skips the filter (``"butterworth"`` only: plain central
            differences).
        filter_order: order of the Butterworth filter (the zero-phase filter has twice this).
        polyorder: polynomial order of the Savitzky-Golay fits (at least 2; default 4, whose
            second derivative is within 0.2 % on a 4 Hz sinusoid with the 20 Hz window).
        window: Savitzky-Golay window length in samples (odd); default from ``cutoff_hz`` by
            `savgol_window`.

    Returns:
        `Derivatives` ``(value, first, second)``, each ``(n_samples, *shape)`` float64 on x's
        device.

    Raises:
        ValueError: on non-uniform or non-increasing t, mismatched lengths, a signal too short
            for the filter, a cut-off outside ``(0, Nyquist)``, bad orders, NaN or inf.
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    x = as_tensor(x, name="x")
    t = as_tensor(t, name="t")
    if x.ndim < 1:
        raise ValueError("x must have a time dimension first, shape (n_samples, ...)")
    n = x.shape[0]
    check_finite(x, "x")
    h = _check_time(t, n)
    rate = 1.0 / h
    device = x.device
    xn = x.detach().cpu().numpy().astype(np.float64)
    if cutoff_hz is not None:
        cutoff_hz = float(cutoff_hz)
        if not 0.0 < cutoff_hz < 0.5 * rate:
            raise ValueError(
                f"cutoff_hz must lie in (0, {0.5 * rate:.6g}) Hz (the Nyquist frequency of the "
                f"{rate:.6g} Hz sampling), got {cutoff_hz}"
            )
    if method == "butterworth":
        if isinstance(filter_order, bool) or not isinstance(filter_order, int) or filter_order < 1:
            raise ValueError(f"filter_order must be a positive int, got {filter_order!r}")
        if cutoff_hz is None:
            if n < 4:
                raise ValueError(f"need at least 4 samples to differentiate, got {n}")
            value = xn.copy()
        else:
            b, a = signal.butter(filter_order, cutoff_hz, btype="low", fs=rate)
            padlen = 3 * max(len(a), len(b))
            if n <= padlen:
                raise ValueError(
                    f"x has {n} samples; the order-{filter_order} zero-phase filter needs more "
                    f"than {padlen}"
                )
            value = signal.filtfilt(b, a, xn, axis=0, padtype="odd", padlen=padlen)
        first, second = _central(value, h)
    else:
        if isinstance(polyorder, bool) or not isinstance(polyorder, int) or polyorder < 2:
            raise ValueError(f"polyorder must be an int >= 2, got {polyorder!r}")
        if window is None:
            if cutoff_hz is None:
                raise ValueError("method 'savgol' needs cutoff_hz or window")
            window = savgol_window(cutoff_hz, rate, polyorder)
        if isinstance(window, bool) or not isinstance(window, int) or window % 2 == 0:
            raise ValueError(f"window must be an odd int, got {window!r}")
        if window <= polyorder:
            raise ValueError(f"window ({window}) must exceed polyorder ({polyorder})")
        if n < window:
            raise ValueError(f"x has {n} samples, fewer than the Savitzky-Golay window {window}")
        kw = {"window_length": window, "polyorder": polyorder, "axis": 0, "mode": "interp"}
        value = signal.savgol_filter(xn, **kw)
        first = signal.savgol_filter(xn, deriv=1, delta=h, **kw)
        second = signal.savgol_filter(xn, deriv=2, delta=h, **kw)
    out = (
        torch.as_tensor(np.ascontiguousarray(v), dtype=torch.float64, device=device)
        for v in (value, first, second)
    )
    return Derivatives(*out)
