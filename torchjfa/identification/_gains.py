"""`identify_drive_gains`: per-joint drive gains (N m/A), or torque scales, from a payload of
known mass.

A motor current ``i_j`` gives the joint torque ``K_j i_j`` through a drive gain that is rarely
known well; identification from currents alone cannot find it, since scaling a joint's gain and
every parameter leaves the equations unchanged. A payload of known mass ``M`` fixes that scale
(Gautier and Briot, *Global identification of joint drive gains and dynamic parameters of
robots*, 2014): with logs read at nominal gains ``K0`` (``u = K0 i``, the ``tau`` of the read
logs), the model is, per joint ``j``,

    unloaded runs:  s_j u_j = Y_j theta
    loaded runs:    s_j u_j = Y_j theta + Z_j pi,    pi = (M, h, I_o) with M known

linear in ``x = (theta, pi, s)``, the gains ``K = s K0``. The robot's parameters ``theta`` are
fitted again with the gains (the identified model gives the structure, the units and a tie-break
for what the data leave free), the payload's centre of mass and inertia are unknown, and every
body (the payload's too) keeps a positive semidefinite pseudo-inertia, friction >= 0 and
``s > 0`` (matrix inequalities, solved by cvxpy with Clarabel).

Least squares on the equation error ``s_j u_j - Y_j theta - ...`` would weigh joint ``j`` by
``s_j^2`` and so prefer small gains: shrinking a joint's gain with the parameters only its own
row sees shrinks that residual. The measured quantity is the current, whose error is
``u_j - (Y_j theta + Z_j pi) / s_j``; the fit minimises that error, each joint weighed by its
residual level, over ``(theta, pi, g = 1 / s)`` by damped Gauss-Newton steps: the error is
bilinear in the parameters and ``g``, so each step linearises it about the last point and
solves the semidefinite program with a Levenberg-Marquardt damping on ``g``, until the gains
stop moving (alternating between the two blocks crawls along the valley where a gain and its
own row's parameters trade off).
Along a direction the logs leave free (a joint's gain with the parameters only its own row
sees) the error is flat, and the tie-break keeps the identified robot's values there.

Spreads come from a delete-one-block jackknife over contiguous blocks of the logs (filtered
rows are correlated, so least-squares formulas on rows understate them); a gain whose relative
spread exceeds `DETERMINED_SPREAD` is reported as not determined by the logs.

The flow's shared stages serve where the fit allows: the normal matrices come from
`stream_moments` (each joint's `Moments` of the robot's regressor and the logged signal per
contiguous block, of which the rows ``(-Y_j, -Z_j, u_j e_j)`` are a linear map:
`_normal_matrices`), the joint weights from `inverse_variance_weights` (``options.weighting``:
``"residual"``, with the floor `JOINT_WEIGHT_FLOOR` of `identify`'s weights, or ``"none"``),
the spreads from the one jackknife formula (`jackknife_std`, beside
`torchjfa.estimators.jackknife`) over ``options.jackknife`` blocks. ``options.estimator`` does
not apply: the fit is a damped Gauss-Newton of semidefinite programs on the current error,
bilinear in the parameters and the gains, not a linear regression that a
`torchjfa.estimators` estimator could fit.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch

from .._util import single_thread
from ..estimators._jackknife import jackknife_std
from ..physical._convex import (
    MARGIN,
    _body_lmis,
    _cvxpy,
    _friction_signs,
    _variable_scales,
    psd_factor,
    solve_quietly,
)
from ._options import IdentificationError, IdentificationWarning, Options
from ._payload import ONE_BODY, payload_regressor
from ._prepare import identified_model, read_prepared, several
from ._stream import inverse_variance_weights, stream_moments

__all__ = ["DETERMINED_SPREAD", "DriveGains", "identify_drive_gains"]

#: a gain whose jackknife spread exceeds this share of it is reported as not determined
DETERMINED_SPREAD = 0.1
#: the fit stops when no gain moves by more than this in a step (relative)
_TOL = 1e-6
_MAX_ROUNDS = 100
#: the tie-break towards the identified robot's parameters, times the cost's mean curvature
_RIDGE = 1e-8
#: the payload's length unit for the solver's variables, m
_PAYLOAD_LENGTH = 0.1


@dataclass(eq=False)
class DriveGains:
    """What `identify_drive_gains` found.

    Attributes:
        joint_names: the joints, in the model's order.
        gains: ``(n_dof,)`` the identified gains ``s K0``, in the units of the nominal ones
            (N m/A for currents; for torque logs, ``K0 = 1`` and a gain is a torque scale).
        nominal: ``(n_dof,)`` the gains the logs were read with, ``K0``.
        std: ``(n_dof,)`` jackknife spreads of ``gains``.
        determined: ``(n_dof,)`` bool: the relative spread at most `DETERMINED_SPREAD`.
        theta: ``(n_params,)`` the robot's parameters fitted with the gains, in N m units.
        payload: ``(10,)`` the payload's ``(m, h, I_o)`` in its link's frame (``m`` the given
            mass).
        rms: ``(n_dof,)`` the fit's residual RMS per joint, ``|u_j - p_j / s_j|``, in the
            logs' units (the current times the nominal gain; N m for torque logs).
        rounds: Gauss-Newton steps until the gains stopped moving.
    """

    joint_names: tuple[str, ...]
    gains: torch.Tensor
    nominal: torch.Tensor
    std: torch.Tensor
    determined: torch.Tensor
    theta: torch.Tensor
    payload: torch.Tensor
    rms: torch.Tensor
    rounds: int

    def summary(self) -> dict:
        """JSON-ready numbers, one entry per joint, and the payload's centre of mass."""
        mass = float(self.payload[0])
        return {
            "joints": {
                name: {
                    "gain": float(self.gains[k]),
                    "std": float(self.std[k]),
                    "nominal": float(self.nominal[k]),
                    "ratio_to_nominal": float(self.gains[k] / self.nominal[k]),
                    "determined": bool(self.determined[k]),
                }
                for k, name in enumerate(self.joint_names)
            },
            "payload_mass": mass,
            "payload_com": (self.payload[1:4] / mass).tolist(),
            "residual_rms": self.rms.tolist(),
            "rounds": self.rounds,
            "determined_spread": DETERMINED_SPREAD,
        }

    def table(self) -> str:
        """A plain-text table: joint, gain +- spread, nominal, ratio, determined."""
        width = max(len(n) for n in self.joint_names)
        lines = [f"{'joint':<{width}}  {'gain':>9}  {'spread':>7}  {'nominal':>9}  ratio"]
        for k, name in enumerate(self.joint_names):
            g, s, n = (float(v[k]) for v in (self.gains, self.std, self.nominal))
            note = "" if self.determined[k] else "  not determined by these logs"
            lines.append(f"{name:<{width}}  {g:9.4g}  {s:7.2g}  {n:9.4g}  {g / n:.3f}{note}")
        return "\n".join(lines)


def _normal_matrices(model, logs, select, blocks: int, options) -> tuple[np.ndarray, np.ndarray]:
    """``(G (blocks, n_dof, P, P), n (blocks,))``: per contiguous block of the logs and per
    joint, the normal matrix of the rows ``(-Y_j, -Y_j select, u_j e_j)`` (``select`` ``(p,
    10)`` the payload's map, zero for unloaded logs), from each joint's `Moments` of ``(Y_j,
    u_j)`` (`stream_moments`), and the block's samples."""
    d, p = model.n_dof, model.n_params
    m = p + 10
    n = sum(log.n_samples for log in logs)
    if n < 10 * blocks:
        raise IdentificationError(f"logs of {n} samples are too short for {blocks} blocks")
    rows = stream_moments(model, logs, n_folds=blocks, per_joint=True, **options.compute.stream())
    T = -torch.cat([torch.eye(p, dtype=torch.float64), select], 1)  # (p, m): -(Y_j, Z_j)
    G = np.zeros((blocks, d, m + d, m + d))
    counts = np.zeros(blocks)
    for b, parts in enumerate(rows):
        for k, mk in enumerate(parts):
            mk = mk.to("cpu")
            G[b, k, :m, :m] = (T.T @ mk.xtx @ T).numpy()
            G[b, k, :m, m + k] = G[b, k, m + k, :m] = (T.T @ mk.xty).numpy()
            G[b, k, m + k, m + k] = float(mk.yty)
        counts[b] = float(parts[0].n)
    return G, counts


class _Fit:
    """The current-error fit on summed normal matrices ``G (n_dof, P, P)`` (see the module):
    Gauss-Newton in ``(a, g)``, ``a = (theta, pi)`` and ``g = 1 / s``, each step a semidefinite
    program (the matrix inequalities on ``a``) with Levenberg-Marquardt damping on ``g``."""

    def __init__(self, cp, model, mass, scales: np.ndarray, ref: np.ndarray, weighted=True):
        self.cp, self.model, self.mass, self.scales, self.ref = cp, model, mass, scales, ref
        self.weighted = weighted

    def step(self, G, weights, a0, g0, damping):
        """The damped Gauss-Newton step from ``(a0, g0)``: ``(a, g)``."""
        cp, model = self.cp, self.model
        p, d = model.n_params, model.n_dof
        m = p + 10
        H = np.zeros((m + d, m + d))
        b = np.zeros(m + d)
        for k in range(d):
            Gaa, Gua = G[k][:m, :m], G[k][m + k, :m]
            w, g = weights[k], g0[k]
            Ga0 = Gaa @ a0
            # the residual u - g p(a) = u + g r.a (r the rows' -Y, -Z part), linear in
            # (a, delta = g - g0) about (a0, g0): u + g0 r.a + delta r.a0
            H[:m, :m] += w * g * g * Gaa
            H[:m, m + k] += w * g * Ga0
            H[m + k, :m] += w * g * Ga0
            H[m + k, m + k] += w * (a0 @ Ga0)
            b[:m] += w * g * Gua
            b[m + k] += w * (Gua @ a0)
        S = np.concatenate([self.scales, g0])  # variables in units of a's scales and of g0
        H = H * S[:, None] * S[None, :]
        H = 0.5 * (H + H.T)
        b = b * S
        unit = max(float(np.trace(H[:m, :m])) / m, 1e-300)
        R = psd_factor(H / unit)
        z = cp.Variable(m + d)
        cost = (
            cp.sum_squares(R @ z)
            + 2 * (b / unit) @ z
            + damping * float(np.mean(np.diag(H[m:, m:]))) / unit * cp.sum_squares(z[m:])
            + _RIDGE * cp.sum_squares(z[:p] - self.ref[:p] / self.scales[:p])
        )
        scaled = torch.as_tensor(self.scales)
        constraints = [
            *_body_lmis(cp, z[:p], model.layout, "log-cholesky", scaled[:p], MARGIN),
            *_body_lmis(cp, z[p:m], ONE_BODY, "log-cholesky", scaled[p:m], MARGIN),
            z[p] == self.mass / self.scales[p],
            z[m:] >= 1e-3 - 1.0,  # g stays positive
        ]
        signs = _friction_signs(model.layout)
        if signs:
            constraints.append(z[signs] >= 0)
        problem = cp.Problem(cp.Minimize(cost), constraints)
        solve_quietly(cp, problem)
        if problem.status not in ("optimal", "optimal_inaccurate") or z.value is None:
            raise IdentificationError(
                f"the drive-gain fit did not converge (solver status {problem.status})"
            )
        return z.value[:m] * self.scales, g0 * (1.0 + z.value[m:])

    def __call__(self, G: np.ndarray, n: float, a: np.ndarray, g: np.ndarray):
        """``(a, s, sigma2, rounds)`` from the start ``(a, g)``."""
        sigma2 = _errors(G, a, g) / n
        damping = 1e-3
        rounds = 0
        while rounds < _MAX_ROUNDS:
            rounds += 1
            weights = np.ones_like(sigma2)
            if self.weighted:  # each joint by its inverse variance (see the module)
                weights = inverse_variance_weights(sigma2).numpy()
            before = float(weights @ _errors(G, a, g))
            while True:
                a_new, g_new = self.step(G, weights, a, g, damping)
                after = float(weights @ _errors(G, a_new, g_new))
                if after <= before * (1 + 1e-12) or damping > 1e6:
                    break
                damping *= 10.0
            moved = float(np.max(np.abs(g_new / g - 1.0)))
            a, g = a_new, g_new
            damping = max(damping / 10.0, 1e-6)
            sigma2 = _errors(G, a, g) / n
            if moved < _TOL:
                return a, 1.0 / g, sigma2, rounds
        warnings.warn(
            f"the drive-gain fit stopped after {rounds} rounds with the gains still moving by "
            f"{100 * moved:.2g} %: take them as approximate",
            IdentificationWarning,
            stacklevel=3,
        )
        return a, 1.0 / g, sigma2, rounds


def _errors(G: np.ndarray, a: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``(n_dof,)`` each joint's squared current error ``|u_j - g_j p_j|^2`` (``p_j`` the
    prediction of ``a``; the rows hold ``-Y, -Z``)."""
    m = a.shape[0]
    out = np.empty(g.shape[0])
    for k in range(g.shape[0]):
        pp = a @ G[k][:m, :m] @ a
        up = -(G[k][m + k, :m] @ a)
        out[k] = G[k][m + k, m + k] - 2 * g[k] * up + g[k] ** 2 * pp
    return np.maximum(out, 0.0)


@single_thread()
def identify_drive_gains(
    identified,
    loaded,
    unloaded,
    *,
    link: str,
    mass: float,
    options: Options | None = None,
    blocks: int | None = None,
) -> DriveGains:
    """Per-joint drive gains from loaded and unloaded runs with a payload of known mass (see
    the module).

    Args:
        identified: the robot's ``model.npz`` (`torchjfa identify`), or ``(model, theta)``:
            its structure (joint terms), units and the tie-break for undetermined directions.
        loaded: a log or logs with the payload mounted.
        unloaded: a log or logs without it (the same trajectory is best, not required).
        link: the frame the payload is fixed to (e.g. ``"ee_link"``).
        mass: the payload's mass, kg (> 0).
        options: `Options` for reading: currents need nominal ``drive_gains`` (e.g. 1 per
            joint, or the datasheet's), which the result scales; the filter and velocity
            options as `identify` has them; ``weighting`` (``"residual"``: each joint's current
            error weighted by its inverse variance, re-estimated every step; ``"none"``),
            ``jackknife`` (the blocks of the spreads) and ``compute``.
        blocks: contiguous blocks of the logs for the jackknife spreads (at least 3; each is
            one more fit), or None: ``options.jackknife``.

    Returns:
        `DriveGains`; ``options.replace(drive_gains=result.gains.tolist())`` reads logs with
        them.

    Raises:
        IdentificationError: on a non-positive mass, a link that carries nothing, a joint
            whose prediction opposes its signal, or a fit that does not converge.
    """
    if not mass > 0:
        raise IdentificationError(f"the payload's mass must be positive (kg), got {mass}")
    options = Options() if options is None else options
    blocks = int(options.jackknife) if blocks is None else blocks
    if blocks < 3:
        raise IdentificationError(
            f"the spreads need at least 3 jackknife blocks (blocks, or options.jackknife), got "
            f"{blocks}"
        )
    ident = identified_model(identified)
    model, theta0, cutoff = ident.model, ident.theta, ident.cutoff_hz
    j, A = payload_regressor(model, link)
    select = torch.zeros(model.n_params, 10, dtype=torch.float64)  # (p, 10): Z = Y select
    select[model.layout.split(torch.arange(model.n_params))[0][j]] = A
    p, d = model.n_params, model.n_dof
    prepared, nominal = {True: [], False: []}, None
    sources = [(s, True) for s in several(loaded)] + [(s, False) for s in several(unloaded)]
    for source, carries in sources:
        raw, log = read_prepared(source, model, options, cutoff)
        prepared[carries].append(log.reorder(model.joint_names))
        nominal = _nominal(raw, model) if nominal is None else nominal
    G, counts = _normal_matrices(model, prepared[True], select, blocks, options)
    Gu, nu = _normal_matrices(model, prepared[False], 0 * select, blocks, options)
    G, counts = G + Gu, counts + nu  # (blocks, d, P, P), (blocks,)
    scales = np.concatenate([
        _variable_scales(model.layout, theta0, None),
        [mass, *(mass * _PAYLOAD_LENGTH,) * 3, *(mass * _PAYLOAD_LENGTH**2,) * 6],
    ])  # fmt: skip
    ref = np.concatenate([theta0.numpy(), np.zeros(10)])
    fit = _Fit(_cvxpy(), model, mass, scales, ref, options.weighting == "residual")
    total, n = G.sum(0), float(counts.sum())
    a, s, sigma2, rounds = fit(total, n, ref, np.ones(d))
    omitted = np.stack([
        fit(total - G[b], n - float(counts[b]), a, 1.0 / s)[1] for b in range(blocks)
    ])  # fmt: skip
    spread = jackknife_std(omitted)
    a[p] = mass  # exactly, not to the solver's accuracy
    gains = torch.as_tensor(s) * nominal
    std = spread * nominal
    return DriveGains(
        tuple(model.joint_names), gains, nominal, std, std <= DETERMINED_SPREAD * gains,
        torch.as_tensor(a[:p]), torch.as_tensor(a[p:]), torch.as_tensor(np.sqrt(sigma2)),
        rounds,
    )  # fmt: skip


def _nominal(raw, model) -> torch.Tensor:
    """``(n_dof,)`` the gains a log was read with (1 for a torque log)."""
    gains = raw.info.get("drive_gains") if raw.info else None
    if not gains:
        return torch.ones(model.n_dof, dtype=torch.float64)
    return torch.tensor([float(gains[name]) for name in model.joint_names], dtype=torch.float64)
