"""Projection of an unconstrained parameter estimate onto physically consistent parameters.

The paper's section III.B: given any estimator's unconstrained theta_hat, find the
consistent theta closest to it in the metric of the data, eq. 8,

    min_phi  (theta(phi) - theta_hat)^T M (theta(phi) - theta_hat),
    M = X^T X + N diag(Psi_x),

where theta(phi) is a parametrisation that is consistent for every phi (`VirtualParameters`, the
paper's eq. 5, or `LogCholeskyParameters`, which adds the triangle inequalities), X^T X and N come
from `torchjfa.Moments` and Psi_x is the per-column input-noise variance (e.g. from Bayesian JFA).
Minimising this metric is the same as minimising the training residual ||y - X theta||^2 over
consistent theta (eq. 6-7), so only the moments are needed, never the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from ..dynamics._consistency import ConsistencyReport, check
from ..dynamics._parametrizations import LogCholeskyParameters, VirtualParameters
from ..stats import Moments
from ._objective import (
    DEFAULT_PARAMETRIZATION,
    check_non_negative,
    normalised_problem,
    objective_terms,
)
from ._optimize import Problem, minimise, single_thread, theta_fn

__all__ = [
    "DEFAULT_PARAMETRIZATION",
    "PARAMETRIZATIONS",
    "ProjectionResult",
    "project",
    "unconstrained_projection",
]

PARAMETRIZATIONS = {"virtual": VirtualParameters, "log-cholesky": LogCholeskyParameters}


@dataclass
class ProjectionResult:
    """What `project` returns.

    Attributes:
        theta: consistent parameters, ``(n_params,)``, in ``theta_hat``'s dtype.
        theta_hat: the unconstrained input, ``(n_params,)``.
        virtual: the fitted parametrisation module (`VirtualParameters` or
            `LogCholeskyParameters`, float64); ``virtual()`` returns ``theta`` in float64.
        parametrization: ``"virtual"`` or ``"log-cholesky"``.
        cost: eq. 8 at the result, ``(theta - theta_hat)^T M (theta - theta_hat)`` (torque^2
            units: how much the training residual sum of squares grows over theta_hat's; inf
            when it exceeds float64's range, e.g. for a theta_hat of 1e300).
        initial_cost: the same for ``from_theta(theta_hat)`` (theta_hat itself when it is
            consistent, otherwise its clipped version), the simple alternative to projecting.
        objective, initial_objective: what was minimised: ``cost`` plus the ridge and prior
            terms (see `project`).
        n_iter: LBFGS iterations (both phases of a warm start); n_eval: evaluations.
        converged: the stopping test on ``tol`` was met within ``max_iter``, and the Newton
            model at the end predicted no larger decrease (a stall is not convergence).
        grad_max: largest absolute gradient of the normalised objective in phi at the end.
        relative_change: ``(n_joints,)`` ``||theta_j - theta_hat_j|| / ||theta_hat_j||`` over each
            joint's parameters (inertial and friction; mixed units, a rough measure).
        mass_change: ``(n_joints,)`` kg.
        before, after: `check` reports of theta_hat and theta.
    """

    theta: torch.Tensor
    theta_hat: torch.Tensor
    virtual: nn.Module
    parametrization: str
    cost: float
    initial_cost: float
    objective: float
    initial_objective: float
    n_iter: int
    n_eval: int
    converged: bool
    grad_max: float
    relative_change: torch.Tensor
    mass_change: torch.Tensor
    before: ConsistencyReport = field(repr=False)
    after: ConsistencyReport = field(repr=False)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.after.joint_names

    def moved(self, threshold: float = 1e-6) -> tuple[str, ...]:
        """Joints whose parameters changed by more than ``threshold`` (relative)."""
        return tuple(
            n
            for n, r in zip(self.joint_names, self.relative_change.tolist(), strict=False)
            if r > threshold
        )

    def table(self) -> str:
        """A readable report: one row per body, then the optimisation summary."""
        head = (
            f"{'joint':<16} {'mass in':>10} {'mass out':>10} {'rel. change':>12} "
            f"{'in ok':>6} {'out ok':>6}"
        )
        lines = [f"projection ({self.parametrization})", head, "-" * len(head)]
        ok_in = self.before.body_ok
        ok_out = self.after.body_ok
        for j, name in enumerate(self.joint_names):
            lines.append(
                f"{name[:16]:<16} {float(self.before.mass[j]):>10.4g} "
                f"{float(self.after.mass[j]):>10.4g} {float(self.relative_change[j]):>12.3g} "
                f"{'yes' if bool(ok_in[j]) else 'no':>6} {'yes' if bool(ok_out[j]) else 'no':>6}"
            )
        lines.append(
            f"cost (eq. 8) {self.initial_cost:.6g} -> {self.cost:.6g}; objective "
            f"{self.initial_objective:.6g} -> {self.objective:.6g}; {self.n_iter} iterations, "
            f"{self.n_eval} evaluations, {'converged' if self.converged else 'NOT converged'} "
            f"(max |grad| {self.grad_max:.2g})"
        )
        lines.append(
            f"fully consistent: {'yes' if self.after.ok else 'no'}; mass, I_c and friction: "
            f"{'yes' if self.after.weakly_ok else 'no'}"
        )
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


@single_thread()  # ~100 x 100 matrices: the answer then does not depend on the caller's threads
def project(
    theta_hat,
    *,
    layout,
    moments: Moments | None = None,
    metric=None,
    input_noise=None,
    parametrization: str = DEFAULT_PARAMETRIZATION,
    prior=None,
    prior_weight: float = 0.0,
    prior_scale=None,
    ridge: float = 1e-8,
    max_iter: int = 1000,
    tol: float = 1e-5,
    warm_start: bool = True,
    verbose: bool = False,
    solver: str = "sdp",
) -> ProjectionResult:
    """Physically consistent parameters closest to ``theta_hat`` in the data's metric (eq. 8).

    Minimises, over the free variables phi of the chosen parametrisation (theta = theta(phi)),

        (theta - theta_hat)^T M (theta - theta_hat)             eq. 8: the increase of the
                                                                  training residual sum of squares
            + ridge * s * ||theta||^2                            tie-break in the null space of M
            + prior_weight * s * ||theta - prior||^2             optional pull to nominal values
              (with ``prior_scale`` p: prior_weight * s_p * sum_k ((theta_k - prior_k) / p_k)^2)

    with ``M = X^T X + N diag(input_noise)`` from ``moments`` (or ``M = metric``) and
    ``s = tr(M) / n_params``, by ``torch.optim.LBFGS`` with a strong-Wolfe line search.

    Scaling and the null space. ``s`` (the mean diagonal of M) makes ``ridge`` and
    ``prior_weight`` dimensionless: ``prior_weight=1`` weighs each parameter's distance to the
    prior like the data weigh an average parameter. M is singular for every real robot
    (unidentifiable parameter combinations); the tiny default ridge makes the problem well posed
    by preferring, among consistent parameters that fit the data equally well, small ones. It
    pulls towards 0 rather than towards theta_hat on purpose: an unregularised estimate on poor
    data has huge components along weakly excited directions, which a pull towards theta_hat
    would force the consistent parameters to imitate. Parameters the data do not excite thus
    end small (an unexcited mass can end near 0), and are determined only loosely (the ridge is
    1e-8 of the data's weight, below the stopping test's resolution). A ``prior`` (CAD values)
    is the better way to pin what the data do not determine.

    The description as a prior. With ``prior_scale`` (``(n_params,)`` positive, in each
    parameter's units, e.g. `parameter_scales` of the description: a typical mass, first
    moment, inertia), the prior term is ``prior_weight * s_p * sum_k ((theta_k - prior_k) /
    p_k)^2`` with ``s_p = sum_k p_k^2 M_kk / n_params``, the data's mean weight of a change of
    one physical scale: every parameter is pulled towards the description in units of its
    kind, and ``prior_weight=1`` weighs a deviation of one physical scale like the data weigh
    an average one. Along directions the data determine (eigenvalues of ``P M P`` far above
    ``prior_weight * s_p``) the solution moves only by O(prior_weight * s_p / eigenvalue);
    along the null space the prior decides. The term scales like eq. 8 under theta_hat,
    prior, prior_scale -> c (...), so the projection stays scale-equivariant;
    ``prior_scale`` of all ones is the plain prior term above. A theta_hat that is already
    consistent (exactly representable by the parametrisation) minimises eq. 8 and is returned
    unchanged when no prior is given.

    Scale. Eq. 8 and the consistent set are invariant under theta -> s theta (s > 0): the
    problem is solved in units where theta_hat's size as the data see it,
    ``sqrt(theta_hat^T M theta_hat / tr(M))``, and M's mean diagonal are 1, and the answer is
    scaled back, so the projection of ``s * theta_hat`` is ``s`` times that of theta_hat for
    any s (masses of 1e-3 kg or 1e12 kg alike; ``cost`` scales with s^2).

    Optimisation. LBFGS sees the objective divided by its value at theta = 0 and runs in cycles
    of 25 iterations, each in coordinates ``phi = phi_start + P psi`` with
    ``P = (|H| + 1e-4)^(-1/2)``, H the Hessian in phi at the cycle's start (absolute
    eigenvalues), so that every direction has a curvature near 1 however ill-conditioned M is.
    It stops when a cycle lowers the objective by less than ``tol`` times the larger of the
    objective and 1e-3 of its value at theta = 0 and the Newton model at its end predicts no larger
    decrease, or after ``max_iter`` iterations (then ``converged`` is False). The
    optimisation runs with one torch thread (the setting is restored afterwards): on matrices
    this small, BLAS threads only add synchronisation, which slows each product down many
    times where other work shares the cores.

    Starting point. The objective in phi is not convex (eq. 5 has stationary points where a
    body's mass is 0: the gradient with respect to its centre of mass vanishes there), so the
    start matters. Candidates: ``from_theta(theta_hat)`` (theta_hat with masses, inertias and
    friction clipped); the same for theta_hat without its components along directions the data
    barely excite (eigenvalues of the column-scaled M below 1e-8 of the largest: an
    unregularised estimate can be huge there); the module's default body (1 kg, 0.01 kg m^2);
    for ``"log-cholesky"`` the pseudo-inertia clip of the eq.-5 clip; for ``"virtual"`` with
    ``warm_start`` the log-Cholesky projection (fully consistent, a subset of eq. 5's set); and
    the prior. LBFGS starts from the one with the lowest objective.

    Args:
        theta_hat: unconstrained estimate, shape ``(n_params,)`` (or a fitted estimator with a
            ``coef_`` attribute).
        layout: a `ParameterLayout` or an object with ``.layout`` (a robot model).
        moments: `torchjfa.Moments` of the regressor rows (``xtx`` and ``n`` are used).
        metric: the matrix M, ``(n_params, n_params)`` symmetric PSD, instead of ``moments``.
        input_noise: per-column input-noise variance, scalar or ``(n_params,)`` (only with
            ``moments``), in the squared units of the regressor columns.
        parametrization: ``"log-cholesky"`` (`DEFAULT_PARAMETRIZATION`: positive definite
            pseudo-inertia, so the triangle inequalities hold too) or ``"virtual"`` (eq. 5:
            mass >= 0, PSD inertia at the centre of mass, friction >= 0).
        prior: nominal (e.g. CAD) parameters, ``(n_params,)``; needs ``prior_weight > 0``.
        prior_weight: weight of the prior term, dimensionless (see above).
        prior_scale: ``(n_params,)`` positive per-parameter scales of the prior term (see
            above), or None (the same weight for every parameter).
        ridge: weight of the tie-break term, dimensionless, >= 0.
        max_iter: largest number of LBFGS iterations (per phase with the warm start).
        tol: relative decrease of the objective over one cycle of 25 iterations below which
            the optimisation stops (see above).
        warm_start: for ``"virtual"``, try the log-Cholesky projection as a start (about twice
            the work, usually a lower cost).
        verbose: show a progress bar and print the result table.
        solver: ``"sdp"``: the problem is first solved as the convex program it is in theta
            (a quadratic cost, a linear matrix inequality per body, each body strictly inside
            by a margin of 1e-8 of its own size: `torchjfa.physical.project_convex`) by a
            semidefinite solver (cvxpy with Clarabel), and that global optimum is one more
            start for LBFGS, which then polishes it in the parametrisation; the description's
            values where the data are silent come from there (LBFGS alone can stall at a
            vanishing mass). The interior-point method's accuracy is relative to the units
            it works in, so the program is solved again in the units of LBFGS's answer (an
            optimum far from theta_hat's sizes, a barely excited body's, is out of the first
            solve's reach) and polished again while that finds a lower point, up to four
            rounds: the answer stands when the program in its own units finds nothing lower.
            ``"lbfgs"``: the starts above only (a local optimum of a non-convex problem).
            `torchjfa.physical.certify` compares the result with the convex optimum.

    Returns:
        A `ProjectionResult`: ``.theta`` (consistent), ``.virtual`` (the fitted module), the
        cost before and after, iterations, convergence, per-body changes and consistency
        reports; ``print(result)`` shows them.

    Raises:
        ValueError: on shapes that do not match the layout, NaN, a metric that is not PSD,
            both or neither of ``moments`` and ``metric``, negative weights or an unknown
            parametrisation.
        TypeError: if ``moments`` is not a `Moments` or ``layout`` has no `ParameterLayout`.

    Example:
        >>> moments = model.moments(q, qd, qdd, tau)                           # doctest: +SKIP
        >>> theta_hat = OLS(fit_intercept=False).fit_moments(moments).coef_     # doctest: +SKIP
        >>> result = project(theta_hat, layout=model, moments=moments)          # doctest: +SKIP
        >>> print(result)                                                       # doctest: +SKIP
    """
    _check_options(
        parametrization, ridge=ridge, prior_weight=prior_weight, tol=tol, max_iter=max_iter
    )
    if solver not in ("sdp", "lbfgs"):
        raise ValueError(f"solver must be 'sdp' or 'lbfgs', got {solver!r}")
    # solved in units where theta_hat and M are O(1), then scaled back (`normalised_problem`)
    layout, theta_hat, problem, unit, m_unit = normalised_problem(
        theta_hat, layout, moments, metric, input_noise, prior, prior_weight, prior_scale, ridge
    )

    cls = PARAMETRIZATIONS[parametrization]
    start = None
    if solver == "sdp" and not _consistent_as_given(cls, layout, problem):
        from ._convex import solve_normalised

        try:
            optimum, _, _ = solve_normalised(problem, layout, parametrization)
            start = cls.from_theta(optimum, layout)  # inside the set by the solver's margin
        except ValueError:  # the solver did not reach an optimum: the other starts remain
            start = None
    solve = {"warm_start": warm_start, "max_iter": int(max_iter), "tol": float(tol)}
    fitted, n_iter, n_eval, converged = _solve(
        cls, layout, problem, **solve, verbose=verbose, start=start
    )
    for _ in range(_SDP_ROUNDS if solver == "sdp" else 0):
        if _consistent_as_given(cls, layout, problem):
            break
        with torch.no_grad():
            before = float(problem.loss(fitted()))
        fitted, more = _rescaled_sdp(cls, layout, problem, parametrization, fitted, solve)
        n_iter, n_eval = n_iter + more[0], n_eval + more[1]
        if more[2] is None:  # the program in the answer's units finds nothing lower
            break
        converged = more[2]
        with torch.no_grad():
            if float(problem.loss(fitted())) > before * (1.0 - _ROUND_GAIN):
                break  # a gain far below the certificate's tolerance: no further round
    result = _result(
        cls,
        fitted,
        problem,
        layout,
        theta_hat,
        unit=unit,
        m_unit=m_unit,
        parametrization=parametrization,
        stats=(n_iter, n_eval, converged),
    )
    if verbose:
        print(result.table())
    return result


def unconstrained_projection(
    theta_hat,
    *,
    layout,
    moments: Moments | None = None,
    metric=None,
    input_noise=None,
    prior=None,
    prior_weight: float = 0.0,
    prior_scale=None,
    ridge: float = 1e-8,
) -> torch.Tensor:
    """`project`'s objective minimised WITHOUT the consistency constraints, in closed form.

    The same objective as `project` (eq. 8 in the metric ``X^T X + N diag(input_noise)``, the
    ridge and the prior terms, with the same arguments and scalings), whose minimiser over all
    of R^d solves one linear system: ``(M + r I + w W) theta = M theta_hat + w W prior``. It is
    the posterior mean of a Gaussian prior on theta (the prior term) with the data's Gaussian
    likelihood (eq. 8), and costs one ``d x d`` pseudo-inverse where `project` runs LBFGS: the
    description prior's weight is chosen with it (`torchjfa.identification.make_consistent`,
    ``description_prior="auto"``).

    Args:
        theta_hat: as for `project`.
        layout: as for `project`.
        moments: as for `project`.
        metric: as for `project`.
        input_noise: as for `project`.
        prior: as for `project`.
        prior_weight: as for `project`.
        prior_scale: as for `project`.
        ridge: as for `project`.

    Returns:
        ``(n_params,)`` float64 on theta_hat's device (not necessarily consistent).
    """
    check_non_negative(ridge=ridge, prior_weight=prior_weight)
    layout, theta_hat, M, prior, prior_w, m_unit = objective_terms(
        theta_hat, layout, moments, metric, input_noise, prior, prior_weight, prior_scale
    )
    th = theta_hat.to(torch.float64)
    return Problem(th, M / m_unit, float(ridge), prior, float(prior_weight), prior_w).minimiser()


def _check_options(parametrization: str, *, ridge, prior_weight, tol, max_iter) -> None:
    """ValueError on an unknown parametrisation, negative weights or tol, ``max_iter < 1``."""
    if parametrization not in PARAMETRIZATIONS:
        raise ValueError(
            f"parametrization must be one of {tuple(PARAMETRIZATIONS)}, got {parametrization!r}"
        )
    check_non_negative(ridge=ridge, prior_weight=prior_weight, tol=tol)
    if int(max_iter) < 1:
        raise ValueError(f"max_iter must be at least 1, got {max_iter}")


def _result(
    cls, fitted, problem: Problem, layout, theta_hat, *, unit, m_unit, parametrization, stats
) -> ProjectionResult:
    """The `ProjectionResult` of a module fitted to the normalised ``problem``.

    Args:
        unit, m_unit: the scales of theta and of M that `project` divided out.
        stats: ``(n_iter, n_eval, converged)`` of the fit.
    """
    n_iter, n_eval, converged = stats
    th = theta_hat.to(torch.float64)
    th_n, M_n = problem.theta_hat, problem.M
    phi = fitted.phi.detach()
    with torch.no_grad():
        theta0_n = cls.from_theta(th_n, layout)()
        theta_n = fitted()
    phi_end = phi.reshape(-1).clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(problem.loss(theta_fn(fitted)(phi_end)), phi_end)
    fitted = cls(layout, phi=fitted._scaled_phi(unit))  # back in theta_hat's units
    with torch.no_grad():
        theta64 = fitted()
    # eq. 8 and the objective scale with unit^2 m_unit (inf beyond float64's range, 1.8e308)
    to_units = unit * unit * m_unit

    inertial_hat, _ = layout.split(th)
    per_hat = th.reshape(layout.n_joints, -1)
    per_new = theta64.reshape(layout.n_joints, -1)
    denom = per_hat.norm(dim=-1)
    rel = (per_new - per_hat).norm(dim=-1) / torch.where(denom > 0, denom, torch.ones_like(denom))
    return ProjectionResult(
        theta=theta64.to(theta_hat.dtype),
        theta_hat=theta_hat,
        virtual=fitted,
        parametrization=parametrization,
        cost=_eq8(theta_n, th_n, M_n) * to_units,
        initial_cost=_eq8(theta0_n, th_n, M_n) * to_units,
        objective=float(problem.objective(theta_n)) * to_units,
        initial_objective=float(problem.objective(theta0_n)) * to_units,
        n_iter=n_iter,
        n_eval=n_eval,
        converged=converged,
        grad_max=float(grad.abs().max()),
        relative_change=rel,
        mass_change=per_new[:, 0] - inertial_hat[:, 0],
        before=check(th, layout),
        after=check(theta64, layout),
    )


def _consistent_as_given(cls, layout, problem: Problem) -> bool:
    """Whether theta_hat is consistent (the module represents it) and no prior pulls: then it
    minimises eq. 8 and is the answer (`_solve` returns it at once)."""
    if problem.prior is not None:
        return False
    th = problem.theta_hat
    with torch.no_grad():
        return bool(torch.allclose(cls.from_theta(th, layout)(), th, rtol=1e-12, atol=1e-14))


def _solve(cls, layout, problem: Problem, *, warm_start, max_iter, tol, verbose, start=None):
    """Fit a ``cls`` module; returns (module, iterations, evaluations, converged). ``start``: one
    more candidate start (the convex optimum)."""
    th = problem.theta_hat
    exact = cls.from_theta(th, layout)
    with torch.no_grad():
        representable = bool(torch.allclose(exact(), th, rtol=1e-12, atol=1e-14))
    if representable and problem.prior is None:
        return exact, 0, 0, True  # theta_hat is consistent: it minimises eq. 8
    # starting points: theta_hat made consistent by clipping, and the alternatives below; the
    # one with the lowest objective wins
    starts = [exact, cls(layout), cls.from_theta(_truncated(th, problem.M), layout)]
    if cls is LogCholeskyParameters:
        with torch.no_grad():
            clipped = VirtualParameters.from_theta(th, layout)()
        starts.append(cls.from_theta(clipped, layout))
    n_iter = n_eval = 0
    if cls is VirtualParameters and warm_start and not representable:
        fully, n_iter, n_eval, _ = _solve(
            LogCholeskyParameters,
            layout,
            problem,
            warm_start=False,
            max_iter=max_iter,
            tol=tol,
            verbose=verbose,
        )
        with torch.no_grad():
            starts.append(cls.from_theta(fully(), layout))
    if problem.prior is not None:
        starts.append(cls.from_theta(problem.prior, layout))
    if start is not None:
        starts.append(start)
    with torch.no_grad():
        losses = [float(problem.loss(m())) for m in starts]
    finite = [(v, i) for i, v in enumerate(losses) if v == v and v != float("inf")]
    module = starts[min(finite)[1]] if finite else exact
    phi, k, e, converged = minimise(module, problem, max_iter=max_iter, tol=tol, verbose=verbose)
    return cls(layout, phi=phi), n_iter + k, n_eval + e, converged


#: how much lower (in the normalised loss, O(1)) the second solve's answer must be to replace
#: the first: above round-off, far below the certificate's 1e-6
_LOWER = 1e-10
#: the most rounds of "semidefinite program in the units of the answer, then LBFGS from its
#: optimum": each round's program sees the optimum more sharply (the interior-point method's
#: accuracy is relative to its units), and the rounds stop when it finds nothing lower
_SDP_ROUNDS = 4
#: a round that lowers the loss by less than this fraction is the last (1 % of the
#: certificate's 1e-6: further rounds would follow round-off, not the optimum)
_ROUND_GAIN = 1e-8


def _rescaled_sdp(cls, layout, problem: Problem, parametrization: str, fitted, solve: dict):
    """The semidefinite program once more, its variables in the units of LBFGS's answer.

    The first solve takes each body's units from theta_hat and the prior; where the optimum
    lies far from them (a body the data barely reach, whose mass runs to thousands of times
    theta_hat's) the interior-point method stops short of it. In units of ``fitted``'s theta
    it reaches it; when that optimum is lower, LBFGS polishes from it and the better of the
    two is kept. Returns ``(module, (iterations, evaluations, converged or None))``."""
    from ._convex import solve_normalised

    with torch.no_grad():
        theta = fitted()
    try:
        optimum, _, _ = solve_normalised(problem, layout, parametrization, reference=theta)
    except ValueError:
        return fitted, (0, 0, None)
    # lower by more than round-off (the loss is O(1)): otherwise the first answer stands, so
    # that the directions the data leave free do not follow round-off from run to run
    if not float(problem.loss(optimum)) < float(problem.loss(theta)) - _LOWER:
        return fitted, (0, 0, None)
    polished, k, e, converged = _solve(
        cls, layout, problem, **solve, verbose=False, start=cls.from_theta(optimum, layout)
    )
    with torch.no_grad():
        better = float(problem.loss(polished())) < float(problem.loss(theta)) - _LOWER
    return (polished, (k, e, converged)) if better else (fitted, (k, e, None))


def _truncated(theta_hat: torch.Tensor, M: torch.Tensor, rcond: float = 1e-8) -> torch.Tensor:
    """theta_hat without its components along directions the data barely excite.

    In the column-scaled metric ``C = D^-1/2 M D^-1/2`` (``D = diag M``), the components along
    eigenvectors with eigenvalue below ``rcond`` times the largest are removed. An
    unregularised estimate on poorly exciting data can be huge along those directions (they
    cost almost nothing in eq. 8); clipping such an estimate gives an absurd start.
    """
    scale = torch.diagonal(M).clamp_min(0).sqrt()
    scale = torch.where(scale > 0, scale, torch.ones_like(scale))
    C = M / torch.outer(scale, scale)
    evals, evecs = torch.linalg.eigh(0.5 * (C + C.T))
    keep = evecs[:, evals > rcond * evals[-1]]
    return (keep @ (keep.T @ (theta_hat * scale))) / scale


def _eq8(theta: torch.Tensor, theta_hat: torch.Tensor, M: torch.Tensor) -> float:
    delta = theta - theta_hat
    return float(delta @ (M @ delta))
