"""A small end-to-end demo: identify the 7-DoF Franka Panda arm from noisy joint data.

    python scripts/demo.py             # about 10 s (after the first build of the EM loop)
    python scripts/demo.py --seeds 0-4 # five seeds: each method's mean, spread and worst case
    python scripts/demo.py --smoke     # a few seconds (CI runs this)

The robot description ships with the package (`torchjfa.robots.path("panda_arm")`). The "robot" is
the model itself with true parameters = the URDF's values plus viscous friction: it moves in a
periodic excitation (two identical periods), its joint positions, velocities and accelerations
are measured with noise (accelerations the noisiest, as after numerical differentiation) and
its torques with noise. The demo then

1. streams the regression rows into `Moments` (the full matrix is never formed),
2. estimates the noise of every regression column from the two repeated periods,
3. fits OLS, the paper's Bayesian JFA, and the noise-informed Bayesian JFA
   (`torchjfa.identification.fit` on the moments),
4. projects each estimate onto physically consistent parameters (the paper's eq. 8,
   `torchjfa.identification.make_consistent`),
5. checks consistency and scores torque prediction on a held-out noiseless trajectory.
"""

from __future__ import annotations

import argparse
import math
import time

import torch
from experiments.seeds import for_each_seed, parse_seeds, seeds_help, summary_lines

import torchjfa
from torchjfa.dynamics import InverseDynamics, RigidBodyModel
from torchjfa.identification import fit, make_consistent
from torchjfa.metrics import nmse
from torchjfa.physical import check


def excitation(model: RigidBodyModel, n: int, *, period_s: float, seed: int, periods: int = 1):
    """A periodic sum-of-sines trajectory: ``(q, qd, qdd)`` each ``(periods * n, n_dof)``."""
    g = torch.Generator().manual_seed(seed)
    dof = model.n_dof
    t = torch.arange(periods * n, dtype=torch.float64) * (period_s / n)
    w0 = 2 * math.pi / period_s
    harmonics = torch.tensor([1.0, 2.0, 3.0, 5.0], dtype=torch.float64)
    amp = torch.rand(dof, 4, generator=g, dtype=torch.float64) * 0.4 / harmonics
    phase = torch.rand(dof, 4, generator=g, dtype=torch.float64) * 2 * math.pi
    prismatic = torch.tensor([k == "prismatic" for k in model.joint_types])
    centre = torch.where(prismatic, 0.02, 0.3).to(torch.float64)
    amp[prismatic] *= 0.02  # finger joints move a few millimetres
    arg = w0 * harmonics * t[:, None, None] + phase  # (T, dof, 4)
    q = centre + (amp * torch.sin(arg)).sum(-1)
    qd = (amp * w0 * harmonics * torch.cos(arg)).sum(-1)
    qdd = -(amp * (w0 * harmonics) ** 2 * torch.sin(arg)).sum(-1)
    return q, qd, qdd


def run(*, smoke: bool = False, seed: int = 0) -> dict:
    torch.manual_seed(seed)
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    theta_true = model.nominal_theta.clone()
    for j in range(model.n_dof):
        theta_true[model.layout.index(j, "fv")] = 0.5 if model.joint_types[j] == "revolute" else 5.0
    n = 400 if smoke else 20_000  # samples per period
    q, qd, qdd = excitation(model, n, period_s=4.0, seed=seed, periods=2)
    tau = model.inverse_dynamics(q, qd, qdd, theta_true)

    g = torch.Generator().manual_seed(seed + 1)
    std = {"q": 2e-3, "qd": 2e-2, "qdd": 0.5, "tau": 0.05}  # rad, rad/s, rad/s^2, N m

    def noisy(x, s):
        return x + s * torch.randn(x.shape, generator=g, dtype=x.dtype)

    qm, qdm, qddm, taum = (
        noisy(q, std["q"]),
        noisy(qd, std["qd"]),
        noisy(qdd, std["qdd"]),
        noisy(tau, std["tau"]),
    )
    print(
        f"{model}\n{2 * n} samples x {model.n_dof} joints = {2 * n * model.n_dof} rows, "
        f"{model.n_params} parameters"
    )

    start = time.perf_counter()
    moments = model.moments(qm, qdm, qddm, taum, chunk_size=4096)
    print(f"moments: {time.perf_counter() - start:.2f} s")
    # the same excitation repeats: half the variance of the difference between the regression
    # rows of the two periods estimates each column's input noise
    Y1 = model.regressor(qm[:n], qdm[:n], qddm[:n]).reshape(-1, model.n_params)
    Y2 = model.regressor(qm[n:], qdm[n:], qddm[n:]).reshape(-1, model.n_params)
    input_noise = ((Y1 - Y2) ** 2).mean(0) / 2

    max_iter = 200 if smoke else 20000
    methods = {  # name -> (estimator, its options, the input noise it is given)
        "OLS": ("ols", {}, "learn"),
        "Bayes JFA (seed)": ("bayes-jfa", {"max_iter": max_iter}, "learn"),
        "Bayes JFA (noise-informed)": ("bayes-jfa", {"max_iter": max_iter}, input_noise),
    }
    qt, qdt, qddt = excitation(model, n // 2, period_s=3.0, seed=seed + 7)
    tau_test = model.inverse_dynamics(qt, qdt, qddt, theta_true)

    def test_nmse(theta):
        return float(nmse(InverseDynamics(model, theta)(qt, qdt, qddt).detach(), tau_test))

    rows = []
    for name, (estimator, kw, noise) in methods.items():
        # the library's stages on moments already formed: the fit, then the projection onto
        # fully consistent parameters (log-Cholesky) in the metric X^T X + N diag(noise) of the
        # paper's eq. 8, with the noise given, or the one Bayesian JFA learned
        options = torchjfa.Options(
            estimator=estimator,
            estimator_options=kw,
            input_noise=noise,
            weighting="none",
            jackknife=0,
            bias_correction=0,
            description_prior=None,
            projection_options={"max_iter": 100 if smoke else 1000},
        )
        start = time.perf_counter()
        result = fit(model, moments, options=options)
        fit_s = time.perf_counter() - start
        theta = make_consistent(result, options).theta
        rows.append(
            {
                "method": name,
                "fit_s": fit_s,
                "consistent_before": check(result.theta_hat, model).ok,
                "consistent_after": check(theta, model).ok,
                "nmse_raw": test_nmse(result.theta_hat),
                "nmse_projected": test_nmse(theta),
            }
        )

    print(
        f"\n{'method':28s} {'fit s':>7s} {'consistent':>11s} {'nMSE raw':>10s} {'nMSE proj':>10s}"
    )
    for r in rows:
        flag = f"{'yes' if r['consistent_before'] else 'no'} -> {'yes' if r['consistent_after'] else 'no'}"
        print(
            f"{r['method']:28s} {r['fit_s']:7.2f} {flag:>11s} {r['nmse_raw']:10.2e} "
            f"{r['nmse_projected']:10.2e}"
        )
    print(
        "\nnMSE: held-out noiseless torques, torchjfa.metrics.nmse (each joint's mean squared "
        "error over its torque's variance, averaged over joints); 'consistent': "
        "torchjfa.physical.check before -> after the projection."
    )
    return {"rows": rows}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--smoke", action="store_true", help="tiny sizes, a few seconds")
    parser.add_argument("--seeds", default="0", help=seeds_help("0"))
    args = parser.parse_args()
    seeds = parse_seeds(args.seeds)
    runs = for_each_seed(
        seeds, lambda seed, _: {r["method"]: r for r in run(smoke=args.smoke, seed=seed)["rows"]}
    )
    if len(seeds) > 1:
        print("\nprojected nMSE (held-out noiseless torques) over the seeds:")
        methods = list(runs[seeds[0]])
        table = {m: {s: runs[s][m]["nmse_projected"] for s in seeds} for m in methods}
        for line in summary_lines(table):
            print(" ", line)
        base = "OLS"
        for m in methods[1:]:
            wins = [
                s for s in seeds if runs[s][m]["nmse_projected"] < runs[s][base]["nmse_projected"]
            ]
            print(f"  {m} below {base} on {len(wins)} of {len(seeds)} seeds")
