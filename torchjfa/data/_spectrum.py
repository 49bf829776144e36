"""The white-noise variance of each measured signal of a raw log, from its spectrum.

A robot's excitation lives in a low band (a few Hz); the sensors' noise (encoder quantisation,
the velocity estimate, the torque sensor) spreads up to the Nyquist frequency. Above the signal
band the power spectral density of a measured signal is flat at the noise's level, and for
white noise of variance ``sigma^2`` sampled at ``fs`` the one-sided density is
``2 sigma^2 / fs``. `signal_noise` finds that floor in each joint's Welch spectrum of ``q``,
``qd`` (where measured) and ``tau`` and reports the variance with the band it was read from.

Use it where the log has no repeated excitation periods (`torchjfa.data.regressor_noise`
needs two); `torchjfa.data.propagated_noise` pushes the variances through the preparation and
the regressor to the regression's input noise. The estimate assumes white noise: coloured
sensor noise is measured only as its level above the signal band.

Reference: P. D. Welch, "The use of fast Fourier transform for the estimation of power
spectra", IEEE Trans. Audio Electroacoustics 15(2), 1967 (the averaged periodogram and its
degrees of freedom).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import signal as _signal
from scipy import stats

from ._log import JointLog
from ._schema import LogError

__all__ = ["SignalNoise", "signal_noise", "floor_variance", "NOISE_SIGNALS"]

#: the raw signals whose noise is estimated, with their units
NOISE_SIGNALS = {"q": "rad", "qd": "rad/s", "tau": "N m"}


@dataclass(frozen=True)
class SignalNoise:
    """White-noise variances of a raw log's measured signals (float64, the log's joint order).

    Attributes:
        variance: ``"q"``, ``"qd"`` (where the log has it) and ``"tau"`` -> ``(n_dof,)``
            variances of the additive white noise, rad^2, (rad/s)^2, (N m)^2.
        band_hz: the same keys -> ``(n_dof,)`` the lower edge of the band the floor was read
            from, Hz (it runs to the Nyquist frequency).
        rate_hz: the log's (median) rate, Hz.
        segment: samples per Welch segment (the frequency resolution is ``rate_hz / segment``).
        detected: whether the band's edge was detected (else given).
    """

    variance: dict[str, torch.Tensor]
    band_hz: dict[str, torch.Tensor]
    rate_hz: float
    segment: int
    detected: bool

    def describe(self) -> str:
        """One line: each signal's noise std (RMS over joints) and the band it came from."""
        parts = []
        for name, var in self.variance.items():
            band = self.band_hz[name]
            parts.append(
                f"{name} {math.sqrt(float(var.mean())):.3g} {NOISE_SIGNALS[name]} "
                f"(above {float(band.min()):.3g}-{float(band.max()):.3g} Hz)"
            )
        edge = "detected where the spectrum flattens" if self.detected else "given"
        return (
            "white sensor noise from the spectrum's floor (Welch, "
            f"{self.segment}-sample segments at {self.rate_hz:.6g} Hz; band {edge}): "
            + ", ".join(parts)
        )


def signal_noise(
    log: JointLog,
    *,
    band_hz: float | None = None,
    segment: int | None = None,
    threshold: float = 2.0,
) -> SignalNoise:
    """Estimate the white-noise variance of each measured signal from its spectrum's floor.

    Each joint's one-sided Welch density ``S(f)`` (Hann segments, half overlapping) of
    ``q``, ``qd`` (where measured) and ``tau`` is read above the signal band: the floor is the
    median of ``S`` over the band's bins, corrected for the median's bias (each bin is
    ``S chi^2_nu / nu`` with Welch's ``nu``), and the variance is ``floor * fs / 2``. The band
    starts above the highest frequency where the spectrum (a 5-bin running median of it) is
    more than ``threshold`` times the floor of the top half of the band ``[fs/4, fs/2]``,
    unless ``band_hz`` gives its edge.

    Args:
        log: a raw `JointLog` (as recorded: before `torchjfa.data.prepare` filters it). An
            uneven log's samples are taken as uniform at its median rate (the noise is per
            sample; the jitter moves the low-band signal, not the floor).
        band_hz: the lower edge of the noise band, Hz (above the excitation's bandwidth), or
            None to detect it per signal and joint.
        segment: samples per Welch segment (default the largest power of two up to 256 that
            gives at least 8 segments).
        threshold: how far above the floor the spectrum counts as signal when detecting.

    Returns:
        A `SignalNoise`.

    Raises:
        LogError: on a log too short for a spectrum, or a band with fewer than 4 bins.
    """
    # an uneven log's samples are read as if uniform at its median rate: white noise is per
    # sample, and interpolating onto a grid (`resample`) would smooth it away in part
    n, fs = log.n_samples, log.rate_hz
    if segment is None:
        if n < 64:
            raise LogError(f"{log.source}: {n} samples are too few for a noise spectrum")
        segment = min(256, 1 << int(math.floor(math.log2(n / 8))))
    segment = int(segment)
    if not 16 <= segment <= n:
        raise LogError(f"segment must lie in [16, {n}] samples, got {segment}")
    if band_hz is not None and not 0.0 < float(band_hz) < 0.5 * fs:
        raise LogError(f"band_hz must lie in (0, {0.5 * fs:.6g}) Hz, got {band_hz}")
    if not threshold > 1.0:
        raise LogError(f"threshold must be above 1, got {threshold}")
    variance, band = {}, {}
    for name in NOISE_SIGNALS:
        x = getattr(log, name)
        if x is None:
            continue
        var, lo = floor_variance(x.numpy(), fs, segment, band_hz, threshold)
        if np.isnan(var).any():
            joint = log.joint_names[int(np.flatnonzero(np.isnan(var))[0])]
            raise LogError(f"{log.source}: the spectrum of {name} of joint {joint} "
                           f"{NO_FLOOR.format(nyquist=0.5 * fs)}")  # fmt: skip
        variance[name] = torch.from_numpy(var)
        band[name] = torch.from_numpy(lo)
    return SignalNoise(variance, band, float(fs), segment, band_hz is None)


#: the end of the error for a signal whose noise floor cannot be read
NO_FLOOR = (
    "does not flatten below the Nyquist frequency ({nyquist:.6g} Hz), so its noise floor "
    "cannot be read (give band_hz, or a log sampled faster)"
)


def floor_variance(
    x: np.ndarray, fs: float, segment: int, band_hz: float | None = None, threshold: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """The white-noise variance of each column of a signal, from its Welch spectrum's floor,
    read as `signal_noise` reads it (for any signal: a base pose, an IMU's readings, ...).

    Args:
        x: ``(n, k)`` (or ``(n,)``) samples, uniform at ``fs``, in any unit.
        fs: the rate, Hz.
        segment: samples per Welch segment (at most ``n``).
        band_hz: the lower edge of the noise band, Hz, or None to detect it per column.
        threshold: how far above the floor the spectrum counts as signal when detecting.

    Returns:
        ``(variance, band)``: ``(k,)`` white-noise variances, the unit squared, and ``(k,)``
        the lower edges of the bands they were read from, Hz. A column whose noise band has
        fewer than 4 bins (its spectrum does not flatten below the Nyquist frequency) gets
        NaN in both.
    """
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    bias = _median_bias(segment, x.shape[0])
    f, S = _signal.welch(x, fs=fs, nperseg=segment, axis=0)
    f, S = f[1:-1], S[1:-1]  # neither the mean nor the (unscaled) Nyquist bin
    var, lo = np.empty(S.shape[1]), np.empty(S.shape[1])
    for j in range(S.shape[1]):
        start = _band_start(f, S[:, j], band_hz, threshold)
        if f.shape[0] - start < 4:
            var[j], lo[j] = np.nan, np.nan
            continue
        var[j] = np.median(S[start:, j]) / bias * 0.5 * fs
        lo[j] = f[start]
    return var, lo


def _band_start(f: np.ndarray, S: np.ndarray, band_hz: float | None, threshold: float) -> int:
    """The first bin of the noise band of one spectrum ``S(f)``."""
    if band_hz is not None:
        return int(np.searchsorted(f, float(band_hz)))
    ref = np.median(S[f >= 0.25 * (f[-1] + f[0])])
    pad = np.pad(S, 2, mode="edge")
    smooth = np.median(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
    above = np.flatnonzero(smooth > threshold * ref)
    return 0 if above.size == 0 else int(above[-1]) + 1


def _median_bias(segment: int, n: int) -> float:
    """``median(chi^2_nu) / nu`` for Welch's Hann segments at half overlap over ``n`` samples:
    ``nu = 2 K / (1 + 2 sum_j (1 - j / K) c_j^2)`` with ``c_j`` the window's overlap
    correlation at a shift of ``j`` steps (only ``c_1`` is nonzero at half overlap)."""
    w = _signal.get_window("hann", segment)
    step = segment - segment // 2
    K = (n - segment) // step + 1
    c1 = float(np.dot(w[step:], w[: segment - step]) / np.dot(w, w))
    nu = 2.0 * K / (1.0 + 2.0 * (1.0 - 1.0 / K) * c1 * c1) if K > 1 else 2.0
    return float(stats.chi2.median(nu) / nu)
