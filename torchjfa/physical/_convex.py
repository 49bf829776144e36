"""The physically consistent projection as the convex problem it is, solved by a semidefinite
solver: the certificate of `project`'s answer, and a solver of its own.

`project` minimises eq. 8 (plus the ridge and the prior) over a parametrisation of the
consistent set, a non-convex problem in its variables, by LBFGS. In theta the same problem is
convex: a quadratic cost, and per body a linear matrix inequality,

    log-Cholesky:  J(pi) = [[tr(I_o)/2 1 - I_o, h], [h^T, m]]  >= 0   (the pseudo-inertia)
    virtual:       [[I_o, S(h)], [S(h)^T, m 1]]                 >= 0   (m >= 0, I_c >= 0)

(``I_o`` the inertia about the body frame's origin, ``h = m c`` its first moment, ``S`` the
cross-product matrix; the second is eq. 5 by a Schur complement), and friction >= 0 for the
viscous, Coulomb and armature terms. `solve_normalised` hands that problem, in `project`'s
own units, to cvxpy (Clarabel, an interior-point solver), each body strictly inside by
`MARGIN`: its optimum is `project`'s best start (``solver="sdp"``), which LBFGS then polishes.
`project_convex` solves the same problem over the closures (``>= 0``), where `project`'s sets
are open (a positive definite pseudo-inertia): its optimum is a lower bound that the
parametrisation can approach arbitrarily closely, and `certify` compares `project`'s cost with
it (a relative gap of at most 1e-6 certifies the answer to that tolerance).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..dynamics._parameters import pseudo_inertia
from ..dynamics._parametrizations import LogCholeskyParameters
from ._objective import DEFAULT_PARAMETRIZATION, normalised_problem
from ._optimize import Problem

__all__ = ["ConvexProjection", "certify", "project_convex", "solve_normalised"]

#: each body's matrix inequality holds with this margin, in the body's own units (its mass,
#: its radius of gyration), so that the answer is consistent beyond the solver's accuracy; it
#: moves the optimum by about as much, relatively
MARGIN = 1e-8
#: the solvers' settings: Clarabel's gaps and feasibility below its defaults (1e-8), so that
#: the optimum is known well beyond the relative cost `certify` compares at
_SETTINGS = {"CLARABEL": {"tol_gap_rel": 1e-10, "tol_gap_abs": 1e-10, "tol_feas": 1e-10}}
#: the relative gap `certify` accepts by default
CERTIFY_TOL = 1e-6


@dataclass(frozen=True)
class ConvexProjection:
    """What `project_convex` found.

    Attributes:
        theta: ``(n_params,)`` the convex optimum, float64 (on the closure of the consistent set:
            a body may be on its boundary, e.g. a massless one).
        objective: the objective at ``theta`` (eq. 8 plus the ridge and prior terms, in the
            units of `project`'s ``objective``).
        status: the solver's status (``"optimal"`` or ``"optimal_inaccurate"``).
        solver: the solver used.
    """

    theta: torch.Tensor
    objective: float
    status: str
    solver: str


def _cvxpy():
    try:
        import cvxpy
    except ImportError:  # an optional dependency
        raise ImportError(
            "the convex projection needs cvxpy and Clarabel (dependencies of torchjfa): "
            "pip install cvxpy clarabel"
        ) from None
    return cvxpy


def _variable_scales(layout, theta_hat: torch.Tensor, prior, reference=None) -> np.ndarray:
    """``(n_params,)`` the unit of each variable: per body ``m_s`` for the mass, ``m_s L`` for
    the first moments and ``m_s L^2`` for the inertias (``m_s`` the larger of the body's
    estimated and prior mass, ``L`` its radius of gyration), per friction term its size."""
    ref = theta_hat.abs() if prior is None else torch.maximum(theta_hat.abs(), prior.abs())
    if reference is not None:
        ref = torch.maximum(ref, reference.abs())
    inertial, friction = layout.split(ref)
    big = float(ref.max()) if float(ref.max()) > 0 else 1.0
    m_s = inertial[:, 0].clamp_min(1e-6 * big)
    inertia = inertial[:, 4:].amax(-1)
    L = (inertia / m_s).sqrt().clamp(min=1e-3, max=1e3)
    per = torch.stack([m_s, *(m_s * L,) * 3, *(m_s * L * L,) * 6], -1)
    fr = friction.clamp_min(1e-6 * big)
    return layout.join(per, fr).numpy()


def _body_lmis(cp, theta, layout, parametrization: str, scales: torch.Tensor, margin) -> list:
    """One linear matrix inequality per body, on ``theta * scales`` (``theta`` a cvxpy
    variable), each divided by its body's mass unit (the same cone)."""
    constraints = []
    n_bodies = layout.n_joints
    eye10 = torch.eye(10, dtype=torch.float64)
    if parametrization == "log-cholesky":
        basis = pseudo_inertia(eye10).numpy()  # (10, 4, 4): J is linear in pi
    else:
        from ..dynamics._parameters import inertia_about_origin

        inertia = inertia_about_origin(eye10).numpy()  # (10, 3, 3)
        basis = np.zeros((10, 6, 6))
        basis[:, :3, :3] = inertia
        for k in range(10):
            h = eye10[k, 1:4].numpy()
            S = np.array([[0, -h[2], h[1]], [h[2], 0, -h[0]], [-h[1], h[0], 0]])
            basis[k, :3, 3:] = S
            basis[k, 3:, :3] = S.T
            basis[k, 3:, 3:] = eye10[k, 0].item() * np.eye(3)
    index, _ = layout.split(torch.arange(layout.n_params))
    size = basis.shape[-1]
    B = basis.reshape(10, size * size).T  # (size^2, 10): vec(J) = B pi
    for b in range(n_bodies):
        idx = index[b].tolist()
        s = scales[idx].numpy()
        # the congruence diag(1/L, 1/L, 1/L, 1) (or its 6x6 twin) and 1/m_s keep the cone
        L = float(np.sqrt(s[4] / s[0]))
        T = (
            np.diag([1 / L] * 3 + [1.0] * (size - 3))
            if size == 4
            else np.diag([1 / L] * 3 + [1 / L] * 3)
        )
        Bb = (np.kron(T, T) @ B) * (s / s[0])[None, :]
        J = cp.reshape(Bb @ theta[idx], (size, size), order="C")
        # strictly inside, by more than the solver's accuracy (the body in its own units)
        constraints.append(0.5 * (J + J.T) >> margin * np.eye(size))
    return constraints


def solve_quietly(cp, problem, solver: str = "CLARABEL") -> str:
    """Solve the cvxpy ``problem`` with ``solver`` at its `_SETTINGS`, its inaccuracy warnings
    silenced (the status returned says it); ``"solver_error"`` where the solver failed."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=solver, **_SETTINGS.get(solver, {}))
    except cp.error.SolverError:
        return "solver_error"
    return problem.status


def psd_factor(H: np.ndarray) -> np.ndarray:
    """``R`` with ``R^T R`` the positive semidefinite part of the symmetric part of ``H``."""
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    return (V * np.sqrt(np.clip(w, 0.0, None))).T


def _friction_signs(layout) -> list[int]:
    """Indices of theta that are friction or armature terms and must be >= 0."""
    _, friction = layout.split(torch.arange(layout.n_params))
    signed = [k != "offset" for k in layout.friction]
    return [int(i) for row in friction.tolist() for i, s in zip(row, signed, strict=True) if s]


def solve_normalised(
    problem: Problem,
    layout,
    parametrization: str,
    solver: str = "CLARABEL",
    margin: float = MARGIN,
    reference=None,
):
    """The minimiser of ``problem`` (`project`'s normalised objective) over the consistent set
    of ``parametrization`` shrunk by ``margin`` (each body's matrix inequality ``>= margin 1``
    in the body's own units; 0: the closure), ``(theta (d,) float64 on the problem's device,
    solver iterations, solver status)``; the solver works on the CPU.

    Raises:
        ImportError: without cvxpy.
        ValueError: when the solver does not reach an optimum.
    """
    cp = _cvxpy()
    device = problem.theta_hat.device
    theta_hat = problem.theta_hat.cpu()
    prior = None if problem.prior is None else problem.prior.cpu()
    # each body in its own units (its mass and its radius of gyration: the LMIs are invariant
    # under them), each friction term in its own, so that the solver sees O(1) numbers
    reference = None if reference is None else reference.cpu()
    D = torch.from_numpy(_variable_scales(layout, theta_hat, prior, reference))
    y = cp.Variable(layout.n_params)
    x = cp.multiply(D.numpy(), y)
    # the objective is f_min + (x - x*)^T A (x - x*) (x* its unconstrained minimiser, A its
    # Hessian / 2): the solver sees the second term alone, in units of its value at a
    # consistent reference (theta_hat's clip), so that it works with O(1) numbers and no
    # cancellation against f_min
    A = (0.5 * problem.norm * problem.hess).cpu()
    x_star = problem.minimiser().cpu()
    evals, evecs = torch.linalg.eigh(0.5 * (A + A.T))
    factor = (evecs * evals.clamp_min(0).sqrt()).numpy()  # A = F F^T
    with torch.no_grad():
        ref = LogCholeskyParameters.from_theta(theta_hat, layout)()
    g = float((ref - x_star) @ (A @ (ref - x_star)))
    constraints = _body_lmis(cp, y, layout, parametrization, D, margin)
    signs = _friction_signs(layout)
    if signs:
        constraints.append(y[signs] >= 0)
    iters = 0
    # the solver's accuracy is relative to the objective's unit: a second solve in units of
    # the first one's optimum when that is far below the reference's value
    for _ in range(2):
        unit = g if g > 0 else 1.0
        # the norm (a second-order cone), not its square: the interior-point solver then sees
        # the square root of the quadratic's condition number
        cost = cp.norm(factor.T @ (x - x_star.numpy())) / np.sqrt(unit)
        prog = cp.Problem(cp.Minimize(cost), constraints)
        if solve_quietly(cp, prog, solver) == "solver_error":
            raise ValueError(f"the semidefinite solver {solver} failed")
        if prog.status not in ("optimal", "optimal_inaccurate") or y.value is None:
            raise ValueError(f"the semidefinite solver {solver} stopped with status {prog.status}")
        iters += int(getattr(prog.solver_stats, "num_iters", None) or 0)
        g_opt = float(prog.value) ** 2 * unit
        if not 0 < g_opt < 1e-2 * unit:
            break
        g = g_opt
    theta = D * torch.from_numpy(np.asarray(y.value, dtype=np.float64))
    return theta.to(device), iters, str(prog.status)


def project_convex(
    theta_hat,
    *,
    layout,
    moments=None,
    metric=None,
    input_noise=None,
    parametrization: str = DEFAULT_PARAMETRIZATION,
    prior=None,
    prior_weight: float = 0.0,
    prior_scale=None,
    ridge: float = 1e-8,
    solver: str = "CLARABEL",
    margin: float = 0.0,
    reference=None,
) -> ConvexProjection:
    """`project`'s problem (the same arguments and objective) solved as a semidefinite program
    by cvxpy with ``solver`` (`solve_normalised`) over the closure of the consistent set
    (``margin=0``): its optimum is a lower bound of every consistent parameter vector's
    objective, the certificate of `project`'s answer (`certify`). ``reference``: a theta
    ``(n_params,)`` whose sizes set the solver's units beside theta_hat's and the prior's
    (e.g. `project`'s answer; the units change the numbers the solver sees, not the problem).

    Raises:
        ImportError: without cvxpy.
        ValueError: as `project`; or when the solver does not reach an optimum.
    """
    layout, _, problem, unit, m_unit = normalised_problem(
        theta_hat, layout, moments, metric, input_noise, prior, prior_weight, prior_scale, ridge
    )
    if reference is not None:
        reference = torch.as_tensor(reference, dtype=torch.float64) / unit
    theta_n, _, status = solve_normalised(
        problem, layout, parametrization, solver, margin, reference
    )
    objective = float(problem.objective(theta_n)) * unit**2 * m_unit
    return ConvexProjection(theta_n * unit, objective, status, solver)


def certify(result, convex: ConvexProjection, *, tol: float = CERTIFY_TOL) -> tuple[bool, float]:
    """Whether `project`'s ``result`` reaches the convex optimum: ``(ok, gap)`` with ``gap`` its
    objective's excess over the optimum's, relative to the optimum (at most ``tol``)."""
    f = float(result.objective)
    f_star = float(convex.objective)
    gap = (f - f_star) / max(abs(f_star), 1e-300)
    return gap <= tol, gap
