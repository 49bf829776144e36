"""Periodic sinusoidal excitation trajectories, as in the paper's robot experiments.

Each joint follows a sum of a few sinusoids with different frequencies and phases,

    q_j(t) = c_j + sum_k a_jk sin(2 pi n_jk f0 t + phi_jk),

with integer harmonics ``n_jk`` of one base frequency ``f0``, so the whole reference repeats
with period ``T = 1 / f0`` and the repetitions give an estimate of the sensor noise (see
`torchjfa.data.regressor_noise`). Velocities and accelerations are the exact derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from .._validation import as_tensor
from ._robots import joint_ranges

__all__ = ["SinusoidTrajectory", "random_trajectory"]


@dataclass(frozen=True)
class SinusoidTrajectory:
    """A periodic sum-of-sinusoids joint reference.

    Attributes:
        base_frequency: f0, Hz; the period is ``1 / f0`` seconds.
        offset: ``(n_dof,)`` c, rad.
        amplitude: ``(n_dof, n_terms)`` a, rad.
        harmonic: ``(n_dof, n_terms)`` integer multiples n of f0.
        phase: ``(n_dof, n_terms)`` phi, rad.
    """

    base_frequency: float
    offset: np.ndarray
    amplitude: np.ndarray
    harmonic: np.ndarray
    phase: np.ndarray

    def __post_init__(self) -> None:
        f0 = float(self.base_frequency)
        if not np.isfinite(f0) or f0 <= 0:
            raise ValueError(f"base_frequency must be positive, got {self.base_frequency}")
        off = np.asarray(self.offset, dtype=np.float64)
        amp = np.asarray(self.amplitude, dtype=np.float64)
        har = np.asarray(self.harmonic)
        ph = np.asarray(self.phase, dtype=np.float64)
        if off.ndim != 1 or amp.ndim != 2 or amp.shape[0] != off.shape[0]:
            raise ValueError(
                f"offset must be (n_dof,) and amplitude (n_dof, n_terms); got {off.shape} and "
                f"{amp.shape}"
            )
        if har.shape != amp.shape or ph.shape != amp.shape:
            raise ValueError(
                f"harmonic {har.shape} and phase {ph.shape} must have amplitude's shape {amp.shape}"
            )
        if not np.all(np.equal(np.round(har), har)) or np.any(har < 1):
            raise ValueError("harmonic must hold positive integers (multiples of base_frequency)")
        for name, v in (("offset", off), ("amplitude", amp), ("phase", ph)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name} has NaN or infinite entries")
        object.__setattr__(self, "base_frequency", f0)
        object.__setattr__(self, "offset", off)
        object.__setattr__(self, "amplitude", amp)
        object.__setattr__(self, "harmonic", np.round(har).astype(np.int64))
        object.__setattr__(self, "phase", ph)

    @property
    def n_dof(self) -> int:
        return self.offset.shape[0]

    @property
    def period(self) -> float:
        """T = 1 / f0, s."""
        return 1.0 / self.base_frequency

    def evaluate_numpy(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, qd, qdd at times ``t (n,)`` as numpy arrays ``(n, n_dof)``, rad, rad/s, rad/s^2."""
        t = np.asarray(t, dtype=np.float64)
        w = 2.0 * np.pi * self.base_frequency * self.harmonic  # (n_dof, K) rad/s
        arg = t[:, None, None] * w + self.phase  # (n, n_dof, K)
        s, c = np.sin(arg), np.cos(arg)
        q = self.offset + np.einsum("njk,jk->nj", s, self.amplitude)
        qd = np.einsum("njk,jk->nj", c, self.amplitude * w)
        qdd = -np.einsum("njk,jk->nj", s, self.amplitude * w * w)
        return q, qd, qdd

    def __call__(self, t) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """q, qd, qdd at times ``t (n,)`` (s), each ``(n, n_dof)``, in t's dtype (float64 default).

        Raises:
            ValueError: if t is not 1-D.
        """
        t = as_tensor(t, name="t")
        if t.ndim != 1:
            raise ValueError(f"t must be 1-D with shape (n,), got {tuple(t.shape)}")
        out = self.evaluate_numpy(t.detach().cpu().numpy())
        return tuple(torch.as_tensor(v, dtype=t.dtype, device=t.device) for v in out)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Guaranteed ``(low, high)`` joint bounds, ``offset -/+ sum |a|``, each ``(n_dof,)``."""
        reach = np.abs(self.amplitude).sum(axis=1)
        return self.offset - reach, self.offset + reach


def random_trajectory(
    model: mujoco.MjModel,
    *,
    base_frequency: float = 0.25,
    n_terms: int = 3,
    max_harmonic: int = 8,
    range_fraction: float = 0.6,
    seed: int | None = 0,
    min_harmonic: int = 1,
    velocity_limit=None,
) -> SinusoidTrajectory:
    """A random periodic excitation inside the robot's joint ranges.

    Per joint, ``n_terms`` distinct harmonics are drawn from ``min_harmonic..max_harmonic``, phases
    uniformly, and amplitudes ``~ U(0.5, 1) / n`` (every term contributes a similar velocity)
    scaled so that
    ``sum |a|`` is ``range_fraction`` of the half range; the offset is the range's middle.
    The reference therefore never leaves ``range_fraction`` of each joint range.

    Args:
        model: the MuJoCo robot (its ``jnt_range``).
        base_frequency: f0, Hz (default 0.25: a 4 s period; with 8 harmonics, up to 2 Hz).
        n_terms: sinusoids per joint.
        max_harmonic: largest multiple of f0.
        min_harmonic: smallest multiple of f0 (default 1). The joint's velocity scales as
            ``1 / sum(1 / n)`` over its harmonics n (the position range is fixed), so a joint that
            draws a low harmonic moves slowly: with harmonics from 1..100 (a long period) the
            joints' peak velocities spread 20x, and a joint that barely moves in one log cannot
            predict another that moves it fast. Keep the band narrow (``max / min`` of about 10,
            as the default 1..8) when the period is long.
        range_fraction: fraction of the half range the motion may use, in ``(0, 1]``.
        seed: seed of the numpy Generator (an int, a SeedSequence or None).
        velocity_limit: a float or ``(n_dof,)`` per joint, rad/s (m/s for a slide joint), or
            None: a joint whose speed bound ``sum_k 2 pi n_k f0 |a_k|`` exceeds its limit has
            its amplitudes scaled down to meet it (never up; ``inf`` for no limit). The draw
            is the same with and without it.

    Returns:
        A `SinusoidTrajectory` with ``n_dof = model.njnt``.
    """
    if isinstance(n_terms, bool) or not isinstance(n_terms, int) or n_terms < 1:
        raise ValueError(f"n_terms must be a positive int, got {n_terms!r}")
    if isinstance(max_harmonic, bool) or not isinstance(max_harmonic, int):
        raise ValueError(f"max_harmonic must be an int, got {max_harmonic!r}")
    if isinstance(min_harmonic, bool) or not isinstance(min_harmonic, int) or min_harmonic < 1:
        raise ValueError(f"min_harmonic must be a positive int, got {min_harmonic!r}")
    if max_harmonic - min_harmonic + 1 < n_terms:
        raise ValueError(
            f"min_harmonic..max_harmonic ({min_harmonic}..{max_harmonic}) must hold at least "
            f"n_terms ({n_terms}) harmonics"
        )
    if not 0.0 < range_fraction <= 1.0:
        raise ValueError(f"range_fraction must lie in (0, 1], got {range_fraction}")
    rng = np.random.default_rng(seed)
    ranges = joint_ranges(model)
    n = ranges.shape[0]
    half = 0.5 * (ranges[:, 1] - ranges[:, 0])
    band = max_harmonic - min_harmonic + 1
    harmonic = np.stack([rng.choice(band, n_terms, replace=False) + min_harmonic for _ in range(n)])
    weight = rng.uniform(0.5, 1.0, (n, n_terms)) / harmonic
    amplitude = weight / weight.sum(axis=1, keepdims=True) * (range_fraction * half)[:, None]
    phase = rng.uniform(0.0, 2.0 * np.pi, (n, n_terms))
    if velocity_limit is not None:
        amplitude = (
            amplitude
            * _speed_scale(amplitude, 2.0 * np.pi * base_frequency * harmonic, velocity_limit)[
                :, None
            ]
        )
    return SinusoidTrajectory(
        base_frequency=base_frequency,
        offset=ranges.mean(axis=1),
        amplitude=amplitude,
        harmonic=harmonic,
        phase=phase,
    )


def _speed_scale(amplitude: np.ndarray, omega: np.ndarray, limit) -> np.ndarray:
    """``(n_dof,)`` factors in (0, 1] that bring each joint's speed bound ``sum |a| w`` (rad/s)
    to at most ``limit`` (a float or ``(n_dof,)``, rad/s, > 0; inf: no limit)."""
    n = amplitude.shape[0]
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), (n,))
    if np.any(np.isnan(limit)) or np.any(limit <= 0):
        raise ValueError(f"velocity_limit must be positive, got {limit.tolist()}")
    bound = np.sum(np.abs(amplitude) * omega, axis=1)
    with np.errstate(divide="ignore"):
        return np.minimum(1.0, np.where(bound > 0, limit / bound, 1.0))
