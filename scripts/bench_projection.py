"""Benchmark: projection of an unconstrained estimate onto consistent parameters (eq. 8).

A serial chain of ``n_joints`` revolute joints (random axes and link inertias; 10 joints = 110
parameters with viscous friction) is built in Pinocchio, whose joint-torque regressor (plus one
viscous-friction column per joint) gives X for random motions. Ordinary least squares on noisy
torques gives an unconstrained theta_hat, made inconsistent on purpose (some masses negative,
some inertias indefinite). `torchjfa.physical.project` then makes it consistent with both
parametrisations. Printed per parametrisation: wall time (median of ``repeats``), LBFGS
iterations, function evaluations, cost before/after, and the time as a ratio against two
references measured in the same run: one batched ``torch.linalg.eigh`` of the bodies' 3x3
inertias, and the eigenvalue-clipping baseline (clip masses, clip eigenvalues of I_c).

    python scripts/bench_projection.py --n-joints 10
    python scripts/bench_projection.py --repeats 3 --write-docs   # also into docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import statistics
import time

import _benchmarks_page as page
import numpy as np
import torch

from torchjfa.dynamics import (
    ParameterLayout,
    inertial_from_vector,
    inertial_vector,
    pseudo_inertia,
)
from torchjfa.dynamics._parameters import symmetric_from_six
from torchjfa.physical import check, project


def chain_data(n_joints: int, n_samples: int, *, seed: int = 0, amplitude: float = 1.0):
    """Regressor rows of a random serial chain from Pinocchio.

    Returns:
        ``(layout, X (n_samples * n_joints, 11 n_joints), theta_true (11 n_joints,))``,
        float64 tensors.
    """
    import pinocchio as pin

    rng = np.random.default_rng(seed)
    model = pin.Model()
    parent = 0
    theta = []
    for j in range(n_joints):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        placement = pin.SE3(pin.exp3(rng.normal(size=3) * 0.5), rng.normal(size=3) * 0.15)
        jid = model.addJoint(parent, pin.JointModelRevoluteUnaligned(axis), placement, f"j{j}")
        mass = float(rng.uniform(0.5, 4.0))
        com = rng.normal(size=3) * 0.08
        a = rng.normal(size=(3, 3))
        inertia_c = mass * 0.01 * (a @ a.T / 3 + np.eye(3))  # PSD, triangle holds if diagonal
        model.appendBodyToJoint(jid, pin.Inertia(mass, com, inertia_c), pin.SE3.Identity())
        parent = jid
        pi = inertial_vector(
            torch.tensor(mass, dtype=torch.float64),
            torch.tensor(com),
            torch.tensor(inertia_c),
        )
        theta.append(torch.cat([pi, torch.tensor([float(rng.uniform(0.05, 0.5))])]))
    data = model.createData()
    rows = []
    for _ in range(n_samples):
        q = rng.uniform(-np.pi, np.pi, n_joints) * amplitude
        v = rng.normal(size=n_joints) * amplitude
        a = rng.normal(size=n_joints) * 2 * amplitude
        Y = pin.computeJointTorqueRegressor(model, data, q, v, a)  # (n, 10 n)
        full = np.zeros((n_joints, 11 * n_joints))
        for j in range(n_joints):
            full[:, 11 * j : 11 * j + 10] = Y[:, 10 * j : 10 * j + 10]
            full[j, 11 * j + 10] = v[j]
        rows.append(full)
    layout = ParameterLayout(tuple(f"j{j}" for j in range(n_joints)))
    return layout, torch.tensor(np.concatenate(rows)), torch.cat(theta)


def inconsistent_estimate(layout, X, theta_true, *, noise: float = 0.5, seed: int = 0):
    """OLS on noisy torques, then damaged: every third body gets a negative mass, every other
    an indefinite inertia at the centre of mass."""
    g = torch.Generator().manual_seed(seed)
    y = X @ theta_true + noise * torch.randn(X.shape[0], generator=g, dtype=torch.float64)
    theta_hat = torch.linalg.lstsq(X, y[:, None], driver="gelsd").solution[:, 0]
    per = theta_hat.reshape(layout.n_joints, -1).clone()
    per[::3, 0] = -0.3 * per[::3, 0].abs() - 0.1
    per[1::2, 4] -= 0.5
    return per.reshape(-1)


def clip_baseline(theta_hat, layout):
    """The simple feasible point: mass clipped to >= 1e-3 kg, centre of mass kept, I_c's
    eigenvalues clipped at 0, friction clipped at 0."""
    inertial, friction = layout.split(theta_hat)
    mass = inertial[:, 0].clamp_min(1e-3)
    com = inertial[:, 1:4] / mass[:, None]
    pos = inertial.clone()
    pos[:, 0] = mass
    _, _, inertia_c = inertial_from_vector(pos)
    evals, evecs = torch.linalg.eigh(inertia_c)
    inertia_c = (evecs * evals.clamp_min(0)[..., None, :]) @ evecs.transpose(-1, -2)
    return layout.join(inertial_vector(mass, com, inertia_c), friction.clamp_min(0))


def _lmi(pi: torch.Tensor, kind: str) -> torch.Tensor:
    """Linear matrix whose positive semidefiniteness is the consistent set of ``kind``:
    the pseudo-inertia (log-Cholesky) or ``[[I_o, S(h)^T], [S(h), m 1]]`` (eq. 5: m >= 0 and
    I_c >= 0, by a Schur complement)."""
    if kind == "log-cholesky":
        return pseudo_inertia(pi)
    inertia = symmetric_from_six(pi[..., 4:10])
    h = pi[..., 1:4]
    z = torch.zeros_like(h[..., 0])
    skew = torch.stack(
        [
            torch.stack([z, -h[..., 2], h[..., 1]], -1),
            torch.stack([h[..., 2], z, -h[..., 0]], -1),
            torch.stack([-h[..., 1], h[..., 0], z], -1),
        ],
        -2,
    )
    mass = pi[..., 0, None, None] * torch.eye(3, dtype=pi.dtype)
    return torch.cat(
        [torch.cat([inertia, skew.transpose(-1, -2)], -1), torch.cat([skew, mass], -1)], -2
    )


def convex_reference(theta_hat, M, layout, kind, *, ridge=1e-8, rho=0.01, iters=20000):
    """The same projection solved as a convex problem in theta by ADMM (an independent
    reference; the constraint set is convex, a linear matrix inequality per body).

    Returns:
        ``(objective, worst relative constraint violation)``; ADMM is stopped after ``iters``
        iterations, so its point may violate the constraints slightly (and its objective then
        be a little optimistic).
    """
    d = layout.n_params
    s = torch.diagonal(M).sum() / d
    eye = torch.eye(d, dtype=torch.float64)

    def lin(theta):
        inertial, friction = layout.split(theta)
        return torch.cat([_lmi(inertial, kind).reshape(-1), friction.reshape(-1)])

    F = torch.stack([lin(e) for e in eye], 1)  # (k, d)
    norm = theta_hat @ M @ theta_hat
    A = (M + ridge * s * eye) / norm
    chol = torch.linalg.cholesky(A + rho * F.T @ F)
    b = (M @ theta_hat) / norm
    n_mat = layout.n_joints * (4 if kind == "log-cholesky" else 6) ** 2
    side = 4 if kind == "log-cholesky" else 6
    signed = torch.tensor([f != "offset" for f in layout.friction])

    def proj(v):
        mats = v[:n_mat].reshape(layout.n_joints, side, side)
        w, V = torch.linalg.eigh(0.5 * (mats + mats.transpose(-1, -2)))
        mats = (V * w.clamp_min(0)[..., None, :]) @ V.transpose(-1, -2)
        fr = v[n_mat:].reshape(layout.n_joints, -1).clone()
        fr[:, signed] = fr[:, signed].clamp_min(0)
        return torch.cat([mats.reshape(-1), fr.reshape(-1)])

    z = proj(F @ theta_hat)
    u = torch.zeros_like(z)
    for _ in range(iters):
        theta = torch.cholesky_solve((b + rho * F.T @ (z - u))[:, None], chol)[:, 0]
        Ft = F @ theta
        z = proj(Ft + u)
        u = u + Ft - z
    inertial, _ = layout.split(theta)
    eig = torch.linalg.eigvalsh(_lmi(inertial, kind))
    violation = float((-eig[:, 0] / eig[:, -1].abs()).clamp_min(0).max())
    delta = theta - theta_hat
    objective = float(delta @ M @ delta + ridge * s * theta @ theta)
    return objective, violation


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run(
    n_joints: int = 10,
    n_samples: int = 2000,
    repeats: int = 5,
    seed: int = 0,
    reference: bool = False,
    threads: int = 1,
) -> dict:
    """Run the benchmark and print a table; returns the numbers as a dict.

    Args:
        n_joints: joints of the random chain (11 parameters each).
        n_samples: random states whose regressor rows make X.
        repeats: timed repetitions (the median is printed; the first, untimed call warms up).
        seed: of the chain, the data and the damage.
        reference: also solve the convex problem by ADMM (slow) and print the gap.
        threads: torch intra-op threads (1: the problem is small, threads only add overhead).
    """
    torch.set_num_threads(threads)
    layout, X, theta_true = chain_data(n_joints, n_samples, seed=seed)
    theta_hat = inconsistent_estimate(layout, X, theta_true, seed=seed)
    M = X.T @ X
    mats = torch.randn(n_joints, 3, 3, dtype=torch.float64)
    mats = mats @ mats.transpose(-1, -2)
    t_eigh = _median_time(lambda: torch.linalg.eigh(mats), 50 * repeats)
    t_clip = _median_time(lambda: clip_baseline(theta_hat, layout), 10 * repeats)
    base = clip_baseline(theta_hat, layout)
    base_cost = float((base - theta_hat) @ M @ (base - theta_hat))
    n_bad = int((~check(theta_hat, layout).body_ok).sum())
    print(
        f"{n_joints} joints, {layout.n_params} parameters, {X.shape[0]} regressor rows, "
        f"{n_bad} inconsistent bodies in theta_hat, torch threads {threads}"
    )
    print(
        f"references: eigh of {n_joints} 3x3 matrices {t_eigh * 1e6:.1f} us; "
        f"clipping baseline {t_clip * 1e6:.1f} us (cost {base_cost:.6g})"
    )
    out = {"t_eigh": t_eigh, "t_clip": t_clip, "baseline_cost": base_cost}
    head = (
        f"{'parametrization':<13} {'time [s]':>8} {'x eigh':>8} {'x clip':>7} {'iters':>6} "
        f"{'evals':>6} {'initial cost':>13} {'final cost':>11} {'conv':>5} {'ok':>5}"
    )
    if reference:
        head += f" {'ADMM cost':>11} {'gap':>7} {'ADMM viol.':>10}"
    print(head)
    for name in ("virtual", "log-cholesky"):
        t0 = time.perf_counter()
        result = project(theta_hat, layout=layout, metric=M, parametrization=name)
        first = time.perf_counter() - t0
        t = _median_time(
            lambda n=name: project(theta_hat, layout=layout, metric=M, parametrization=n),
            repeats,
        )
        ok = result.after.ok if name == "log-cholesky" else result.after.weakly_ok
        line = (
            f"{name:<13} {t:>8.3f} {t / t_eigh:>8.0f} {t / t_clip:>7.0f} {result.n_iter:>6} "
            f"{result.n_eval:>6} {result.initial_cost:>13.6g} {result.cost:>11.6g} "
            f"{str(result.converged):>5} {str(ok):>5}"
        )
        row = {
            "time": t,
            "first_call": first,
            "n_iter": result.n_iter,
            "n_eval": result.n_eval,
            "cost": result.cost,
            "objective": result.objective,
            "initial_cost": result.initial_cost,
            "converged": result.converged,
        }
        if reference:
            ref, violation = convex_reference(theta_hat, M, layout, name)
            line += f" {ref:>11.6g} {result.objective / ref - 1:>7.2%} {violation:>10.1e}"
            row.update(reference=ref, violation=violation)
        print(line)
        print(f"{'':<13} first call {first:.3f} s (includes one-time lazy imports of torch.optim)")
        out[name] = row
    return out


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n-joints", type=int, default=10, help="joints of the random chain")
    p.add_argument("--n-samples", type=int, default=2000, help="random states whose rows make X")
    p.add_argument("--repeats", type=int, default=5, help="timed repetitions (the median)")
    p.add_argument("--seed", type=int, default=0, help="seed of the chain, data and damage")
    p.add_argument("--reference", action="store_true", help="also solve by ADMM (slow)")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    return page.add_option(p)


def main(argv=None) -> dict:
    args = parser().parse_args(argv)
    with page.recording("bench_projection", "bench_projection", args.write_docs, argv):
        return run(
            args.n_joints, args.n_samples, args.repeats, args.seed, args.reference, args.threads
        )


if __name__ == "__main__":
    main()
