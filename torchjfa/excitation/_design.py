"""Optimal excitation: Fourier coefficients that make the base-parameter information large.

The information a trajectory carries about the identifiable (base) parameters is the weighted
moment matrix of the regressor restricted to the identifiable directions,

    M = V^T (1/N sum_i Y_i^T W Y_i) V,

with ``Y_i = Y(q(t_i), qd(t_i), qdd(t_i))`` the batched regressor (`RigidBodyModel.regressor`,
differentiable), ``W = diag(joint_weights)`` and ``V (n_params, r)`` an orthonormal basis of the
regressor's row space, computed once from an SVD of the regressor at random states
(`base_directions`: the directions no motion can excite are dropped). The criteria (Swevers
et al. 1997; Gautier and Khalil 1992):

* ``"d"``, D-optimality: ``-log det M / r``, the mean log-eigenvalue (invariant to the choice
  of basis and of parameter units),
* ``"condition"``: ``log cond(Y V) = log(lambda_max / lambda_min) / 2``, the condition number
  of the base regressor in the parameters' units (the one `trajectory_information` reports),
* ``"d+condition"`` (default): D-optimal starts, then the best ``polish_starts`` (two) polished
  on the condition number (it keeps the D-optimum's low errors and lowers the condition
  number; the polish runs longer than the starts, ``polish_iter``, and never returns a
  trajectory of higher exact condition number than the starts it polished),
* ``"e"``, E-optimality: ``-log lambda_min(M)``.

`optimize_excitation` minimises the criterion over the coefficients of a `FourierTrajectory`
on a coarse grid of one period with torch autograd (LBFGS or Adam, several random starts)
while a quadratic penalty, raised over rounds, keeps the limits (`Limits`: joints, torques,
workspace boxes, and the mounting plane and self-collision through capsules along the links,
`torchjfa.excitation._geometry`) with a small safety margin (in the polish, each limit's target is moved after every round by what the
round's optimum exceeded it by: `_Design.update_shift`). The condition number, a nonsmooth
ratio of extreme eigenvalues (LBFGS stalls on it where they cluster), is optimised through
its smooth bound `soft_condition` with the exponent p raised over rounds (``condition_p``;
``inf`` is the exact log condition number). The result is then checked on a grid 10x finer
than the output rate and shrunk about the posture until it holds there (`check_limits`; the
floor and self-collision on the description's collision geometry through MuJoCo where it has
some, after cuts where that geometry came closer than the capsules allowed:
`torchjfa.excitation._problem.repair_geometry`), or a ``ValueError`` says which limit cannot
be met.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import torch

from .._util import progress_bar
from ..dynamics import RigidBodyModel
from ..sim import SinusoidTrajectory, random_trajectory
from ._check import check_limits, physical_margins
from ._fourier import FourierTrajectory, constrain_coefficients
from ._geometry import Geometry, start_geometry
from ._information import (
    CRITERIA,
    base_directions,
    payload_directions,
    period_grid,
    trajectory_information,
)
from ._limits import JOINT_KINDS as JOINT_KINDS
from ._limits import Limits, _Kinematics
from ._problem import _EDGE as _EDGE
from ._problem import _SAFETY as _SAFETY
from ._problem import (
    _condition_key,
    _Design,
    _optimise_round,
    _worst_violation,
    repair_geometry,
)
from ._problem import _penalty as _penalty

__all__ = ["DEFAULT_RATE", "ExcitationResult", "optimize_excitation", "random_excitation"]

#: an excitation's output rate, Hz (its limits are checked at 10x)
DEFAULT_RATE = 200.0


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
        physical_margins: what is left of each limit on the fine grid in physical units
            (`torchjfa.excitation._check.physical_margins`).
        geometry: lines on the floor and self-collision checks (what was used, what was
            left out), empty when neither is checked.
        posture_moved: the default posture (the middle of the limits) was moved to clear the
            floor.
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
    physical_margins: dict = field(default_factory=dict)
    geometry: list = field(default_factory=list)
    posture_moved: bool = False


def _largest_feasible_scale(
    model, scaled, limits, rate, *, high: float = 1.0, theta=None, geometry=None
):
    """The largest s in (0, high] for which ``scaled(s)`` holds the limits on the fine grid.

    Bisection (10 steps) on the output-rate grid, then the fine grid (10x the rate), backing
    off by 2 % until it holds there too (0 when nothing does: the hard check then raises).
    """

    def feasible(s, refine):
        m = check_limits(model, scaled(s), limits, rate=rate, refine=refine, theta=theta,
                         raise_error=False, geometry=geometry)  # fmt: skip
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
    criterion: str = "d+condition",
    joint_weights=None,
    rate: float = DEFAULT_RATE,
    n_grid: int = 200,
    n_starts: int = 3,
    optimizer: str = "lbfgs",
    max_iter: int = 50,
    rounds: tuple[float, ...] = (1e3,),
    condition_p: tuple[float, ...] = (2.0, 8.0, 32.0, 128.0),
    polish_iter: int = 200,
    polish_starts: int = 2,
    seed: int | None = 0,
    generator: torch.Generator | None = None,
    progress: bool = False,
    payload: str | None = None,
) -> ExcitationResult:
    """Optimise a Fourier excitation for the identification of ``model``.

    Args:
        model: the robot (`RigidBodyModel`; its friction terms are part of the parameters).
        limits: the `Limits` to respect (`limits_from_model`).
        duration: length of the experiment, s: a whole number of periods ``1 / base_frequency``.
        base_frequency: f0, Hz.
        harmonics: H >= 2 harmonics per joint (the highest frequency is ``H f0``).
        posture: ``(n_dof,)`` q0 the trajectory starts and ends at, at rest (default: the middle
            of the position limits, moved to the nearest posture that clears the floor when
            it does not: `torchjfa.excitation._geometry.safe_posture`).
        criterion: ``"d+condition"`` (default), ``"d"``, ``"condition"`` or ``"e"`` (see the
            module).
        joint_weights: ``(n_dof,)`` weights of each joint's torque equation (e.g. 1 / torque
            noise variance); default 1.
        rate: output rate, Hz: the limits are checked at ``10 * rate``.
        n_grid: coarse grid points per period where the criterion and penalties are evaluated.
        n_starts: random starts; the best is kept.
        optimizer: ``"lbfgs"`` or ``"adam"``.
        max_iter: iterations per penalty round (LBFGS) or Adam steps per round.
        rounds: penalty weights, one optimisation round each.
        condition_p: exponents of `soft_condition`, one round each (at the last penalty
            weight): for ``"condition"`` after every start's penalty rounds (run at the first
            exponent; ``max_iter`` iterations), for ``"d+condition"`` on the best D-optimal
            starts (``polish_iter`` iterations); ``math.inf`` is the exact log condition
            number.
        polish_iter: LBFGS iterations (or Adam steps) per exponent of the ``"d+condition"``
            polish.
        polish_starts: how many of the best D-optimal starts ``"d+condition"`` polishes; the
            trajectory kept is the one (polished or not) of lowest exact condition number on
            the coarse grid among those that hold the limits there.
        seed: seeds the `torch.Generator` when ``generator`` is None.
        generator: the random starts' and base directions' generator.
        progress: show a progress bar.
        payload: a link: design for the parameters of a payload fixed to it alone (the
            robot's model given; `payload_directions`) instead of the robot's.

    Returns:
        An `ExcitationResult`.

    Raises:
        ValueError: on bad arguments, a posture outside the limits or too close to the floor,
            or limits the trajectory cannot meet on the fine grid even shrunk to rest.
    """
    t0 = time.perf_counter()
    f0 = _check_design(
        model,
        limits,
        criterion=criterion,
        optimizer=optimizer,
        harmonics=harmonics,
        base_frequency=base_frequency,
        duration=duration,
        counts={
            "n_grid": n_grid,
            "n_starts": n_starts,
            "max_iter": max_iter,
            "polish_iter": polish_iter,
            "polish_starts": polish_starts,
        },  # fmt: skip
    )
    condition_p = _check_exponents(condition_p, criterion)
    q0 = _posture(limits, posture, model.n_dof)
    geometry, moved = None, False
    if limits.has_geometry:
        q0, geometry, moved = start_geometry(model, limits, q0, movable=posture is None)
    g = generator if generator is not None else torch.Generator()
    if generator is None and seed is not None:
        g.manual_seed(int(seed))
    basis = _basis(model, limits, payload, joint_weights, g)
    kin = None
    if limits.workspace:
        kin = _Kinematics(model, [b.frame for b in limits.workspace])
    problem = _Design(
        model, limits, basis, criterion, joint_weights, kin, period_grid(1.0 / f0, n_grid), q0, f0
    )
    problem.geometry = geometry
    # "d+condition": D-optimal starts, the best one polished at every exponent; "condition":
    # every start on soft_condition (its penalty rounds at the first exponent, then the others),
    # so its start_values are the bound at the last exponent
    plan = _Plan(
        rounds=rounds,
        per_start=condition_p[1:] if criterion == "condition" else (),
        start_p=condition_p[0] if criterion == "condition" else None,
        polish=condition_p if criterion == "d+condition" else (),
        optimizer=optimizer,
        max_iter=max_iter,
        polish_iter=polish_iter,
    )
    problem.p = plan.start_p
    room = torch.as_tensor(
        np.minimum(q0 - limits.position_low, limits.position_high - q0), dtype=torch.float64
    )
    n_polish = min(polish_starts, n_starts) if plan.polish else 0
    total = n_starts * (len(rounds) + len(plan.per_start)) + n_polish * len(plan.polish)
    with progress_bar(total=total, desc="excitation", enabled=progress, unit="round") as bar:
        starts, values = _run_starts(problem, plan, n_starts, harmonics, g, room, bar)
        a_raw, b_raw = _polish(problem, plan, starts[:n_polish], starts[0], room, bar)
        a_raw, b_raw = a_raw.clone().requires_grad_(True), b_raw.clone().requires_grad_(True)
        repair_geometry(problem, a_raw, b_raw, plan.rounds[-1], optimizer, max_iter, room)
        with torch.no_grad():
            a, b = constrain_coefficients(a_raw, b_raw)
    traj = FourierTrajectory(f0, q0, a.numpy(), b.numpy(), model.joint_names)
    traj, shrink, margins, physical = _checked(model, traj, limits, rate, problem.theta, geometry)
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
        physical_margins=physical,
        geometry=geometry.describe() if geometry is not None else [],
        posture_moved=moved,
    )


def _basis(model, limits, payload, joint_weights, g) -> torch.Tensor:
    """The directions the criterion weighs: the robot's identifiable ones, or a payload's."""
    if payload is None:
        return base_directions(model, limits, joint_weights=joint_weights, generator=g)
    return payload_directions(model, limits, payload, joint_weights=joint_weights, generator=g)


def _checked(model, traj, limits, rate, theta, geometry):
    """``(trajectory, shrink, margins, physical margins)``: ``traj`` shrunk about its posture
    until it holds every limit on the fine grid, then checked there (`check_limits`: raises
    with every violated limit if even the shrunk trajectory fails)."""
    shrink = _largest_feasible_scale(
        model, traj.scaled, limits, rate, theta=theta, geometry=geometry
    )
    if shrink < 1.0:
        traj = traj.scaled(shrink)
    kw = {"rate": rate, "theta": theta, "geometry": geometry}
    margins = check_limits(model, traj, limits, **kw)
    return traj, shrink, margins, physical_margins(model, traj, limits, **kw)


@dataclass(frozen=True)
class _Plan:
    """The rounds of `optimize_excitation`'s optimisation.

    Attributes:
        rounds: penalty weights, one round each, for every start.
        per_start: `soft_condition` exponents of the further rounds of every start (at the
            last penalty weight; ``"condition"``).
        start_p: the exponent of the starts' penalty rounds (None: the criterion itself).
        polish: the exponents of the polish of the best starts (``"d+condition"``).
        optimizer: ``"lbfgs"`` or ``"adam"``.
        max_iter: iterations per round of a start.
        polish_iter: iterations per round of the polish.
    """

    rounds: tuple[float, ...]
    per_start: tuple[float, ...]
    start_p: float | None
    polish: tuple[float, ...]
    optimizer: str
    max_iter: int
    polish_iter: int


def _random_start(g: torch.Generator, n: int, harmonics: int, w, room):
    """Raw coefficients ``(n, H)`` of a random start inside the position limits: each joint
    uses about half of its room (``room``) about the posture; they require grad."""
    kw = {"dtype": torch.float64}
    a0 = torch.randn(n, harmonics, generator=g, **kw)
    b0 = torch.randn(n, harmonics, generator=g, **kw)
    a0, b0 = constrain_coefficients(a0, b0)
    reach = ((a0.abs() + b0.abs()) / w).sum(-1)  # bound on |q - q0|
    scale = (0.5 * room / reach)[:, None]
    return (a0 * scale).requires_grad_(True), (b0 * scale).requires_grad_(True)


def _run_starts(problem: _Design, plan: _Plan, n_starts: int, harmonics: int, g, room, bar):
    """Optimise ``n_starts`` random starts; returns them ranked, ``[(key, a_raw, b_raw)]``
    (feasible on the coarse grid first, then by the criterion), and each one's criterion."""
    w = 2 * math.pi * problem.f0 * torch.arange(1, harmonics + 1, dtype=torch.float64)
    starts, values = [], []
    for _ in range(n_starts):
        a_raw, b_raw = _random_start(g, problem.model.n_dof, harmonics, w, room)
        problem.scale_into_geometry(a_raw, b_raw)
        crit = math.inf
        steps = [(rho, problem.p) for rho in plan.rounds]
        for rho, p in steps + [(plan.rounds[-1], p) for p in plan.per_start]:
            problem.p = p
            crit = _optimise_round(problem, a_raw, b_raw, rho, plan.optimizer, plan.max_iter, room)
            bar.update(1)
            bar.set_postfix(criterion=f"{crit:.4g}")
        problem.p = plan.start_p
        # the penalty leaves the joint limits slightly exceeded where the criterion pulls:
        # scale the start into them, so the starts are compared (and polished) as they run
        problem.scale_into_joint_limits(a_raw, b_raw)
        values.append(crit)
        # prefer feasible starts on the coarse grid, then the criterion
        key = (_worst_violation(problem, a_raw, b_raw) > 0, crit)
        starts.append((key, a_raw.detach().clone(), b_raw.detach().clone()))
    starts.sort(key=lambda s: s[0])
    return starts, values


def _polish(problem: _Design, plan: _Plan, chosen: list, best, room, bar):
    """Polish the ``chosen`` starts at every exponent of ``plan.polish``; returns the raw
    coefficients kept.

    Kept: the feasible candidate (coarse grid) of lowest exact condition number, the unpolished
    starts included, so the polish never returns a worse condition number than its start;
    ``best`` (the best start) when nothing is polished.
    """
    if chosen:
        best = min(
            ((_condition_key(problem, a, b), a, b) for _, a, b in chosen), key=lambda s: s[0]
        )
    for _, a_start, b_start in chosen:
        a_raw = a_start.clone().requires_grad_(True)
        b_raw = b_start.clone().requires_grad_(True)
        problem.shift = {}  # each polish moves its own targets
        for p in plan.polish:
            problem.p = p
            crit = _optimise_round(
                problem, a_raw, b_raw, plan.rounds[-1], plan.optimizer, plan.polish_iter, room
            )
            problem.update_shift(a_raw, b_raw)
            bar.update(1)
            bar.set_postfix(condition=f"{crit:.4g}")
        problem.scale_into_joint_limits(a_raw, b_raw)
        key = _condition_key(problem, a_raw, b_raw)
        if key < best[0]:
            best = (key, a_raw.detach().clone(), b_raw.detach().clone())
    return best[1], best[2]


def _check_design(
    model, limits, *, criterion, optimizer, harmonics, base_frequency, duration, counts
) -> float:
    """Check `optimize_excitation`'s arguments; returns the base frequency f0, Hz."""
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
    for name, v in counts.items():
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    if counts["n_grid"] < 4 * harmonics:
        raise ValueError(
            f"n_grid ({counts['n_grid']}) must be at least 4 x harmonics ({4 * harmonics})"
        )
    return f0


def _check_exponents(condition_p, criterion: str) -> tuple[float, ...]:
    """``condition_p`` as a tuple of positive floats (at least one for the condition criteria)."""
    try:
        ps = tuple(float(p) for p in condition_p)
    except (TypeError, ValueError):
        raise ValueError(f"condition_p must be positive numbers, got {condition_p!r}") from None
    if not all(p > 0 and not math.isnan(p) for p in ps):
        raise ValueError(f"condition_p must be positive numbers, got {condition_p!r}")
    if not ps and criterion in ("condition", "d+condition"):
        raise ValueError(f"the {criterion!r} criterion needs at least one exponent in condition_p")
    return ps


def _posture(limits: Limits, posture, n: int) -> np.ndarray:
    """``(n,)`` q0: ``posture``, or the middle of the position limits; strictly inside them."""
    lo, hi = limits.position_low, limits.position_high
    q0 = 0.5 * (lo + hi) if posture is None else np.asarray(posture, dtype=np.float64)
    if q0.shape != (n,):
        raise ValueError(f"posture must be {n} numbers (one per joint), got shape {q0.shape}")
    outside = [limits.joint_names[j] for j in range(n) if not lo[j] < q0[j] < hi[j]]
    if outside:
        raise ValueError(
            f"the posture is outside the position limits (margin included) of {outside}"
        )
    return q0


def random_excitation(
    model: RigidBodyModel,
    limits: Limits,
    *,
    base_frequency: float = 0.1,
    harmonics: int = 5,
    rate: float = DEFAULT_RATE,
    seed: int | None = 0,
    posture=None,
    geometry=None,
) -> SinusoidTrajectory:
    """The library's random sum of sinusoids (`torchjfa.sim.random_trajectory`) in the limits.

    The baseline an optimised excitation is compared with: ``min(3, H)`` random harmonics of
    ``base_frequency`` up to ``H``, centred at ``posture`` (default: the middle of the
    position limits), its amplitudes then scaled by the largest factor that keeps every limit
    on the fine grid (10x ``rate``): at most the factor at which one joint's motion spans the
    room the posture leaves it.

    Args:
        posture: ``(n_dof,)`` the centre, e.g. an optimised excitation's posture (which
            clears the floor).
        geometry: the floor and self-collision constraints at ``posture``
            (`torchjfa.excitation._check.trajectory_geometry`; built when needed).

    Returns:
        A `torchjfa.sim.SinusoidTrajectory` in the model's joint order.
    """
    lo, hi = limits.position_low, limits.position_high
    centre = _posture(limits, posture, limits.n_dof)
    room = np.minimum(centre - lo, hi - centre)
    lo, hi = centre - room, centre + room
    if geometry is None and limits.has_geometry:
        geometry = Geometry(model, limits, centre)
    # random_trajectory reads only the joint ranges of the MuJoCo model it is given
    ranges = SimpleNamespace(
        jnt_range=np.stack([lo, hi], 1),
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
    half = 0.5 * (hi - lo)
    high = float(np.min(half / np.abs(q - traj.offset).max(0)))
    return scaled(_largest_feasible_scale(model, scaled, limits, rate, high=high,
                                          geometry=geometry))  # fmt: skip
