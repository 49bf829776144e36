"""The low-pass cut-off chosen from the data: held-out torque prediction over a grid.

The cut-off of `prepare`'s zero-phase filter decides more of a real robot's identification
than the estimator does (on a real arm's log the cut-off can change the held-out error by a
factor of two). Too low, and the filter removes real dynamics from the positions and the
torques alike; too high, and the accelerations differentiated twice from the measurements
drown in noise. `choose_cutoff` measures it:

1. the log is put on uniform time once, and split into contiguous blocks (``n_folds``);
2. for each cut-off on the grid (default 2-30 Hz, 8 values, log-spaced) it is prepared as
   `prepare` does (same filter, same velocities), decimated for speed, and ordinary least
   squares with the model's joint terms is fitted on all but one block and scores the torque
   prediction on the block held out, for every block in turn; the samples within the filter's
   reach of a held-out block (``2 / min(grid)`` s: beyond it the zero-phase 4th-order
   Butterworth's impulse response holds under 0.5 % of its weight) are left out of its fit,
   so that the fit does not see the held-out torques through the filter;
3. every cut-off is scored against ONE target, the same for all: the measured torque, not
   filtered. Against the torque filtered at each candidate's own cut-off, a lower cut-off would
   win by smoothing its own target. The raw torque's noise, independent of any prediction,
   adds the same amount to every candidate's mean squared error, so the ranking is that of the
   error against the true torque (what the noise hides, it hides from all alike);
4. the score is the mean over joints of the held-out nMSE (squared error over the measured
   torque's variance, so that every joint counts); the choice is the LARGEST cut-off whose
   score lies within one standard error of the best one (the one-standard-error rule; the
   standard error of the score difference from contiguous blocks of the held-out samples): of
   cut-offs the data cannot tell apart, the one that distorts the dynamics least;
5. where the model has a Coulomb term, each cut-off is scored with the best of a few smoothing
   velocities ``v_c`` of it (`COULOMB_GRID`; the column ``tanh(qd / v_c)``, ``sign(qd)`` at 0),
   and the chosen cut-off's best ``v_c`` is returned with it: real dry friction changes sign
   over a band of velocities, and how wide it is, is a property of the robot the log shows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from .._util import single_thread
from .._validation import check_coulomb_velocity
from ._log import JointLog, LogError
from ._prepare import is_uniform, prepare, resample

__all__ = ["COULOMB_GRID", "CutoffChoice", "armature_helps", "choose_cutoff", "cutoff_grid"]

#: The Coulomb term's smoothing velocities `choose_cutoff` tries by default, rad/s (0: sign).
COULOMB_GRID = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2)


def cutoff_grid(low_hz: float = 2.0, high_hz: float = 30.0, n: int = 8) -> tuple[float, ...]:
    """``n`` log-spaced cut-offs from ``low_hz`` to ``high_hz``, Hz, rounded to 3 digits."""
    if not (0 < low_hz < high_hz) or n < 2:
        raise ValueError(f"need 0 < low_hz < high_hz and n >= 2, got {low_hz}, {high_hz}, {n}")
    r = (high_hz / low_hz) ** (1.0 / (n - 1))
    return tuple(float(f"{low_hz * r**i:.3g}") for i in range(n))


@dataclass(frozen=True)
class CutoffChoice:
    """What `choose_cutoff` measured.

    Attributes:
        cutoff_hz: the chosen cut-off, Hz.
        grid_hz: the cut-offs tried, Hz, increasing.
        scores: held-out mean nMSE per cut-off (against the unfiltered torque).
        rms: held-out mean per-joint RMS torque error per cut-off, N m (same target).
        standard_errors: standard error of each score's difference from the best one's.
        best_hz: the cut-off with the lowest score, Hz (``cutoff_hz`` is the largest within
            one standard error of it).
        how: one line for a report: how the cut-off was chosen, with the numbers.
        coulomb_velocity: the chosen smoothing velocity of the Coulomb term, rad/s (0:
            ``sign(qd)``), or None where none was chosen (no Coulomb term, empty grid).
        coulomb_grid: the smoothing velocities tried, rad/s (empty where none was chosen).
        coulomb_scores: held-out mean nMSE per smoothing velocity at the chosen cut-off.
    """

    cutoff_hz: float
    grid_hz: tuple[float, ...]
    scores: tuple[float, ...]
    rms: tuple[float, ...]
    standard_errors: tuple[float, ...]
    best_hz: float
    how: str
    coulomb_velocity: float | None = None
    coulomb_grid: tuple[float, ...] = ()
    coulomb_scores: tuple[float, ...] = ()


@single_thread()  # small matrices: threads only wait on each other
def _fit(Y: torch.Tensor, tau: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Least squares ``tau ~ Y theta`` with joint weights ``w``, from the moments (the normal
    equations of the column-scaled problem, solved by a pseudo-inverse: minimum norm along the
    directions the data leave undetermined)."""
    p = Y.shape[-1]
    A = (Y * w[None, :, None]).reshape(-1, p)
    b = (tau * w[None, :]).reshape(-1)
    s = A.norm(dim=0)
    s = torch.where(s > 0, s, torch.ones_like(s))
    A = A / s
    # eigenvalues of the Gram matrix are squared singular values: 1e-14 of the largest is
    # 1e-7 in singular values, above the round-off of forming A^T A in float64
    sol = torch.linalg.pinv(A.T @ A, rtol=1e-14, hermitian=True) @ (A.T @ b)
    return sol / s


def choose_cutoff(
    model,
    log: JointLog,
    *,
    grid_hz: Sequence[float] | None = None,
    method: str = "butterworth",
    velocity: str = "auto",
    n_folds: int = 3,
    reach_s: float | None = None,
    rate_hz: float | None = None,
    compiled: bool | None = None,
    coulomb_grid: Sequence[float] | None = None,
) -> CutoffChoice:
    """The low-pass cut-off of `prepare` that predicts held-out torques best (module docstring).

    Args:
        model: the robot (a `torchjfa.dynamics.RigidBodyModel` with its joint terms); the
            log's joints in its order (`JointLog.reorder`).
        log: the raw training log (never the part held out for validation), q and tau.
        grid_hz: the cut-offs to try, Hz (default `cutoff_grid()`: 2-30 Hz, 8 values).
        method: as for `prepare`.
        velocity: as for `prepare`.
        n_folds: contiguous blocks, each held out once (at least 2).
        reach_s: samples within this many seconds of a held-out block are left out of its fit,
            and as many at the log's ends (default ``2 / min(grid_hz)``).
        rate_hz: the rate the prepared data are decimated to for the fits (default: about
            four times the largest cut-off, so that decimation never aliases).
        compiled: the regressor's path (see `RigidBodyModel.regressor`).
        coulomb_grid: smoothing velocities of the Coulomb term to choose from with the cut-off,
            rad/s (`torchjfa.dynamics.RigidBodyModel.coulomb_velocity`; 0 is ``sign(qd)``);
            default `COULOMB_GRID` where the model has a Coulomb term; ``()`` keeps the
            model's own.

    Returns:
        `CutoffChoice`.

    Raises:
        LogError: a log too short for the blocks and the filter's reach, or no cut-off on the
            grid below the log's Nyquist frequency.
    """
    grid = _check_arguments(model, log, grid_hz, n_folds)
    folds = _Folds.of(log, grid, n_folds, method, velocity, reach_s, rate_hz)
    widths = _widths(model, coulomb_grid)
    errors, rms, by_width = [], [], []
    for c in folds.grid:
        e, r, j, per_width = _score(model, folds, c, widths, compiled)
        errors.append(e)
        rms.append(r)
        by_width.append((j, per_width))
    E = torch.stack(errors)  # (n_grid, n)
    scores, se, best, pick = _one_standard_error(E, folds)
    grid = folds.grid
    shown = ", ".join(f"{c:g} Hz {float(s):.3g}" for c, s in zip(grid, scores, strict=True))
    how = (
        f"chosen by held-out torque prediction over {grid[0]:g}..{grid[-1]:g} Hz "
        f"({len(grid)} cut-offs; OLS with the model's joint terms, {n_folds} blocks held out in "
        f"turn, {folds.reach:.3g} s apart from their fits, scored against the unfiltered "
        f"torque): mean nMSE {shown}; " + _verdict(grid, scores, se, best, pick)
    )
    chosen_v, v_scores = None, ()
    if widths != [None]:
        j, v_scores = by_width[pick]
        chosen_v = widths[j]
        how += (
            "; with it the Coulomb term's smoothing velocity tanh(qd / v_c), each cut-off "
            "scored with its best v_c: "
            + ", ".join(f"{v:g} rad/s {sc:.3g}" for v, sc in zip(widths, v_scores, strict=True))
            + f"; v_c = {chosen_v:g} rad/s"
            + (" (sign(qd))" if chosen_v == 0 else "")
        )
    return CutoffChoice(
        cutoff_hz=grid[pick],
        grid_hz=tuple(grid),
        scores=tuple(float(s) for s in scores),
        rms=tuple(rms),
        standard_errors=tuple(float(s) for s in se),
        best_hz=grid[best],
        how=how,
        coulomb_velocity=chosen_v,
        coulomb_grid=() if chosen_v is None else tuple(widths),
        coulomb_scores=tuple(v_scores),
    )


def armature_helps(
    model,
    log: JointLog,
    cutoff_hz: float,
    *,
    method: str = "butterworth",
    velocity: str = "auto",
    n_folds: int = 5,
    compiled: bool | None = None,
) -> tuple[bool, str]:
    """Whether the motor's reflected inertia (the joint term ``"armature"``, a column ``qdd``
    per joint) predicts held-out torques better than the model without it.

    The same held-out blocks as `choose_cutoff` at ``cutoff_hz`` (ordinary least squares on
    the other blocks, the filter's reach apart, scored against the unfiltered torque); the
    armature is taken only where it wins by more than one standard error of the difference
    (from contiguous blocks of the held-out samples): a term the data cannot tell from none is
    left out. On geared arms the rotor inertia is a large part of the torque (the motor's
    inertia times the gear ratio squared); behind link-side torque sensors it is not seen.

    Args:
        model: the robot without the armature term.
        log: the raw training log, as for `choose_cutoff`.
        cutoff_hz: the cut-off the identification prepares with, Hz.
        method: as for `choose_cutoff`.
        velocity: as for `choose_cutoff`.
        n_folds: as for `choose_cutoff`.
        compiled: as for `choose_cutoff`.

    Returns:
        ``(helps, how)``: whether to add the term, and one line for the report.

    Raises:
        LogError: a log too short for the blocks, as `choose_cutoff`.
    """
    if "armature" in model.friction:
        return True, "given"
    grid = _check_arguments(model, log, (cutoff_hz,), n_folds)
    folds = _Folds.of(log, grid, n_folds, method, velocity, None, None)
    other = model.with_joint_terms((*model.friction, "armature"))
    without, with_ = (_score(m, folds, grid[0], [None], compiled)[0] for m in (model, other))
    gain, se = _difference(without - with_, folds)
    helps = gain > se
    how = (
        f"held-out torque prediction at {grid[0]:g} Hz (OLS, {n_folds} blocks held out in turn, "
        f"against the unfiltered torque): mean nMSE {float(without.mean()):.4g} without the "
        f"motor's armature, {float(with_.mean()):.4g} with it (standard error of the "
        f"difference {se:.2g}): "
        + ("armature added" if helps else "left out (it does not win by a standard error)")
    )
    return helps, how


def _difference(d: torch.Tensor, folds: _Folds) -> tuple[float, float]:
    """The mean of per-sample differences ``d (n,)`` and its standard error from contiguous
    blocks of about 0.5 s (as `_one_standard_error`)."""
    n = d.shape[0]
    n_blocks = max(2, min(20, n // max(1, int(0.5 * folds.rate / folds.k))))
    means = torch.stack([b.mean() for b in torch.tensor_split(d, n_blocks)])
    return float(d.mean()), float(means.std() / math.sqrt(n_blocks))


def _check_arguments(model, log: JointLog, grid_hz, n_folds) -> list[float]:
    """Check `choose_cutoff`'s arguments; returns the grid, Hz, increasing."""
    grid = sorted(float(c) for c in (cutoff_grid() if grid_hz is None else grid_hz))
    if not grid or any(not (math.isfinite(c) and c > 0) for c in grid):
        raise ValueError(f"grid_hz must hold positive cut-offs, Hz, got {grid_hz!r}")
    if isinstance(n_folds, bool) or not isinstance(n_folds, int) or n_folds < 2:
        raise ValueError(f"n_folds must be an int of at least 2, got {n_folds!r}")
    if tuple(log.joint_names) != tuple(model.joint_names):
        raise ValueError(
            f"the log's joints {tuple(log.joint_names)} are not the model's "
            f"{tuple(model.joint_names)} in its order; use log.reorder(model.joint_names)"
        )
    if log.n_samples < 2 * (n_folds + 2):
        raise LogError(
            f"{log.source}: {log.n_samples} samples are too few to choose a cut-off by "
            f"{n_folds} held-out blocks; give the cut-off (--cutoff HZ)"
        )
    return grid


@dataclass(frozen=True)
class _Folds:
    """The log on uniform time, and how `choose_cutoff` prepares it and holds blocks out.

    Attributes:
        uniform: the log on uniform time.
        rate: its rate, Hz.
        grid: the cut-offs tried, Hz (those below 0.45 ``rate``).
        reach: the filter's reach, s: the samples this close to a held-out block are left out
            of its fit.
        k: the decimation factor of the prepared data.
        common: `prepare`'s keyword arguments shared by every cut-off.
        raw: ``(n, n_dof)`` the measured torque, not filtered, decimated: the target.
        bounds: ``n_folds + 1`` sample indices of the blocks' edges.
        gap: the reach in decimated samples.
    """

    uniform: JointLog
    rate: float
    grid: list[float]
    reach: float
    k: int
    common: dict
    raw: torch.Tensor
    bounds: list[int]
    gap: int

    @classmethod
    def of(cls, log, grid, n_folds, method, velocity, reach_s, rate_hz) -> _Folds:
        """The folds of ``log``; raises `LogError` where it is too short for them."""
        uniform = log if is_uniform(log.t) else resample(log)
        rate = uniform.rate_hz
        grid = [c for c in grid if c < 0.45 * rate]
        if not grid:
            raise LogError(f"{log.source}: no cut-off on the grid lies below {0.45 * rate:.4g} Hz")
        reach = 2.0 / grid[0] if reach_s is None else float(reach_s)
        target_rate = 4.0 * grid[-1] if rate_hz is None else float(rate_hz)
        k = max(1, int(rate // target_rate))
        while k > 1 and grid[-1] >= 0.5 * rate / k:
            k -= 1
        if not uniform.duration > (n_folds + 2) * reach:
            raise LogError(
                f"{log.source}: {log.duration:.3g} s are too short to choose a cut-off by "
                f"{n_folds} held-out blocks with the filter's reach of {reach:.3g} s (more than "
                f"{(n_folds + 2) * reach:.3g} s needed); give the cut-off (--cutoff HZ)"
            )
        common = {"method": method, "velocity": velocity, "period_s": None, "edge_s": reach}
        raw = prepare(uniform, cutoff_hz=grid[0], filter_torque=False, decimate=k, **common).tau
        n = raw.shape[0]
        gap = int(math.ceil(reach * rate / k))
        bounds = [round(i * n / n_folds) for i in range(n_folds + 1)]
        if min(b - a for a, b in zip(bounds, bounds[1:], strict=False)) < 2 or gap >= n // n_folds:
            raise LogError(
                f"{log.source}: {n} samples after decimation by {k} are too few to choose a "
                f"cut-off by {n_folds} held-out blocks {gap} samples apart from their fits; give "
                "the cut-off (--cutoff HZ)"
            )
        return cls(uniform, rate, grid, reach, k, common, raw, bounds, gap)


def _score(model, folds: _Folds, cutoff: float, widths: list, compiled):
    """Held-out errors of one cut-off, with the best of the Coulomb smoothing velocities.

    Returns:
        ``(per-sample nMSE (n,), mean per-joint RMS error, index of the best width, mean nMSE
        per width)``.
    """
    raw, bounds, gap = folds.raw, folds.bounds, folds.gap
    var = raw.var(0).clamp_min(1e-300)
    idx = torch.arange(raw.shape[0])
    d = prepare(folds.uniform, cutoff_hz=cutoff, decimate=folds.k, **folds.common)
    w = 1.0 / d.tau.std(0).clamp_min(1e-12)
    tried = []
    for v in widths:
        m = model if v is None else model.with_coulomb_velocity(v)
        Y = m.regressor(d.q, d.qd, d.qdd, compiled=compiled)
        pred = torch.empty_like(raw)
        with single_thread():  # small solves: threads only wait on each other
            for a, b in zip(bounds, bounds[1:], strict=False):
                fit = (idx < a - gap) | (idx >= b + gap)
                pred[a:b] = Y[a:b] @ _fit(Y[fit], d.tau[fit], w)
        e2 = (pred - raw) ** 2
        tried.append(((e2 / var).mean(1), float(e2.mean(0).sqrt().mean())))  # per-sample nMSE
    j = min(range(len(tried)), key=lambda i: float(tried[i][0].mean()))
    return tried[j][0], tried[j][1], j, tuple(float(e.mean()) for e, _ in tried)


def _one_standard_error(E: torch.Tensor, folds: _Folds):
    """The one-standard-error rule on per-sample errors ``E (n_grid, n)``.

    Returns:
        ``(scores (n_grid,), standard errors of each score's difference from the best one's,
        index of the best, index of the largest cut-off within one standard error of it)``;
        the standard errors from contiguous blocks of about 0.5 s.
    """
    scores = E.mean(1)
    best = int(torch.argmin(scores))
    n = E.shape[1]
    n_blocks = max(2, min(20, n // max(1, int(0.5 * folds.rate / folds.k))))  # about 0.5 s blocks
    blocks = torch.tensor_split(E - E[best], n_blocks, dim=1)
    means = torch.stack([b.mean(1) for b in blocks], 1)  # (n_grid, n_blocks)
    se = means.std(1) / math.sqrt(n_blocks)
    within = [i for i in range(len(folds.grid)) if float(scores[i] - scores[best]) <= float(se[i])]
    return scores, se, best, max(within)


def _verdict(grid, scores, se, best: int, pick: int) -> str:
    """How the rule chose: the best, the largest within one standard error of it, or, where
    every cut-off lies within one standard error of the best, a tie that the rule breaks."""
    if len(grid) > 1 and all(
        float(scores[i] - scores[best]) <= float(se[i]) for i in range(len(grid))
    ):
        return (
            "the log cannot tell these cut-offs apart (every score lies within one standard "
            f"error of the best, {grid[best]:g} Hz); the rule takes the largest, "
            f"{grid[pick]:g} Hz, which distorts the dynamics least"
        )
    if pick == best:
        return f"best {grid[best]:g} Hz"
    return f"best {grid[best]:g} Hz, {grid[pick]:g} Hz the largest within one standard error of it"


def _widths(model, coulomb_grid) -> list:
    """The Coulomb smoothing velocities to try: ``[None]`` (the model's own) when the model has
    no Coulomb term or ``coulomb_grid`` is empty, else the checked grid."""
    if "coulomb" not in getattr(model, "friction", ()):
        return [None]
    grid = COULOMB_GRID if coulomb_grid is None else tuple(coulomb_grid)
    return [check_coulomb_velocity(v) for v in grid] or [None]
