"""Standing still at the ends of a log: found, so that it can be dropped.

Robots are logged from before they start to after they stop: an excitation run starts and ends
at rest, often for seconds. Rest identifies nothing (no velocity, no acceleration: only the
gravity terms, and the friction at zero velocity is undetermined), and when the held-out part is
the end of the log, rest there makes the held-out score measure nothing but the torque noise.
`motion_span` finds the first and the last moving sample; `torchjfa.identification.prepare_data`
keeps the motion and the filter's reach on both sides of it.

A joint moves at a sample when its speed (the measured velocity, or the positions' central
differences), averaged over `REST_WINDOW_S`, exceeds `REST_FRACTION` of the joint's peak speed
(its 99th percentile); joints whose peak speed stays under `REST_MIN_SPEED` never count (they
stand still the whole log). The robot moves when any joint moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._log import JointLog

__all__ = ["REST_FRACTION", "REST_MIN_SPEED", "REST_WINDOW_S", "RestSpan", "motion_span"]

#: a joint moves where its speed exceeds this share of its peak speed
REST_FRACTION = 0.05
#: a joint whose peak speed stays below this (rad/s, m/s) does not move at all
REST_MIN_SPEED = 1e-2
#: the speed is averaged over this window, s (noise spikes do not count as motion)
REST_WINDOW_S = 0.05


@dataclass(frozen=True)
class RestSpan:
    """Where a log moves: samples ``[start, stop)``.

    Attributes:
        start: the first moving sample (0 when the log starts moving).
        stop: one past the last moving sample (the log's length when it ends moving).
        n_samples: the log's samples.
        rest_start_s: seconds of rest before ``start``.
        rest_end_s: seconds of rest after ``stop - 1``.
    """

    start: int
    stop: int
    n_samples: int
    rest_start_s: float
    rest_end_s: float

    @property
    def moves(self) -> bool:
        """Whether any joint moves at all."""
        return self.stop > self.start


def _speed(log: JointLog) -> np.ndarray:
    """``(n, n_dof)`` joint speeds: the measured velocity's magnitude, or the positions' central
    differences', each averaged over `REST_WINDOW_S`."""
    t = log.t.numpy()
    if log.qd is not None:
        v = np.abs(log.qd.numpy())
    else:
        v = np.abs(np.gradient(log.q.numpy(), t, axis=0))
    step = float(np.median(np.diff(t)))
    w = max(1, int(round(REST_WINDOW_S / step)))
    if w == 1:
        return v
    kernel = np.ones(w) / w
    return np.stack([np.convolve(v[:, j], kernel, mode="same") for j in range(v.shape[1])], 1)


def motion_span(log: JointLog) -> RestSpan:
    """The samples from the first to the last at which the robot moves (see the module)."""
    n = log.n_samples
    if n < 3:
        return RestSpan(0, n, n, 0.0, 0.0)
    v = _speed(log)
    peak = np.percentile(v, 99, axis=0)
    live = peak > REST_MIN_SPEED
    if not live.any():
        return RestSpan(0, 0, n, 0.0, 0.0)
    moving = (v[:, live] > REST_FRACTION * peak[live]).any(axis=1)
    idx = np.flatnonzero(moving)
    start, stop = int(idx[0]), int(idx[-1]) + 1
    t = log.t
    return RestSpan(
        start,
        stop,
        n,
        float(t[start] - t[0]),
        float(t[-1] - t[stop - 1]),
    )
