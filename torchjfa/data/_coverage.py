"""How far one log's motion goes beyond another's: is a model identified on one used outside it?

An identified model is a fit to the states its log visited. Inside them, unmodelled effects
that the model's terms can mimic (dry friction by viscous friction at the log's typical speed,
a spring by a gravity term, armature by a link inertia) cost little; outside them, the mimicry
extrapolates and the error grows with the distance. On the simulated head (docs/residual.md)
one random excitation moved a joint at most 0.49 rad/s where the test log reached 2.1 rad/s, and
the held-out torque error of that joint rose 100x. `coverage` measures that distance per joint
and signal, so the report and the scripts can say it before anyone trusts the numbers.

Peaks are robust: the 99th percentile of ``|qd|`` and ``|qdd|`` (a spike of derivative noise
does not count) and the 1st and 99th percentiles of ``q``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["Coverage", "coverage", "DEFAULT_COVERAGE_LIMIT"]

DEFAULT_COVERAGE_LIMIT = 1.5  # a peak 1.5x the identification log's is extrapolation
_SIGNALS = ("q", "qd", "qdd")
_UNITS = {"q": "rad", "qd": "rad/s", "qdd": "rad/s^2"}
_LOW, _HIGH = 1.0, 99.0  # percentiles


def _states(states, name: str) -> list[np.ndarray]:
    if len(states) != 3:
        raise ValueError(f"{name} must be (q, qd, qdd), got {len(states)} arrays")
    out = []
    for s, v in zip(_SIGNALS, states, strict=True):
        a = v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else np.asarray(v)
        a = np.asarray(a, dtype=np.float64)
        if a.ndim != 2 or a.shape[0] < 2:
            raise ValueError(f"{name} {s} must be (n_samples >= 2, n_dof), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} {s} has NaN or infinite entries")
        out.append(a)
    if len({a.shape[1] for a in out}) != 1:
        raise ValueError(f"{name}: q, qd and qdd have different numbers of joints")
    return out


@dataclass(frozen=True)
class Coverage:
    """Per joint, how far the other log's motion goes beyond the identification log's.

    Attributes:
        joint_names: ``n_dof`` names (or ``"joint 1"``, ...).
        ratio: ``{"q", "qd", "qdd"} -> (n_dof,)``. For ``qd`` and ``qdd``: the other log's
            robust peak ``|x|`` over the identification log's (1 = the same reach; inf where the
            identification log never moved). For ``q``: ``1 + `` how far the other log's range
            sticks out of the identification log's, as a fraction of the latter's width
            (1 = inside).
        reference_peak: the identification log's robust peaks, ``(n_dof,)`` each (q: the
            width of its 1-99 percentile range), rad, rad/s, rad/s^2.
        other_peak: the other log's, the same way.
    """

    joint_names: tuple[str, ...]
    ratio: dict[str, np.ndarray]
    reference_peak: dict[str, np.ndarray]
    other_peak: dict[str, np.ndarray]

    def worst(self) -> tuple[str, str, float]:
        """``(joint, signal, ratio)`` of the largest ratio."""
        best = max(
            (
                (j, s, float(self.ratio[s][j]))
                for s in _SIGNALS
                for j in range(len(self.joint_names))
            ),
            key=lambda t: t[2],
        )
        return self.joint_names[best[0]], best[1], best[2]

    def warnings(self, limit: float = DEFAULT_COVERAGE_LIMIT) -> list[str]:
        """One line per joint whose ratio exceeds ``limit`` for some signal (none: empty)."""
        lines = []
        for j, name in enumerate(self.joint_names):
            parts = []
            for s in _SIGNALS:
                r = float(self.ratio[s][j])
                if r <= limit:
                    continue
                if s == "q":
                    parts.append(f"positions {r - 1:.0%} of its range outside it")
                else:
                    parts.append(
                        f"{s} up to {self.other_peak[s][j]:.3g} {_UNITS[s]} where it reached "
                        f"{self.reference_peak[s][j]:.3g} ({r:.1f}x)"
                    )
            if parts:
                lines.append(f"{name}: " + "; ".join(parts))
        return lines


def coverage(
    reference: Sequence, other: Sequence, *, joint_names: Sequence[str] | None = None
) -> Coverage:
    """Compare the motion of ``other`` with that of ``reference`` (the identification log).

    Args:
        reference: ``(q, qd, qdd)`` of the identification log, each ``(n, n_dof)`` (arrays or
            tensors), rad, rad/s, rad/s^2 (m, m/s, m/s^2 for prismatic joints).
        other: ``(q, qd, qdd)`` of the log the model will predict, ``(m, n_dof)`` each.
        joint_names: ``n_dof`` names for the messages.

    Returns:
        A `Coverage`; ``.warnings()`` lists the joints where ``other`` extrapolates.

    Raises:
        ValueError: on shapes that do not match, fewer than 2 samples, or NaN entries.
    """
    ref, oth = _states(reference, "reference"), _states(other, "other")
    n = ref[0].shape[1]
    if oth[0].shape[1] != n:
        raise ValueError(f"reference has {n} joints, other {oth[0].shape[1]}")
    names = (
        tuple(joint_names) if joint_names is not None else tuple(f"joint {j + 1}" for j in range(n))
    )
    if len(names) != n:
        raise ValueError(f"{len(names)} joint names for {n} joints")
    ratio, rpeak, opeak = {}, {}, {}
    lo_r, hi_r = np.percentile(ref[0], [_LOW, _HIGH], axis=0)
    lo_o, hi_o = np.percentile(oth[0], [_LOW, _HIGH], axis=0)
    width = hi_r - lo_r
    out = np.maximum(0.0, np.maximum(hi_o - hi_r, lo_r - lo_o))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio["q"] = 1.0 + np.where(width > 0, out / width, np.where(out > 0, np.inf, 0.0))
        rpeak["q"], opeak["q"] = width, hi_o - lo_o
        for s, a, b in zip(_SIGNALS[1:], ref[1:], oth[1:], strict=True):
            pa = np.percentile(np.abs(a), _HIGH, axis=0)
            pb = np.percentile(np.abs(b), _HIGH, axis=0)
            ratio[s] = np.where(pa > 0, pb / pa, np.where(pb > 0, np.inf, 1.0))
            rpeak[s], opeak[s] = pa, pb
    return Coverage(names, ratio, rpeak, opeak)
