"""Optimal excitation: Fourier coefficients that make the base-parameter information large.

The information a trajectory carries about the identifiable (base) parameters is the weighted
moment matrix of the regressor restricted to the identifiable directions,

    M = V^T (1/N sum_i Y_i^T W Y_i) V,

with ``Y_i = Y(q(t_i), qd(t_i), qdd(t_i))`` the batched regressor (`RigidBodyModel.regressor`,
differentiable), ``W = diag(joint_weights)`` and ``V (n_params, r)`` an orthonormal basis of the
regressor's row space, computed once from an SVD of the regressor at random states
(`base_directions`: the directions no motion can excite are dropped). The criteria (Swevers
et al. 1997; Gautier and Khalil 1992):

* ``"d"`` (default), D-optimality: ``-log det M / r``, the mean log-eigenvalue (invariant to
  the choice of basis and of parameter units),
* ``"condition"``: ``log cond(Y V) = log(lambda_max / lambda_min) / 2``,
* ``"e"``, E-optimality: ``-log lambda_min(M)``.

`optimize_excitation` minimises the criterion over the coefficients of a `FourierTrajectory`
on a coarse grid of one period with torch autograd (LBFGS or Adam, several random starts)
while a quadratic penalty, raised over rounds, keeps the limits (`Limits`) with a small
safety margin; the result is then checked on a grid 10x finer than the output rate and shrunk
about the posture until it holds there (`check_limits`), or a ``ValueError`` says which limit
cannot be met.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import torch

from .._progress import progress_bar
from .._validation import check_joint_weights
from ..dynamics import RigidBodyModel
from ..sim import SinusoidTrajectory, random_trajectory
from ._fourier import FourierTrajectory, constrain_coefficients, fourier_states
from ._limits import Limits, _Kinematics, check_limits, constraint_violations

__all__ = [
    "CRITERIA",
    "ExcitationResult",
    "base_directions",
    "information_matrix",
    "criterion_value",
    "trajectory_information",
    "optimize_excitation",
    "random_excitation",
]

CRITERIA = ("d", "condition", "e")
_SAFETY = 0.02  # the optimiser aims 2% inside every limit so the fine-grid check holds


def base_directions(
    model: RigidBodyModel,
    limits: Limits,
    *,
    n_samples: int | None = None,
    joint_weights=None,
    rtol: float = 1e-9,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """An orthonormal basis of the identifiable parameter directions.

    The regressor at ``n_samples`` random states (positions uniform in the limits, velocities
    and accelerations uniform in +-min(limit, 2 rad/s) and +-min(limit, 10 rad/s^2)) is
    stacked and decomposed; right singular vectors with singular values above
    ``rtol * s_max`` span what any motion can identify.

    Args:
        model, limits: the robot and its `Limits`.
        n_samples: random states (default ``max(200, 4 * n_params)``).
        joint_weights: ``(n_dof,)`` weights of each joint's equations (default 1).
        rtol: relative rank tolerance.
        generator: the random draws' `torch.Generator`.

    Returns:
        ``(n_params, r)`` float64 basis V.
    """
    n, P = model.n_dof, model.n_params
    B = max(200, 4 * P) if n_samples is None else int(n_samples)
    g = generator
    kw = {"dtype": torch.float64}
    lo = torch.as_tensor(limits.position_low, **kw)
    hi = torch.as_tensor(limits.position_high, **kw)
    vmax = torch.as_tensor(np.minimum(limits.velocity, 2.0), **kw)
    amax = torch.as_tensor(np.minimum(limits.acceleration, 10.0), **kw)
    q = lo + (hi - lo) * torch.rand(B, n, generator=g, **kw)
    qd = vmax * (2 * torch.rand(B, n, generator=g, **kw) - 1)
    qdd = amax * (2 * torch.rand(B, n, generator=g, **kw) - 1)
    Y = model.regressor(q, qd, qdd) * _sqrt_weights(joint_weights, n)[:, None]
    _, s, Vh = torch.linalg.svd(Y.reshape(-1, P), full_matrices=False)
    r = int((s > rtol * s[0]).sum())
    return Vh[:r].T.contiguous()


def _sqrt_weights(joint_weights, n: int, like: torch.Tensor | None = None) -> torch.Tensor:
    kw = {"dtype": torch.float64} if like is None else {"dtype": like.dtype, "device": like.device}
    if joint_weights is None:
        return torch.ones(n, **kw)
    return check_joint_weights(joint_weights, n, positive=True, **kw).sqrt()


def information_matrix(
    model: RigidBodyModel, q, qd, qdd, basis: torch.Tensor, *, joint_weights=None
) -> torch.Tensor:
    """``M = V^T (1/N sum_i Y_i^T W Y_i) V``, ``(r, r)``, differentiable in the states.

    Args:
        model: the robot.
        q, qd, qdd: ``(N, n_dof)`` states.
        basis: ``(n_params, r)`` V from `base_directions`.
        joint_weights: ``(n_dof,)`` W's diagonal (default 1).
    """
    return _information(model.regressor(q, qd, qdd), basis, joint_weights)


def _information(Y: torch.Tensor, basis: torch.Tensor, joint_weights) -> torch.Tensor:
    """M from the regressor ``Y (N, n_dof, n_params)``."""
    Yb = (Y * _sqrt_weights(joint_weights, Y.shape[-2], Y)[:, None]) @ basis.to(Y)  # (N, n, r)
    Yb = Yb.reshape(-1, Yb.shape[-1])
    return Yb.T @ Yb / Y.shape[0]


def criterion_value(M: torch.Tensor, kind: str = "d") -> torch.Tensor:
    """The criterion of an information matrix (smaller is better; see the module).

    Args:
        M: ``(r, r)`` symmetric positive definite information matrix.
        kind: ``"d"``, ``"condition"`` or ``"e"``.

    Returns:
        A 0-d tensor; +inf when M is singular (a direction not excited).
    """
    if kind not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {kind!r}")
    ev = torch.linalg.eigvalsh(0.5 * (M + M.T))
    if not bool(ev[0] > 0):
        return ev.new_tensor(math.inf)
    if kind == "d":
        return -torch.log(ev).mean()
    if kind == "condition":
        return 0.5 * (torch.log(ev[-1]) - torch.log(ev[0]))
    return -torch.log(ev[0])


def _grid(period: float, n: int) -> torch.Tensor:
    return torch.arange(n, dtype=torch.float64) * (period / n)


def trajectory_information(
    model: RigidBodyModel,
    trajectory,
    basis: torch.Tensor,
    *,
    n_grid: int = 1000,
    joint_weights=None,
) -> dict:
    """Criteria, condition number and singular values of a trajectory's base regressor.

    Args:
        model: the robot.
        trajectory: `FourierTrajectory` or `torchjfa.sim.SinusoidTrajectory` (model joint order).
        basis: ``(n_params, r)`` V.
        n_grid: samples over one period.
        joint_weights: W's diagonal.

    Returns:
        ``{"d", "condition", "e"}`` criterion values, ``"condition_number"`` (cond of Y V) and
        ``"singular_values"`` (of ``Y V / sqrt(N)``, descending, numpy).
    """
    with torch.no_grad():
        M = information_matrix(
            model, *trajectory(_grid(trajectory.period, n_grid)), basis, joint_weights=joint_weights
        )
        ev = torch.linalg.eigvalsh(M).clamp_min(0.0).flip(0)
        out = {k: float(criterion_value(M, k)) for k in CRITERIA}
    out["condition_number"] = float((ev[0] / ev[-1]).sqrt()) if ev[-1] > 0 else math.inf
    out["singular_values"] = ev.sqrt().numpy()
    return out


@dataclass
class ExcitationResult:
    """What `optimize_excitation` found.

    Attributes:
        trajectory: the optimised `FourierTrajectory` (limits checked on the fine grid).
        criterion: the criterion's name.
        value: its value on the coarse grid at the optimum.
        condition_number: cond of the base regressor on the coarse grid.
        margins: smallest margin per kind of limit on the fine grid (fraction of the limit).
        basis: ``(n_params, r)`` the identifiable directions.
        limits: the `Limits` used.
        start_values: the criterion each random start reached.
        shrink: the factor the best start was shrunk by to hold the limits on the fine grid.
        seconds: wall time of the optimisation.
    """

    trajectory: FourierTrajectory
    criterion: str
    value: float
    condition_number: float
    margins: dict
    basis: torch.Tensor
    limits: Limits
    start_values: list = field(default_factory=list)
    shrink: float = 1.0
    seconds: float = 0.0


def _penalty(viol: dict[str, torch.Tensor]) -> torch.Tensor:
    return sum((torch.relu(v + _SAFETY) ** 2).mean(0).sum() for v in viol.values())


def _largest_feasible_scale(model, scaled, limits, rate, *, high: float = 1.0, theta=None):
    """The largest s in (0, high] for which ``scaled(s)`` holds the limits on the fine grid.

    Bisection (10 steps) on the output-rate grid, then the fine grid (10x the rate), backing
    off by 2 % until it holds there too (0 when nothing does: the hard check then raises).
    """

    def feasible(s, refine):
        m = check_limits(model, scaled(s), limits, rate=rate, refine=refine, theta=theta,
                         raise_error=False)  # fmt: skip
        return min(m.values()) >= 0.0

    s = high
    if not feasible(high, 1):
        lo, hi = 0.0, high
        for _ in range(10):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if feasible(mid, 1) else (lo, mid)
        s = lo
    for _ in range(20):
        if s == 0.0 or feasible(s, 10):
            return s
        s *= 0.98
    return 0.0


def optimize_excitation(
    model: RigidBodyModel,
    limits: Limits,
    *,
    duration: float = 10.0,
    base_frequency: float = 0.1,
    harmonics: int = 5,
    posture=None,
    criterion: str = "d",
    joint_weights=None,
    rate: float = 100.0,
    n_grid: int = 200,
    n_starts: int = 3,
    optimizer: str = "lbfgs",
    max_iter: int = 50,
    rounds: tuple[float, ...] = (1e3,),
    seed: int | None = 0,
    generator: torch.Generator | None = None,
    progress: bool = False,
) -> ExcitationResult:
    """Optimise a Fourier excitation for the identification of ``model``.

    Args:
        model: the robot (`RigidBodyModel`; its friction terms are part of the parameters).
        limits: the `Limits` to respect (`limits_from_model`).
        duration: length of the experiment, s: a whole number of periods ``1 / base_frequency``.
        base_frequency: f0, Hz.
        harmonics: H >= 2 harmonics per joint (the highest frequency is ``H f0``).
        posture: ``(n_dof,)`` q0 the trajectory starts and ends at, at rest (default: the middle
            of the position limits).
        criterion: ``"d"`` (default), ``"condition"`` or ``"e"`` (see the module).
        joint_weights: ``(n_dof,)`` weights of each joint's torque equation (e.g. 1 / torque
            noise variance); default 1.
        rate: output rate, Hz: the limits are checked at ``10 * rate``.
        n_grid: coarse grid points per period where the criterion and penalties are evaluated.
        n_starts: random starts; the best is kept.
        optimizer: ``"lbfgs"`` or ``"adam"``.
        max_iter: iterations per penalty round (LBFGS) or Adam steps per round.
        rounds: penalty weights, one optimisation round each.
        seed: seeds the `torch.Generator` when ``generator`` is None.
        generator: the random starts' and base directions' generator.
        progress: show a progress bar.

    Returns:
        An `ExcitationResult`.

    Raises:
        ValueError: on bad arguments, a posture outside the limits, or limits the trajectory
            cannot meet on the fine grid even shrunk to rest.
    """
    t0 = time.perf_counter()
    if not isinstance(model, RigidBodyModel):
        raise TypeError(f"model must be a RigidBodyModel, got {type(model)}")
    if not isinstance(limits, Limits) or limits.joint_names != model.joint_names:
        raise ValueError("limits must be the model's Limits (limits_from_model(model, ...))")
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    if optimizer not in ("lbfgs", "adam"):
        raise ValueError(f"optimizer must be 'lbfgs' or 'adam', got {optimizer!r}")
    if isinstance(harmonics, bool) or not isinstance(harmonics, int) or harmonics < 2:
        raise ValueError(
            f"harmonics must be an int >= 2 (rest at t = 0 needs 2), got {harmonics!r}"
        )
    f0 = float(base_frequency)
    if not f0 > 0 or not math.isfinite(f0):
        raise ValueError(f"base_frequency must be positive, got {base_frequency}")
    periods = float(duration) * f0
    if not periods >= 1 - 1e-9 or abs(periods - round(periods)) > 1e-6:
        raise ValueError(
            f"duration ({duration} s) must be a whole number of periods 1 / base_frequency "
            f"= {1 / f0:g} s"
        )
    for name, v in (("n_grid", n_grid), ("n_starts", n_starts), ("max_iter", max_iter)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    if n_grid < 4 * harmonics:
        raise ValueError(f"n_grid ({n_grid}) must be at least 4 x harmonics ({4 * harmonics})")
    n = model.n_dof
    lo, hi = limits.position_low, limits.position_high
    q0 = 0.5 * (lo + hi) if posture is None else np.asarray(posture, dtype=np.float64)
    if q0.shape != (n,):
        raise ValueError(f"posture must be {n} numbers (one per joint), got shape {q0.shape}")
    outside = [limits.joint_names[j] for j in range(n) if not lo[j] < q0[j] < hi[j]]
    if outside:
        raise ValueError(
            f"the posture is outside the position limits (margin included) of {outside}"
        )
    g = generator if generator is not None else torch.Generator()
    if generator is None and seed is not None:
        g.manual_seed(int(seed))
    basis = base_directions(model, limits, joint_weights=joint_weights, generator=g)
    kw = {"dtype": torch.float64}
    t = _grid(1.0 / f0, n_grid)
    posture_t = torch.as_tensor(q0, **kw)
    kin = None
    if limits.workspace:
        kin = _Kinematics(model, [b.frame for b in limits.workspace], torch.float64, "cpu")
    theta = model.nominal_theta
    w = 2 * math.pi * f0 * torch.arange(1, harmonics + 1, **kw)
    room = torch.as_tensor(np.minimum(q0 - lo, hi - q0), **kw)  # (n,) rad

    def states(a_raw, b_raw):
        a, b = constrain_coefficients(a_raw, b_raw)
        return a, b, fourier_states(t, posture_t, a, b, f0)

    def objective(a_raw, b_raw, rho):
        _, _, (q, qd, qdd) = states(a_raw, b_raw)
        Y = model.regressor(q, qd, qdd)  # (n_grid, n, P): one pass for M and the torques
        crit = criterion_value(_information(Y, basis, joint_weights), criterion)
        viol = constraint_violations(model, limits, q, qd, qdd, tau=Y @ theta, kinematics=kin)
        return crit + rho * _penalty(viol), crit

    best = None
    values = []
    total = n_starts * len(rounds)
    with progress_bar(total=total, desc="excitation", enabled=progress, unit="round") as bar:
        for _ in range(n_starts):
            # a random start inside the position limits: each joint uses ~half of its room
            a0 = torch.randn(n, harmonics, generator=g, **kw)
            b0 = torch.randn(n, harmonics, generator=g, **kw)
            a0, b0 = constrain_coefficients(a0, b0)
            reach = ((a0.abs() + b0.abs()) / w).sum(-1)  # bound on |q - q0|
            scale = (0.5 * room / reach)[:, None]
            a_raw = (a0 * scale).requires_grad_(True)
            b_raw = (b0 * scale).requires_grad_(True)
            crit = math.inf
            for rho in rounds:
                if optimizer == "lbfgs":
                    opt = torch.optim.LBFGS(
                        [a_raw, b_raw], lr=1.0, max_iter=max_iter, line_search_fn="strong_wolfe"
                    )

                    def closure(rho=rho, opt=opt, a_raw=a_raw, b_raw=b_raw):
                        opt.zero_grad()
                        loss, _ = objective(a_raw, b_raw, rho)
                        if torch.isfinite(loss):
                            loss.backward()
                        return loss

                    opt.step(closure)
                else:
                    opt = torch.optim.Adam([a_raw, b_raw], lr=0.02 * float(room.mean()))
                    for _ in range(max_iter):
                        opt.zero_grad()
                        loss, _ = objective(a_raw, b_raw, rho)
                        loss.backward()
                        opt.step()
                with torch.no_grad():
                    loss, c = objective(a_raw, b_raw, rho)
                crit = float(c)
                bar.update(1)
                bar.set_postfix(criterion=f"{crit:.4g}")
            with torch.no_grad():
                a, b, (q, qd, qdd) = states(a_raw, b_raw)
                viol = constraint_violations(model, limits, q, qd, qdd, theta=theta, kinematics=kin)
                worst = max(float(v.max()) for v in viol.values())
            values.append(crit)
            # prefer feasible starts on the coarse grid, then the criterion
            key = (worst > 0, crit)
            if best is None or key < best[0]:
                best = (key, a.detach().clone(), b.detach().clone())
    traj = FourierTrajectory(f0, q0, best[1].numpy(), best[2].numpy(), model.joint_names)

    shrink = _largest_feasible_scale(model, traj.scaled, limits, rate, theta=theta)
    if shrink < 1.0:
        traj = traj.scaled(shrink)
    # the hard check: raises with every violated limit if even the shrunk trajectory fails
    margins = check_limits(model, traj, limits, rate=rate, theta=theta)
    info = trajectory_information(model, traj, basis, n_grid=n_grid, joint_weights=joint_weights)
    return ExcitationResult(
        trajectory=traj,
        criterion=criterion,
        value=info[criterion],
        condition_number=info["condition_number"],
        margins=margins,
        basis=basis,
        limits=limits,
        start_values=values,
        shrink=shrink,
        seconds=time.perf_counter() - t0,
    )


def random_excitation(
    model: RigidBodyModel,
    limits: Limits,
    *,
    base_frequency: float = 0.1,
    harmonics: int = 5,
    rate: float = 100.0,
    seed: int | None = 0,
) -> SinusoidTrajectory:
    """The library's random sum of sinusoids (`torchjfa.sim.random_trajectory`) in the limits.

    The baseline an optimised excitation is compared with: ``min(3, H)`` random harmonics of
    ``base_frequency`` up to ``H``, centred in the position limits, its amplitudes then scaled
    by the largest factor that keeps every limit on the fine grid (10x ``rate``): at most the
    factor at which one joint's motion spans its whole position range.

    Returns:
        A `torchjfa.sim.SinusoidTrajectory` in the model's joint order.
    """
    # random_trajectory reads only the joint ranges of the MuJoCo model it is given
    ranges = SimpleNamespace(
        jnt_range=np.stack([limits.position_low, limits.position_high], 1),
        jnt_limited=np.ones(limits.n_dof, dtype=bool),
    )
    traj = random_trajectory(
        ranges,
        base_frequency=base_frequency,
        n_terms=min(3, harmonics),
        max_harmonic=harmonics,
        range_fraction=1.0,
        seed=seed,
    )

    def scaled(s):
        return SinusoidTrajectory(
            traj.base_frequency, traj.offset, traj.amplitude * s, traj.harmonic, traj.phase
        )

    t = torch.arange(int(math.ceil(traj.period * rate * 10)), dtype=torch.float64) / (10 * rate)
    q = traj(t)[0].numpy()
    half = 0.5 * (limits.position_high - limits.position_low)
    high = float(np.min(half / np.abs(q - traj.offset).max(0)))
    return scaled(_largest_feasible_scale(model, scaled, limits, rate, high=high))
