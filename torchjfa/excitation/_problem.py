"""The penalised problem `optimize_excitation` solves, and one optimisation round of it.

`_Design` holds it on a coarse time grid of one period: the raw Fourier coefficients map to
the joint states, the criterion of the information matrix (`torchjfa.excitation._information`)
plus ``rho`` times the limits' quadratic penalty (`_penalty`, aiming `_SAFETY` inside each limit
and moved further in by the adaptive targets of `_Design.update_shift`) is the objective, and
the joint limits are evaluated on a grid `_DENSE` times finer. `_optimise_round` runs LBFGS or
Adam on it for one penalty round; `_condition_key` and `_worst_violation` rank candidates;
`repair_geometry` adds cuts where the description's collision geometry came closer than the
capsules (`torchjfa.excitation._geometry`) allowed, and optimises again.
"""

from __future__ import annotations

import math

import torch

from ._fourier import constrain_coefficients, fourier_states
from ._information import criterion_value, period_grid, soft_condition, weighted_information
from ._limits import GEOMETRY_KINDS, JOINT_KINDS, constraint_violations

#: the joint limits (position, velocity, acceleration: the Fourier series alone, no regressor)
#: are penalised on a grid this many times denser than the criterion's
_DENSE = 10
#: the optimiser aims this far inside each limit (fraction of it) so the fine-grid check holds:
#: torques and workspace boxes, penalised on the coarse grid, where the excess between its
#: points can reach a few per cent; the joint limits on the dense grid, where it is ~100x less
#: (a smooth signal exceeds its grid maximum by at most max|f''| dt^2 / 8)
_SAFETY = {"torque": 0.02, "workspace": 0.02} | dict.fromkeys(JOINT_KINDS, 0.005)
#: m: the floor and self-collision distances (metres) are penalised in units of this length,
#: and aim `_SAFETY` of it (5 mm) beyond the clearance: on the coarse grid a point of the arm
#: moving at 10 m/s^2 exceeds its grid extreme by ~3 mm (max|f''| dt^2 / 8, dt = 50 ms)
_LENGTH = 0.01
_SAFETY |= dict.fromkeys(GEOMETRY_KINDS, 0.5)
#: rounds of `repair_geometry` at most
_REPAIRS = 5
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
        #: the floor and self-collision constraints (`torchjfa.excitation._geometry.Geometry`)
        self.geometry = None
        self.p: float | None = None
        #: per kind of limit, ``(m,)`` how much further inside than ``_SAFETY`` the penalty aims
        self.shift: dict[str, torch.Tensor] = {}

    def states(self, a_raw, b_raw):
        a, b = constrain_coefficients(a_raw, b_raw)
        return a, b, fourier_states(self.t, self.posture, a, b, self.f0)

    def evaluate(self, a_raw, b_raw):
        """``(M, violations)``: the weighted information matrix and the limits' violations
        (`constraint_violations`; torques from the same pass of the regressor as M, joint
        limits on the dense grid, floor and self-collision of the capsules in units of
        `_LENGTH`)."""
        a, b, (q, qd, qdd) = self.states(a_raw, b_raw)
        Y = self.model.regressor(q, qd, qdd)  # (n_grid, n, P): one pass for M and the torques
        M = weighted_information(Y, self.basis, self.joint_weights)
        viol = constraint_violations(
            self.model, self.limits, q, qd, qdd, tau=Y @ self.theta, kinematics=self.kin,
            geometry=self.geometry, kinds=("torque", "workspace", *GEOMETRY_KINDS),
        )  # fmt: skip
        for k in GEOMETRY_KINDS:
            if k in viol:
                viol[k] = viol[k] / _LENGTH
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

    def scale_into_geometry(self, a_raw, b_raw, steps: int = 12) -> None:
        """Scale the coefficients (in place) about the posture by the largest factor in
        [0.001, 1] (bisection) at which the floor and self-collision hold on the coarse grid,
        with the penalty's safety (or half the room the posture leaves, where that is less): a
        random start that swings the arm through the floor starts inside instead."""
        if self.geometry is None:
            return

        with torch.no_grad():
            # per column, the target: the penalty's safety inside, or half the room the
            # posture leaves where that is less (parts close by design)
            at_rest = self.geometry.violations(self.posture[None])
            aim = {k: torch.clamp(0.5 * v[0], min=-_SAFETY[k] * _LENGTH)
                   for k, v in at_rest.items()}  # fmt: skip

            def ok(s: float) -> bool:
                a, b = constrain_coefficients(s * a_raw, s * b_raw)
                q = fourier_states(self.t, self.posture, a, b, self.f0)[0]
                v = self.geometry.violations(q)
                return all(bool((x.amax(0) <= aim[k]).all()) for k, x in v.items())

            if ok(1.0):
                return
            lo, hi = 0.0, 1.0
            for _ in range(steps):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if ok(mid) else (lo, mid)
            s = max(lo, 1e-3)  # never all at rest: the criterion needs motion
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


def repair_geometry(problem: _Design, a_raw, b_raw, rho, optimizer, max_iter, room) -> int:
    """Where the collision geometry comes closer than it may, add a cut there and optimise
    again (in place); returns the number of cuts added.

    The capsules are the optimiser's stand-in for the description's collision geometry
    (`torchjfa.excitation._meshes`): a pair of bodies can come closer than their capsules
    suggest (a wrist turning its non-round shape towards the forearm). Up to `_REPAIRS` times,
    the motion is checked with MuJoCo on the dense grid; for each pair of bodies closer than
    required, the two closest points of its geometry at its worst sample, fixed to their
    bodies, must keep the required distance (plus the penalty's safety) in the optimiser
    (`Geometry.add_witness`; the surfaces are never farther apart than two of their points, so
    the cut holds at the posture), and one more penalty round runs, then the joint-limit
    scaling.
    """
    geo = problem.geometry
    if geo is None or geo.meshes is None or "collision" not in geo.meshes.kinds:
        return 0
    root = problem.model.frame_names[0]
    need = geo.meshes.required("collision")
    added = 0
    for _ in range(_REPAIRS):
        with torch.no_grad():
            a, b = constrain_coefficients(a_raw, b_raw)
            q = fourier_states(problem.t_dense, problem.posture, a, b, problem.f0)[0]
            worst, at = geo.meshes.violations(q)["collision"].max(0)
        bad = torch.nonzero(worst > 0).flatten().tolist()
        for c in bad:
            w = geo.meshes.witness(q[at[c]].numpy(), c)
            if w is not None:
                fa, pa, fb, pb = w
                geo.add_witness(fa or root, pa, fb or root, pb,
                                need[c] + _SAFETY["collision"] * _LENGTH)  # fmt: skip
                added += 1
        if not bad:
            break
        old = problem.shift.get("collision")
        if old is not None:  # the new cuts' targets start unmoved
            problem.shift["collision"] = torch.cat([old, old.new_zeros(added - _extra(old, geo))])
        _optimise_round(problem, a_raw, b_raw, rho, optimizer, max_iter, room)
        problem.scale_into_joint_limits(a_raw, b_raw)
    return added


def _extra(shift: torch.Tensor, geo) -> int:
    """How many of the cuts (`Geometry.add_witness`) ``shift`` already has targets for."""
    return shift.numel() - len(geo.capsules.pairs)
