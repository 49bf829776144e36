"""From a raw joint log to identification data: uniform time, filtering, derivatives, trimming.

`prepare` is the whole recipe, each step also available alone:

1. `resample`: logs from real robots have jitter and gaps (dropped packets, dropped NaN
   rows); the filter and the differences need uniform time, so an uneven log is interpolated
   (cubic splines) onto a uniform grid at its median rate.
2. `detect_period`: a periodic excitation (the paper's sums of sinusoids) repeats; its
   period, found from the autocorrelation of the positions, lets the noise be measured from
   the spread between periods (`torchjfa.data.regressor_noise`). The log is resampled so that
   a period is a whole number of samples.
3. `torchjfa.data.differentiate`: zero-phase low-pass (Butterworth filtfilt or Savitzky-Golay)
   and derivatives. Measured velocities, when the log has them, are filtered and
   differentiated for the accelerations; otherwise both come from the positions. Torques get
   the same zero-phase filter, so that both sides of ``tau = Y theta`` see the same filter.
4. Trimming: the filter's ends (``edge_s``) and the start-up transient (``skip_start_s``, or
   ``"auto"``: the leading periods that differ from the settled ones by more than the noise).
5. Decimation by a whole factor, allowed when the cut-off lies below the new Nyquist frequency
   (the filter is then the anti-aliasing filter).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch
from scipy import interpolate

from ._differentiate import DEFAULT_CUTOFF_HZ, differentiate, edge_seconds
from ._log import JointLog, LogError

__all__ = ["prepare", "resample", "detect_period", "transient_periods", "is_uniform"]

_JITTER = 1e-3  # steps within 0.1 % of the median count as uniform


def is_uniform(t: torch.Tensor) -> bool:
    """Whether the steps of ``t`` are equal to 0.1 % of the median step."""
    dt = torch.diff(torch.as_tensor(t, dtype=torch.float64))
    h = float(torch.median(dt))
    return bool((dt - h).abs().max() <= _JITTER * h + 4e-16 * float(t.abs().max()))


def resample(log: JointLog, rate_hz: float | None = None) -> JointLog:
    """The log interpolated by cubic splines onto uniform time at ``rate_hz``.

    Args:
        log: a `JointLog` with strictly increasing time.
        rate_hz: the new rate, Hz (default the median rate of the log).

    Returns:
        A `JointLog` starting at the first sample's time, ``floor(duration * rate) + 1``
        samples; ``period_samples`` is dropped.
    """
    rate = log.rate_hz if rate_hz is None else float(rate_hz)
    if not math.isfinite(rate) or rate <= 0:
        raise LogError(f"the resampling rate must be positive, got {rate_hz}")
    t = log.t.numpy()
    n = int(math.floor((t[-1] - t[0]) * rate * (1 + 1e-12))) + 1
    if n < 4:
        raise LogError(f"{log.source}: {n} samples at {rate:.6g} Hz are too few to resample")
    grid = t[0] + np.arange(n) / rate
    grid[-1] = min(grid[-1], t[-1])
    out = {
        k: torch.from_numpy(interpolate.CubicSpline(t, v.numpy(), axis=0)(grid))
        for k, v in log.signals().items()
    }
    return replace(log, t=torch.from_numpy(grid), period_samples=None, **out)


def detect_period(
    x,
    rate_hz: float,
    *,
    min_period_s: float | None = None,
    max_period_s: float | None = None,
    min_correlation: float = 0.8,
) -> float | None:
    """The period of a periodic multi-joint signal, s, from its autocorrelation; None if none.

    The joints' autocorrelations (mean removed, each normalised to 1 at lag 0, unbiased for
    the overlap) are averaged; the period is the first lag after the first decorrelation whose
    peak reaches 0.9 of the highest peak, refined to a fraction of a sample by a parabola
    through the minimum of the mean squared difference ``|x_{i+L} - x_i|^2`` at multiples
    2, 4, 8, ... of it that fit twice in the log.

    Args:
        x: ``(n_samples, n_dof)`` (or ``(n_samples,)``) uniformly sampled signal, e.g. positions.
        rate_hz: its sampling rate, Hz.
        min_period_s: the shortest period searched (default: the first decorrelation).
        max_period_s: the longest period searched (default: half the log, so at least two
            periods are in it).
        min_correlation: the peak's average correlation needed to call the signal periodic.

    Returns:
        The period in seconds, or None when the signal is not clearly periodic.
    """
    x = torch.as_tensor(x, dtype=torch.float64)
    x = x[:, None] if x.ndim == 1 else x
    n = x.shape[0]
    x = x - x.mean(0)
    std = x.std(0)
    x = x[:, std > 0]
    if x.shape[1] == 0 or n < 8:
        return None
    xn = x.numpy() / std[std > 0].numpy()
    size = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(xn, size, axis=0)
    raw = np.fft.irfft(f * np.conj(f), size, axis=0)[:n].sum(1)  # sum_i x_i . x_{i+L}
    overlap = np.arange(n, 0, -1, dtype=np.float64)
    acf = raw / overlap
    acf /= acf[0]
    # the mean squared difference between x_i and x_{i+L}; its minima locate the period without
    # the bias the log's ends give the autocorrelation's peaks
    cum = np.concatenate(([0.0], np.cumsum((xn * xn).sum(1))))
    lags = np.arange(n)
    sqdiff = (cum[n] - cum[lags] + cum[n - lags] - 2.0 * raw) / overlap
    hi = n // 2 if max_period_s is None else min(n // 2, int(max_period_s * rate_hz))
    below = np.flatnonzero(acf[:hi] < 0.5)
    if below.size == 0:
        return None
    lo = int(below[0])
    if min_period_s is not None:
        lo = max(lo, int(min_period_s * rate_hz))
    if hi - lo < 3:
        return None
    seg = acf[lo:hi]
    peaks = np.flatnonzero((seg[1:-1] >= seg[:-2]) & (seg[1:-1] >= seg[2:])) + 1
    if peaks.size == 0:
        return None
    top = float(seg[peaks].max())
    if top < min_correlation:
        return None
    lag = lo + int(peaks[np.argmax(seg[peaks] >= 0.9 * top)])
    # refine to a fraction of a sample at ever larger multiples of the period (2, 4, 8, ...)
    est, k = _peak(-sqdiff, lag), 1
    while 2 * k * est <= n // 2:
        k *= 2
        est = _peak(-sqdiff, int(round(k * est))) / k
    return est / rate_hz


def _peak(acf: np.ndarray, c: int, reach: int = 2) -> float:
    """The maximum of ``acf`` within ``reach`` samples of ``c``, by a parabola through it."""
    a, b = max(1, c - reach), min(acf.shape[0] - 1, c + reach + 1)
    i = a + int(np.argmax(acf[a:b]))
    if not 0 < i < acf.shape[0] - 1:
        return float(i)
    y0, y1, y2 = acf[i - 1], acf[i], acf[i + 1]
    den = y0 - 2.0 * y1 + y2
    return float(i + (0.5 * (y0 - y2) / den if den < 0 else 0.0))


def transient_periods(x, period_samples: int, *, factor: float = 3.0) -> int:
    """Leading whole periods of ``x`` that differ from the settled motion by more than noise.

    Each period is compared with the mean of the last half of the periods; the leading ones
    whose RMS difference exceeds ``factor`` times the median RMS difference are the start-up
    transient.

    Args:
        x: ``(n_samples, n_dof)`` signal (positions), first sample at a period's start.
        period_samples: samples per period.
        factor: how far above the typical period-to-period difference counts as transient.

    Returns:
        The number of leading periods to drop (at most all but two).
    """
    x = torch.as_tensor(x, dtype=torch.float64)
    x = x[:, None] if x.ndim == 1 else x
    P = int(period_samples)
    k = x.shape[0] // P
    if k < 3:
        return 0
    per = x[: k * P].reshape(k, P, -1)
    ref = per[k // 2 :].mean(0)
    rms = (per - ref).pow(2).mean(dim=(1, 2)).sqrt()
    limit = factor * float(rms.median())
    drop = 0
    while drop < k - 2 and float(rms[drop]) > limit:
        drop += 1
    return drop


def _filter(t: torch.Tensor, x: torch.Tensor, method: str, cutoff_hz: float) -> torch.Tensor:
    return differentiate(t, x, method=method, cutoff_hz=cutoff_hz).value


def prepare(
    log: JointLog,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    method: str = "butterworth",
    velocity: str = "auto",
    filter_torque: bool = True,
    period_s: float | str | None = "auto",
    skip_start_s: float | str = 0.0,
    edge_s: float | None = None,
    decimate: int = 1,
) -> JointLog:
    """Turn a raw joint log into identification data (q, qd, qdd, tau on uniform time).

    Args:
        log: a `JointLog` (from `read_log`) with positions and torques.
        cutoff_hz: the zero-phase low-pass cut-off, Hz (default 20 Hz, see
            `torchjfa.data.differentiate`); applied to positions (or velocities) and torques.
        method: ``"butterworth"`` or ``"savgol"``.
        velocity: ``"measured"`` (filter the log's qd, differentiate it for qdd),
            ``"differentiate"`` (both from q) or ``"auto"`` (measured when the log has it).
        filter_torque: filter the torques with the same low-pass.
        period_s: the excitation's period, s; ``"auto"`` detects it (`detect_period`), None
            skips it. With a period, the log is resampled so that a period is a whole number
            of samples and ``period_samples`` is set.
        skip_start_s: seconds to drop at the start (start-up transients), or ``"auto"``: the
            leading periods that differ from the settled motion (`transient_periods`; needs a
            period).
        edge_s: seconds dropped at both ends for the filter's start and end (default
            `torchjfa.data.edge_seconds` of ``cutoff_hz``).
        decimate: keep every ``decimate``-th sample after filtering; the cut-off must lie
            below the new Nyquist frequency.

    Returns:
        A `JointLog` with ``q``, ``qd``, ``qdd`` and ``tau`` filled, and ``info`` describing
        what was done (rate, period, samples dropped).

    Raises:
        LogError: on a log too short for the filter, a bad option, or ``skip_start_s="auto"``
            without a period.
    """
    if velocity not in ("auto", "measured", "differentiate"):
        raise LogError(f"velocity must be 'auto', 'measured' or 'differentiate', got {velocity!r}")
    if velocity == "measured" and log.qd is None:
        raise LogError(f"{log.source}: velocity='measured' but the log has no qd_<joint> columns")
    if isinstance(decimate, bool) or not isinstance(decimate, int) or decimate < 1:
        raise LogError(f"decimate must be a positive int, got {decimate!r}")
    info: dict[str, object] = {"raw_samples": log.n_samples, "raw_rate_hz": log.rate_hz}
    uniform = is_uniform(log.t)
    info["resampled"] = not uniform
    if not uniform:
        log = resample(log)
    rate = log.rate_hz
    period = None
    if period_s == "auto":
        period = detect_period(log.q, rate)
    elif period_s is not None:
        period = float(period_s)
        if not math.isfinite(period) or period <= 0:
            raise LogError(f"period_s must be positive, 'auto' or None, got {period_s!r}")
    P = None
    if period is not None:
        P = int(round(period * rate))
        if P < 8:
            raise LogError(f"a period of {period:.4g} s is under 8 samples at {rate:.6g} Hz")
        # resample unless the period is already whole to 0.05 sample over the log
        if log.n_samples * abs(P / (period * rate) - 1.0) > 0.05:
            log = resample(log, P / period)
            info["resampled"] = True
            rate = log.rate_hz
    info["period_s"] = period
    try:
        use_qd = log.qd is not None and velocity != "differentiate"
        dq = differentiate(log.t, log.q, method=method, cutoff_hz=cutoff_hz)
        q, qd, qdd = dq.value, dq.first, dq.second
        if use_qd:
            dv = differentiate(log.t, log.qd, method=method, cutoff_hz=cutoff_hz)
            qd, qdd = dv.value, dv.first
        tau = _filter(log.t, log.tau, method, cutoff_hz) if filter_torque else log.tau
    except ValueError as exc:
        raise LogError(f"{log.source}: {exc}") from None
    info["velocity"] = "measured" if use_qd else "differentiated"
    out = replace(log, q=q, qd=qd, qdd=qdd, tau=tau, period_samples=None)
    edge = int(math.ceil((edge_seconds(cutoff_hz) if edge_s is None else float(edge_s)) * rate))
    if skip_start_s == "auto":
        if P is None:
            raise LogError(
                "skip_start_s='auto' finds the start-up transient from the excitation's "
                "periods, but no period was found; give skip_start_s in seconds"
            )
        start = edge + transient_periods(q[edge:], P) * P
    else:
        skip = float(skip_start_s)
        if not math.isfinite(skip) or skip < 0:
            raise LogError(
                f"skip_start_s must be non-negative seconds or 'auto', got {skip_start_s!r}"
            )
        start = edge + int(math.ceil(skip * rate))
    stop = out.n_samples - edge
    if stop - start < 2:
        raise LogError(
            f"{log.source}: {out.n_samples} samples leave {max(stop - start, 0)} after dropping "
            f"{start} at the start and {edge} at the end (filter edges, start-up transient)"
        )
    out = out.select(slice(start, stop))
    info["dropped_start_s"] = start / rate
    info["dropped_end_s"] = edge / rate
    if decimate > 1:
        if cutoff_hz >= 0.5 * rate / decimate:
            raise LogError(
                f"decimating by {decimate} takes the rate to {rate / decimate:.6g} Hz, whose "
                f"Nyquist frequency is below the {cutoff_hz} Hz cut-off (aliasing); lower the "
                "cut-off or the factor"
            )
        out = out.select(slice(None, None, decimate))
        rate = rate / decimate
        if P is not None:
            P = P // decimate if P % decimate == 0 else None
    out.period_samples = P
    info["rate_hz"] = rate
    info["samples"] = out.n_samples
    out.info = info
    return out
