"""The optimiser behind `torchjfa.physical.project`: preconditioned LBFGS cycles on phi.

Private: `project` documents the objective, the scaling and the stopping rule.
"""

from __future__ import annotations

import torch
from torch import nn

from .._util import progress_bar, single_thread

__all__ = ["Problem", "minimise", "single_thread", "theta_fn"]


class Problem:
    """The objective of `project` and its normalised form for LBFGS.

    Args:
        theta_hat: ``(d,)`` float64.
        M: ``(d, d)`` the metric.
        ridge, prior_weight: dimensionless weights, multiplied by ``tr(M) / d``.
        prior: ``(d,)`` or None.
        prior_w: ``(d,)`` per-parameter weights of the prior term, or None (all 1).
    """

    def __init__(self, theta_hat, M, ridge, prior, prior_weight, prior_w=None):
        d = theta_hat.shape[0]
        scale = torch.diagonal(M).sum() / d
        self.theta_hat, self.prior, self.M = theta_hat, prior, M
        self.ridge = ridge * scale
        self.weight = prior_weight * scale if prior is not None else 0.0
        # per-parameter weights of the prior term (``(d,)``, mean-diagonal normalised), or 1
        self.prior_w = prior_w if prior is not None and prior_w is not None else None
        with torch.no_grad():
            norm = float(self.objective(torch.zeros_like(theta_hat)))
        self.norm = norm if norm > 0 else float(scale)
        eye = torch.eye(d, dtype=M.dtype, device=M.device)
        w = eye if self.prior_w is None else torch.diag(self.prior_w)
        self.hess = 2.0 * (M + self.ridge * eye + self.weight * w) / self.norm  # of `loss`

    def objective(self, theta: torch.Tensor) -> torch.Tensor:
        """Eq. 8 plus the ridge and prior terms (see `project`), 0-d."""
        delta = theta - self.theta_hat
        f = delta @ (self.M @ delta) + self.ridge * (theta @ theta)
        if self.prior is not None:
            sq = (theta - self.prior) ** 2
            f = f + self.weight * (sq if self.prior_w is None else self.prior_w * sq).sum()
        return f

    @single_thread()  # small matrices: threads only wait on each other
    def minimiser(self) -> torch.Tensor:
        """The objective's minimiser without the consistency constraints, ``(d,)``: the solution
        of ``(M + ridge I + weight W) theta = M theta_hat + weight W prior`` (minimum norm where
        that matrix is singular: no ridge, no prior and a rank-deficient M)."""
        A = 0.5 * self.norm * self.hess
        b = self.M @ self.theta_hat
        if self.prior is not None and self.weight:
            w = 1.0 if self.prior_w is None else self.prior_w
            b = b + self.weight * w * self.prior
        return torch.linalg.pinv(A, rtol=1e-14, hermitian=True) @ b

    def loss(self, theta: torch.Tensor) -> torch.Tensor:
        """The objective divided by its value at theta = 0 (the data term's: the energy of the
        torques theta_hat predicts, plus the prior's)."""
        return self.objective(theta) / self.norm


#: LBFGS iterations between two computations of the preconditioner
_CYCLE = 25
#: the stopping test is relative to max(objective, this fraction of the objective at theta = 0)
_FLOOR = 1e-3
#: damping of the preconditioner, in units of the normalised objective's curvature
_MU = 1e-4


def theta_fn(module: nn.Module):
    """``phi (n_joints * k,) -> theta (n_params,)`` through ``module.theta_from_phi``."""
    shape = module.phi.shape

    def theta_of(phi_flat: torch.Tensor) -> torch.Tensor:
        return module.theta_from_phi(phi_flat.reshape(shape))

    return theta_of


def minimise(module, problem: Problem, *, max_iter: int, tol: float, verbose: bool):
    """Preconditioned LBFGS cycles on ``problem.loss(module(phi))`` from ``module.phi``.

    Stops, converged, when a cycle lowers the loss by less than ``tol * (loss + _FLOOR)`` *and*
    the Newton model at the end predicts no larger decrease (`_predicted_decrease`): a slow
    cycle far from a minimum (a badly scaled problem, or a body creeping to the boundary of the
    consistent set, where log-Cholesky variables run to -inf) is not taken for convergence.

    Returns:
        phi ``(n_joints, k)``, iterations, evaluations, converged (``tol`` met within
        ``max_iter``).
    """
    theta_of = theta_fn(module)
    phi = module.phi.detach().reshape(-1).clone()
    n_joints = module.phi.shape[0]
    n_iter = n_eval = 0
    converged = False
    with torch.no_grad():
        previous = float(problem.loss(theta_of(phi)))
    hessian = _hessian(theta_of, problem, phi, n_joints)
    with progress_bar(total=max_iter, desc="projection", enabled=verbose) as bar:
        while n_iter < max_iter:
            phi, done, evals, finite = _cycle(
                theta_of, problem, phi, min(_CYCLE, max_iter - n_iter), hessian
            )
            n_iter, n_eval = n_iter + done, n_eval + evals
            bar.update(done)
            if not finite:
                break  # the last step overflowed: keep the last finite point, not converged
            with torch.no_grad():
                current = float(problem.loss(theta_of(phi)))
            bar.set_postfix(objective=f"{current * problem.norm:.5e}")
            hessian = _hessian(theta_of, problem, phi, n_joints)  # for the next cycle, too
            small = tol * (abs(current) + _FLOOR)
            if previous - current <= small or done == 0:
                converged = _predicted_decrease(theta_of, problem, phi, hessian) <= small
                if converged or done == 0:
                    break  # done == 0 and not converged: LBFGS is stuck, report it
            previous = current
    return phi.reshape(module.phi.shape), n_iter, n_eval, converged


def _predicted_decrease(theta_of, problem: Problem, phi: torch.Tensor, hessian) -> float:
    """What a Newton step would still gain on the normalised loss at ``phi``:
    ``g^T |H|^-1 g / 2`` (eigenvalues below 1e-12 of the largest are damped to it).

    Unlike the preconditioner's damping (``_MU``, absolute), this one is relative, so that a
    problem whose curvature is tiny everywhere still shows its remaining decrease.
    """
    x = phi.detach().clone().requires_grad_(True)
    (g,) = torch.autograd.grad(problem.loss(theta_of(x)), x)
    if not (bool(torch.isfinite(g).all()) and bool(torch.isfinite(hessian).all())):
        return float("inf")
    evals, evecs = torch.linalg.eigh(0.5 * (hessian + hessian.T))
    curvature = evals.abs() + 1e-12 * float(evals.abs().max()) + 1e-300
    return float(0.5 * ((evecs.T @ g) ** 2 / curvature).sum())


def _cycle(theta_of, problem: Problem, phi: torch.Tensor, iters: int, hessian: torch.Tensor):
    """One LBFGS run of at most ``iters`` iterations in Newton-scaled coordinates from ``phi``
    (``hessian``: the loss's in phi at ``phi``, `_hessian`).

    Returns:
        (phi, iterations, evaluations, finite): phi is the start again when the end point's
        objective is not finite.
    """
    if bool(torch.isfinite(hessian).all()):
        evals, evecs = torch.linalg.eigh(0.5 * (hessian + hessian.T))
        P = (evecs * (evals.abs() + _MU).rsqrt()) @ evecs.T
    else:
        P = torch.eye(phi.numel(), dtype=phi.dtype, device=phi.device)
    psi = torch.zeros_like(phi, requires_grad=True)
    opt = torch.optim.LBFGS(
        [psi],
        lr=1.0,
        max_iter=iters,
        max_eval=3 * iters,
        tolerance_grad=1e-14,
        tolerance_change=1e-16,
        history_size=_CYCLE,
        line_search_fn="strong_wolfe",
    )
    n_eval = 0
    with torch.no_grad():
        worse = 2.0 * abs(float(problem.loss(theta_of(phi)))) + 1.0

    def closure() -> torch.Tensor:
        nonlocal n_eval
        opt.zero_grad()
        loss = problem.loss(theta_of(phi + P @ psi))
        n_eval += 1
        if not bool(torch.isfinite(loss)):
            # a trial step of the line search overflowed (exp in log-Cholesky): report a finite
            # value worse than the start, with zero gradient, so that the line search steps back
            psi.grad = torch.zeros_like(psi)
            return torch.tensor(worse, dtype=phi.dtype, device=phi.device)
        loss.backward()
        return loss

    opt.step(closure)
    done = int(opt.state[psi].get("n_iter", 0))
    new = (phi + P @ psi.detach()).detach()
    with torch.no_grad():
        if not bool(torch.isfinite(problem.loss(theta_of(new)))):
            return phi, done, n_eval, False
    return new, done, n_eval, True


def _hessian(theta_of, problem: Problem, phi: torch.Tensor, n_joints: int) -> torch.Tensor:
    """Hessian of ``problem.loss(theta_of(phi))`` in phi, ``J^T H J + sum_i g_i d2theta_i``.

    theta of a joint depends on that joint's variables only, so the Jacobian J and the second
    term are block diagonal: each is assembled from one backward pass per variable of a joint
    (summed over the joints), with no vmap.
    """
    k = phi.numel() // n_joints
    x = phi.detach().requires_grad_(True)
    theta = theta_of(x)
    per = theta.reshape(n_joints, k)
    jac = phi.new_zeros(n_joints, k, k)
    for i in range(k):
        (row,) = torch.autograd.grad(per[:, i].sum(), x, retain_graph=True)
        jac[:, i, :] = row.reshape(n_joints, k)
    t = theta.detach().requires_grad_(True)
    (g,) = torch.autograd.grad(problem.loss(t), t)
    (v,) = torch.autograd.grad((g * theta).sum(), x, create_graph=True)
    v = v.reshape(n_joints, k)
    second = phi.new_zeros(n_joints, k, k)
    for j in range(k):
        (row,) = torch.autograd.grad(v[:, j].sum(), x, retain_graph=True, allow_unused=True)
        if row is not None:  # None: theta is linear in this variable (an offset)
            second[:, j, :] = row.reshape(n_joints, k)
    J = torch.block_diag(*jac)
    return J.T @ problem.hess @ J + torch.block_diag(*second)
