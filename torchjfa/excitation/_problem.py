"""The penalised problem `optimize_excitation` solves, and one optimisation round of it.

`_Design` holds it on a coarse time grid of one period: the raw Fourier coefficients map to
the joint states, the criterion of the information matrix (`torchjfa.excitation._information`)
plus ``rho`` times the limits' quadratic penalty (`_penalty`, aiming `_SAFETY` inside each limit
and moved further in by the adaptive targets of `_Design.update_shift`) is the objective, and
the joint limits are evaluated on a grid `_DENSE` times finer. `_optimise_round` runs LBFGS or
Adam on it for one penalty round; `_condition_key` and `_worst_violation` rank candidates.
"""

from __future__ import annotations

import math

import torch

from ._fourier import constrain_coefficients, fourier_states
from ._information import criterion_value, period_grid, soft_condition, weighted_information
from ._limits import JOINT_KINDS, constraint_violations

#: the joint limits (position, velocity, acceleration: the Fourier series alone, no regressor)
#: are penalised on a grid this many times denser than the criterion's
_DENSE = 10
#: the optimiser aims this far inside each limit (fraction of it) so the fine-grid check holds:
#: torques and workspace boxes, penalised on the coarse grid, where the excess between its
#: points can reach a few per cent; the joint limits on the dense grid, where it is ~100x less
#: (a smooth signal exceeds its grid maximum by at most max|f''| dt^2 / 8)
_SAFETY = {"torque": 0.02, "workspace": 0.02} | dict.fromkeys(JOINT_KINDS, 0.005)
#: each optimised candidate is scaled about the posture until the joint limits hold on the
#: dense grid this far inside them (fraction of the limit; position: of the range), which
#: covers what the signals do between its points (``max|f''| dt^2 / 8`` above the grid's
#: maximum: ~1e-4 of the limit for 10 s, 5 harmonics and the limits of the benchmark)
_EDGE = 1e-3


def _penalty(viol: dict[str, torch.Tensor], shift: dict[str, torch.Tensor]) -> torch.Tensor:
    """The limits' quadratic penalty: each sample's excess over its target, ``_SAFETY`` inside
    the limit, moved further inside by the limit's ``shift`` (`_Design.update_shift`)."""
    return sum(
        (torch.relu(v + _SAFETY[k] + shift.get(k, 0.0)) ** 2).mean(0).sum() for k, v in viol.items()
    )


def _condition_key(problem, a_raw, b_raw) -> tuple[bool, float]:
    """(a limit is violated on the coarse grid, the exact log condition number there)."""
    with torch.no_grad():
        M, viol = problem.evaluate(a_raw, b_raw)
        return (_worst(viol) > 0, float(criterion_value(M, "condition")))


def _worst_violation(problem, a_raw, b_raw) -> float:
    """The largest limit violation (fraction of the limit) on the coarse grid."""
    with torch.no_grad():
        return _worst(problem.evaluate(a_raw, b_raw)[1])


def _worst(viol: dict[str, torch.Tensor]) -> float:
    return max(float(v.max()) for v in viol.values())


class _Design:
    """The optimisation problem of `optimize_excitation` on the coarse grid ``t`` (one period).

    ``states`` maps raw Fourier coefficients ``(n, H)`` to the constrained ones and the joint
    states ``(n_grid, n)``; ``objective`` is the criterion plus ``rho`` times the limits'
    penalty, and the criterion alone. The joint limits are evaluated on a grid `_DENSE` times
    finer than ``t`` (the criterion, torque and workspace limits on ``t``). The criterion is
    `soft_condition` at exponent ``p`` when ``p`` is set, else ``criterion`` (``"d"`` for
    ``"d+condition"``).
    """

    def __init__(self, model, limits, basis, criterion, joint_weights, kin, t, q0, f0) -> None:
        self.model, self.limits, self.basis, self.kin = model, limits, basis, kin
        self.criterion, self.joint_weights = criterion, joint_weights
        self.t, self.f0 = t, f0
        self.t_dense = period_grid(1.0 / f0, _DENSE * len(t))
        self.posture = torch.as_tensor(q0, dtype=torch.float64)
        self.theta = model.nominal_theta
        self.p: float | None = None
        #: per kind of limit, ``(m,)`` how much further inside than ``_SAFETY`` the penalty aims
        self.shift: dict[str, torch.Tensor] = {}

    def states(self, a_raw, b_raw):
        a, b = constrain_coefficients(a_raw, b_raw)
        return a, b, fourier_states(self.t, self.posture, a, b, self.f0)

    def evaluate(self, a_raw, b_raw):
        """``(M, violations)``: the weighted information matrix and the limits' violations
        (`constraint_violations`; torques from the same pass of the regressor as M, joint
        limits on the dense grid)."""
        a, b, (q, qd, qdd) = self.states(a_raw, b_raw)
        Y = self.model.regressor(q, qd, qdd)  # (n_grid, n, P): one pass for M and the torques
        M = weighted_information(Y, self.basis, self.joint_weights)
        viol = constraint_violations(
            self.model, self.limits, q, qd, qdd, tau=Y @ self.theta, kinematics=self.kin,
            kinds=("torque", "workspace"),
        )  # fmt: skip
        dense = fourier_states(self.t_dense, self.posture, a, b, self.f0)
        viol.update(constraint_violations(self.model, self.limits, *dense, kinds=JOINT_KINDS))
        return M, viol

    def joint_usage(self, a, b) -> torch.Tensor:
        """``(n,)`` per joint, the largest fraction of its joint limits (position: the room
        between the posture and each end, less `_EDGE` of the range; velocity, acceleration:
        the limit less `_EDGE` of it) that the motion of coefficients ``a``, ``b`` uses on the
        dense grid (q - q0, qd and qdd are linear in the coefficients)."""
        q, qd, qdd = fourier_states(self.t_dense, self.posture, a, b, self.f0)
        lim = self.limits
        lo, hi = (torch.as_tensor(x, dtype=q.dtype) for x in (lim.position_low, lim.position_high))
        edge = _EDGE * (hi - lo)
        d = q - self.posture
        room = torch.where(d > 0, hi - edge - self.posture, self.posture - lo - edge)
        usage = [d.abs() / room.clamp_min(torch.finfo(q.dtype).tiny)]  # posture at the edge
        for x, bound in ((qd, lim.velocity), (qdd, lim.acceleration)):
            bound = torch.as_tensor(bound, dtype=q.dtype)  # inf where unlimited: usage 0
            usage.append(x.abs() / (bound * (1 - _EDGE)))
        return torch.stack([u.amax(0) for u in usage]).amax(0)

    def joint_scale(self, a_raw, b_raw) -> float:
        """The largest s in [0, 1] for which ``s`` times the motion about the posture holds the
        joint limits on the dense grid, `_EDGE` inside them (closed form: q - q0, qd and qdd
        are linear in the coefficients)."""
        with torch.no_grad():
            used = float(self.joint_usage(*constrain_coefficients(a_raw, b_raw)).max())
        return 1.0 if used <= 1.0 else 1.0 / used  # at rest (used 0) or inside: 1

    def scale_into_joint_limits(self, a_raw, b_raw) -> None:
        """Scale the coefficients (in place) by `joint_scale`."""
        s = self.joint_scale(a_raw, b_raw)
        if s < 1.0:
            with torch.no_grad():
                a_raw.mul_(s)
                b_raw.mul_(s)

    def objective(self, a_raw, b_raw, rho):
        M, viol = self.evaluate(a_raw, b_raw)
        if self.p is not None and math.isinf(self.p):
            crit = criterion_value(M, "condition")
        elif self.p is not None:
            crit = soft_condition(M, self.p)
        else:
            crit = criterion_value(M, "d" if self.criterion == "d+condition" else self.criterion)
        return crit + rho * _penalty(viol, self.shift), crit

    def update_shift(self, a_raw, b_raw) -> None:
        """Move each limit's target by what the motion exceeds it by (at its worst sample).

        The quadratic penalty balances the criterion's pull a little outside its target (the
        polish ended 1-2 % outside the joint limits on the head, which `joint_scale` then
        took back from the whole motion). After each round each limit's (each column's)
        ``shift`` grows by the worst excess over the target, or shrinks (not below 0) by the
        worst room left, so the next round's penalty equilibrium sits at the target: the
        adaptive targets of a method of multipliers, with one multiplier per limit.
        """
        with torch.no_grad():
            _, viol = self.evaluate(a_raw, b_raw)
            for k, v in viol.items():
                old = self.shift.get(k, torch.zeros_like(v[0]))
                self.shift[k] = (old + (v + _SAFETY[k]).amax(0)).clamp(min=0.0)


def _optimise_round(problem: _Design, a_raw, b_raw, rho, optimizer, max_iter, room) -> float:
    """One penalty round on ``a_raw``, ``b_raw`` (in place); returns the criterion at its end."""
    if optimizer == "lbfgs":
        opt = torch.optim.LBFGS(
            [a_raw, b_raw], lr=1.0, max_iter=max_iter, line_search_fn="strong_wolfe"
        )

        def closure():
            opt.zero_grad()
            loss, _ = problem.objective(a_raw, b_raw, rho)
            if torch.isfinite(loss):
                loss.backward()
            return loss

        opt.step(closure)
    else:
        opt = torch.optim.Adam([a_raw, b_raw], lr=0.02 * float(room.mean()))
        for _ in range(max_iter):
            opt.zero_grad()
            loss, _ = problem.objective(a_raw, b_raw, rho)
            loss.backward()
            opt.step()
    with torch.no_grad():
        _, c = problem.objective(a_raw, b_raw, rho)
    return float(c)
