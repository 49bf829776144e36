"""Does a log show a motor that turns two joints, which the model does not have?

Many wrists drive a joint through the previous one (a belt or a differential): one motor turns
joints ``j`` and ``k`` together, and its rotor's inertia and damping then add to each joint's
torque a term in the OTHER joint's acceleration and velocity (the drive train's ``R^T I_m R``
has off-diagonal entries; `torchjfa.dynamics.Transmission`). A rigid-body model with one set of
joint terms per joint has no such constant cross term where the two axes are not parallel, so
the two joints' torques are predicted worse than the data allow, and nothing says why.

`coupled_drives` tests each pair of consecutive joints: it adds to the model two columns, a
shared constant cross inertia (``qdd_k`` in joint ``j``'s row, ``qdd_j`` in joint ``k``'s) and a
shared cross damping (``qd_k``, ``qd_j``), and scores the held-out torque prediction of the two
joints with and without them, as `armature_helps` scores the armature (ordinary least squares on
the other blocks, the filter's reach apart, against the unfiltered torque). A pair is reported
where the columns win by more than `MIN_SE` standard errors of the difference and by
`CHANCE_FACTOR` times the largest change the cross terms of any pair sharing no joint with it
make (on a short or poorly excited log, any two extra columns move the held-out score a lot,
either way; a pair that shares a joint also moves with a true coupling), AND cut the two joints'
held-out error by at least `MIN_GAIN` of its value: a drive train the description lacks (give it
with ``--transmission``), or on a robot without one a sign of some other cross-talk between the
two channels.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .._util import single_thread
from ._cutoff import _check_arguments, _difference, _Folds
from ._log import JointLog
from ._prepare import prepare

__all__ = ["CoupledDrive", "coupled_drives"]

#: the cross terms must win by more than this many standard errors of the difference
MIN_SE = 1.5
#: and cut the two joints' held-out mean nMSE by at least this share of it
MIN_GAIN = 0.25
#: and win by this many times the largest change (either way) that the cross terms of any
#: pair sharing no joint with it make: how much two such columns move the score by chance in
#: this log
CHANCE_FACTOR = 3.0


@dataclass(frozen=True)
class CoupledDrive:
    """A pair of joints whose torques follow each other's motion as a shared motor would.

    Attributes:
        joints: the two joints' names.
        nmse: the two joints' held-out mean nMSE without the cross terms.
        nmse_coupled: the same with them.
        standard_error: the standard error of the difference (all joints' per-sample nMSE).
    """

    joints: tuple[str, str]
    nmse: float
    nmse_coupled: float
    standard_error: float

    def describe(self) -> str:
        """One line: the joints, the evidence, the likely fix."""
        a, b = self.joints
        return (
            f"the torques of {a} and {b} follow each other's acceleration and velocity as a "
            f"motor turning both would (held-out nMSE of the two joints {self.nmse:.3g} without "
            f"a shared rotor's inertia and damping, {self.nmse_coupled:.3g} with them): a "
            "coupled drive the description lacks; give the drive train with --transmission "
            "FILE (motor velocity = ratio @ joint velocity, a row with two entries for a motor "
            "that turns both)"
        )


def coupled_drives(
    model,
    log: JointLog,
    cutoff_hz: float,
    *,
    method: str = "butterworth",
    velocity: str = "auto",
    n_folds: int = 5,
    compiled: bool | None = None,
) -> list[CoupledDrive]:
    """The pairs of consecutive joints whose held-out torques a shared motor explains
    (module docstring).

    Args:
        model: the robot with its joint terms (a `torchjfa.dynamics.RigidBodyModel`); the
            log's joints in its order.
        log: the raw training log, as for `torchjfa.data.choose_cutoff`.
        cutoff_hz: the cut-off the identification prepares with, Hz.
        method: as for `torchjfa.data.armature_helps`.
        velocity: as for `torchjfa.data.armature_helps`.
        n_folds: as for `torchjfa.data.armature_helps`.
        compiled: as for `torchjfa.data.armature_helps`.

    Returns:
        The pairs found, in joint order (empty where none).

    Raises:
        LogError: a log too short for the blocks, as `torchjfa.data.choose_cutoff`.
    """
    grid = _check_arguments(model, log, (cutoff_hz,), n_folds)
    folds = _Folds.of(log, grid, n_folds, method, velocity, None, None)
    d = prepare(folds.uniform, cutoff_hz=grid[0], decimate=folds.k, **folds.common)
    Y = model.regressor(d.q, d.qd, d.qdd, compiled=compiled)  # (n, n_dof, p)
    moments = _Moments(Y, d.tau, folds)
    var = folds.raw.var(0).clamp_min(1e-300)
    base = (moments.predict() - folds.raw) ** 2 / var  # (n, n_dof) per-sample nMSE
    names = list(model.joint_names)
    tried = []
    for j in range(len(names) - 1):
        extra = torch.zeros(*Y.shape[:-1], 2, dtype=Y.dtype)
        extra[:, j, 0], extra[:, j + 1, 0] = d.qdd[:, j + 1], d.qdd[:, j]
        extra[:, j, 1], extra[:, j + 1, 1] = d.qd[:, j + 1], d.qd[:, j]
        crossed = (moments.predict(extra) - folds.raw) ** 2 / var
        gain, se = _difference((base - crossed).mean(1), folds)
        pair = [j, j + 1]
        tried.append((j, gain, se, float(base[:, pair].mean()), float(crossed[:, pair].mean())))
    found = []
    for j, gain, se, before, after in tried:
        chance = max((abs(t[1]) for t in tried if abs(t[0] - j) > 1), default=0.0)
        if gain > max(MIN_SE * se, CHANCE_FACTOR * chance) and after <= (1 - MIN_GAIN) * before:
            found.append(CoupledDrive((names[j], names[j + 1]), before, after, se))
    return found


class _Moments:
    """Held-out predictions of ordinary least squares on each fold's training samples (all
    but the held-out block and the filter's reach around it), from moments per segment of
    the log: the regression's normal equations are formed once, a few columns added later
    cost only their own products."""

    def __init__(self, Y: torch.Tensor, tau: torch.Tensor, folds: _Folds) -> None:
        n = Y.shape[0]
        self.w = 1.0 / tau.std(0).clamp_min(1e-12)  # each joint's equations weighted
        self.Y, self.tau, self.folds = Y, tau, folds
        cuts = {0, n}
        for a, b in zip(folds.bounds, folds.bounds[1:], strict=False):
            cuts |= {min(n, max(0, x)) for x in (a - folds.gap, a, b, b + folds.gap)}
        self.cuts = sorted(cuts)
        self.G = [self._gram(Y, Y, s) for s in self._segments()]
        self.r = [self._gram(Y, tau[..., None], s)[:, 0] for s in self._segments()]

    def _segments(self):
        return [slice(a, b) for a, b in zip(self.cuts, self.cuts[1:], strict=False)]

    def _gram(self, A: torch.Tensor, B: torch.Tensor, s: slice) -> torch.Tensor:
        w = self.w[None, :, None]
        a, b = (A[s] * w).reshape(-1, A.shape[-1]), (B[s] * w).reshape(-1, B.shape[-1])
        return a.T @ b

    @single_thread()  # small matrices: threads only wait on each other
    def predict(self, extra: torch.Tensor | None = None) -> torch.Tensor:
        """``(n, n_dof)`` held-out predictions of the regression on ``Y`` and ``extra``
        (``(n, n_dof, e)`` further columns, or None)."""
        segs = self._segments()
        if extra is None:
            G, r, X = self.G, self.r, self.Y
        else:
            G, r = [], []
            for s, g, rr in zip(segs, self.G, self.r, strict=True):
                ye, ee = self._gram(self.Y, extra, s), self._gram(extra, extra, s)
                G.append(torch.cat([torch.cat([g, ye], 1), torch.cat([ye.T, ee], 1)], 0))
                r.append(torch.cat([rr, self._gram(extra, self.tau[..., None], s)[:, 0]]))
            X = torch.cat([self.Y, extra], dim=-1)
        pred = torch.empty_like(self.tau)
        f = self.folds
        for a, b in zip(f.bounds, f.bounds[1:], strict=False):
            train = [i for i, s in enumerate(segs) if s.stop <= a - f.gap or s.start >= b + f.gap]
            Gt, rt = sum(G[i] for i in train), sum(r[i] for i in train)
            scale = Gt.diagonal().sqrt()
            scale = torch.where(scale > 0, scale, torch.ones_like(scale))
            sol = torch.linalg.pinv(Gt / scale[:, None] / scale[None, :], rtol=1e-14,
                                    hermitian=True) @ (rt / scale)  # fmt: skip
            pred[a:b] = X[a:b] @ (sol / scale)
        return pred
