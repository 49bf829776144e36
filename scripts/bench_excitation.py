"""Optimised vs random excitation: identification from each, in simulation.

    python scripts/bench_excitation.py --seeds 3     # head, arm, panda; a few minutes per seed
    python scripts/bench_excitation.py --smoke       # seconds (CI-sized)

For each robot and seed, two trajectories of the same duration inside the same limits:

* optimised: `torchjfa.excitation.optimize_excitation` (its default criterion: D-optimal
  starts, the best polished on the condition number; Fourier series at rest at the middle of
  the position limits; ``--criterion`` for another),
* random: `torchjfa.excitation.random_excitation` (the library's random sum of sinusoids,
  `torchjfa.sim.random_trajectory`, with the same base frequency and harmonics, scaled to the
  largest amplitude the same limits allow).

Each runs for two periods. The Sarcos-like head and arm are simulated in MuJoCo by
`torchjfa.sim.generate_log` (computed-torque tracking, default sensor noise, accelerations
differentiated from the noisy velocity sensor) with the unmodeled effects off (rigid body plus
viscous damping: what the identified model can represent, so the comparison measures the
excitation); the Panda arm (no MuJoCo model ships with it) moves exactly along the trajectory
with torques ``Y theta_true`` (theta_true: the URDF's inertials, viscous friction 0.5 N m s/rad)
and gets the same sensor noise and the same differentiation as `generate_log`. OLS
in the identifiable directions (the moments from `torchjfa.identification.stream_moments`, then
``theta_hat = V (V^T X^T X V)^-1 V^T X^T y``) identifies each log. Printed per robot (medians over the
seeds, and their ratios random / optimised):

* base-parameter error ``|V^T (theta_hat - theta_true)| / |V^T theta_true|`` (V: the identifiable
  directions, `torchjfa.excitation.base_directions`),
* held-out RMS torque error (N m, all joints) on a common noiseless test trajectory
  (`random_trajectory` of the robot, 4 s period, 8 harmonics),
* condition number of the base regressor of each trajectory (`trajectory_information`),
* the optimisation's wall time.

Goal: errors 2x lower and condition number 5x lower for the optimised trajectory.

    python scripts/bench_excitation.py --seeds 3 --quiet --write-docs   # into docs/benchmarks.md
"""

from __future__ import annotations

import argparse
from types import SimpleNamespace

import _benchmarks_page as page
import numpy as np
import torch

import torchjfa
from torchjfa.data import differentiate
from torchjfa.dynamics import RigidBodyModel
from torchjfa.excitation import (
    CRITERIA,
    limits_from_model,
    optimize_excitation,
    random_excitation,
    trajectory_information,
)
from torchjfa.identification import stream_moments
from torchjfa.sim import (
    DEFAULT_RATES,
    SensorNoise,
    SinusoidTrajectory,
    generate_log,
    model_path,
    random_trajectory,
    robot_effects,
)

PANDA_RATE = 500.0
PANDA_FV = 0.5


def _robot(name: str):
    if name in ("head", "arm"):
        model = RigidBodyModel.from_mjcf(model_path(name))
        theta = model.nominal_theta.clone()
        damping = robot_effects(name)["damping"]  # MuJoCo joint order = the MJCF's
        mj_names = _mj_names(name)
        for j, joint in enumerate(model.joint_names):
            theta[model.layout.index(j, "fv")] = float(damping[mj_names.index(joint)])
        limits = limits_from_model(model, velocity=2.0, acceleration=10.0)
        return model, theta, limits, DEFAULT_RATES[name]
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    theta = model.nominal_theta.clone()
    for j in range(model.n_dof):
        theta[model.layout.index(j, "fv")] = PANDA_FV
    limits = limits_from_model(model, acceleration=10.0)  # URDF position, velocity, effort
    return model, theta, limits, PANDA_RATE


def _mj_names(robot: str) -> list[str]:
    import mujoco

    mj = mujoco.MjModel.from_xml_path(str(model_path(robot)))
    return [mj.joint(i).name for i in range(mj.njnt)]


def _reorder(traj, perm) -> SinusoidTrajectory:
    s = traj if isinstance(traj, SinusoidTrajectory) else traj.to_sinusoid()
    return SinusoidTrajectory(
        s.base_frequency, s.offset[perm], s.amplitude[perm], s.harmonic[perm], s.phase[perm]
    )


def _log(name, model, theta, rate, traj, periods: int, seed: int) -> dict:
    """A noisy identification log of ``periods`` periods, in the model's joint order."""
    n_per = int(round(traj.period * rate))
    if name in ("head", "arm"):
        mj = _mj_names(name)
        perm = [model.joint_names.index(j) for j in mj]  # model rows -> MuJoCo order
        log = generate_log(
            name, n_samples=periods * n_per, unmodeled=False, trajectory=_reorder(traj, perm),
            seed=seed,
        )  # fmt: skip
        back = [mj.index(j) for j in model.joint_names]
        return {k: getattr(log, k)[:, back] for k in ("q", "qd", "qdd", "tau")}
    # the Panda: exact motion, generate_log's noise and differentiation, one period of padding
    noise = SensorNoise()
    t = torch.arange(-n_per, (periods + 1) * n_per, dtype=torch.float64) / rate
    q, qd, qdd = traj(torch.remainder(t, traj.period))
    tau = model.inverse_dynamics(q, qd, qdd, theta)
    g = torch.Generator().manual_seed(10_000 + seed)

    def noisy(x, std):
        return x + std * torch.randn(x.shape, generator=g, dtype=x.dtype)

    qm = noisy(q, noise.position_std)
    qdm = noisy(qd, noise.velocity_std)
    taum = noisy(tau, noise.torque_std)
    qddm = differentiate(t, qdm).first
    keep = slice(n_per, (periods + 1) * n_per)
    return {"q": qm[keep], "qd": qdm[keep], "qdd": qddm[keep], "tau": taum[keep]}


def _test_set(name, model, theta, limits) -> tuple:
    if name in ("head", "arm"):
        import mujoco

        mj = mujoco.MjModel.from_xml_path(str(model_path(name)))
        traj = _reorder(random_trajectory(mj, seed=1000), [_mj_names(name).index(j)
                                                          for j in model.joint_names])  # fmt: skip
    else:
        ranges = SimpleNamespace(
            jnt_range=np.stack([limits.position_low, limits.position_high], 1),
            jnt_limited=np.ones(model.n_dof, dtype=bool),
        )
        traj = random_trajectory(ranges, seed=1000)
    t = torch.arange(2000, dtype=torch.float64) * (traj.period / 2000)
    q, qd, qdd = traj(t)
    return q, qd, qdd, model.inverse_dynamics(q, qd, qdd, theta)


def run(
    *,
    robots=("head", "arm", "panda"),
    seeds=(0, 1, 2),
    duration: float = 10.0,
    base_frequency: float = 0.1,
    harmonics: int = 5,
    periods: int = 2,
    criterion: str = "d+condition",
    smoke: bool = False,
    progress: bool = True,
) -> dict:
    """Identify each robot from optimised and random excitations; print and return the numbers.

    Returns:
        ``{robot: {"optimised": {...}, "random": {...}, "ratio": {...}}}`` with medians over
        the seeds of ``base_error``, ``torque_rms``, ``condition`` and ``seconds``.
    """
    opt_kw = {}
    if smoke:
        duration, base_frequency, harmonics = 4.0, 0.25, 3
        opt_kw = {"n_grid": 60, "n_starts": 1, "max_iter": 8, "polish_iter": 8}
    results = {}
    for name in robots:
        model, theta, limits, rate = _robot(name)
        test = _test_set(name, model, theta, limits)
        rows = {"optimised": [], "random": []}
        for seed in seeds:
            res = optimize_excitation(
                model, limits, duration=duration, base_frequency=base_frequency,
                harmonics=harmonics, rate=rate, seed=seed, criterion=criterion, progress=progress,
                **opt_kw,
            )  # fmt: skip
            rnd = random_excitation(
                model, limits, base_frequency=base_frequency, harmonics=harmonics, rate=rate,
                seed=seed,
            )  # fmt: skip
            V = res.basis
            for key, traj in (("optimised", res.trajectory), ("random", rnd)):
                log = _log(
                    name,
                    model,
                    theta,
                    rate,
                    traj,
                    periods * int(round(duration * base_frequency)),
                    seed,
                )  # noqa: E501
                m = stream_moments(model, log)
                # least squares in the identifiable directions: theta_hat = V (V'X'XV)^-1 V'X'y
                theta_hat = V @ torch.linalg.solve(V.T @ m.xtx @ V, V.T @ m.xty)
                err = float((V.T @ (theta_hat - theta)).norm() / (V.T @ theta).norm())
                pred = model.inverse_dynamics(*test[:3], theta_hat)
                rms = float((pred - test[3]).pow(2).mean().sqrt())
                cond = trajectory_information(model, traj, V)["condition_number"]
                secs = res.seconds if key == "optimised" else 0.0
                rows[key].append({"base_error": err, "torque_rms": rms, "condition": cond,
                                  "seconds": secs})  # fmt: skip
        med = {
            key: {m: float(np.median([r[m] for r in rs])) for m in rs[0]}
            for key, rs in rows.items()
        }
        med["ratio"] = {
            m: med["random"][m] / med["optimised"][m]
            for m in ("base_error", "torque_rms", "condition")
        }
        med["per_seed"] = rows
        results[name] = med
    _print(results, seeds, duration, base_frequency, harmonics, periods)
    return results


def _print(results, seeds, duration, f0, H, periods) -> None:
    print(
        f"\n{duration:g} s trajectories ({H} harmonics of {f0:g} Hz), {periods} periods logged, "
        f"seeds {list(seeds)}; medians over the seeds; ratio = random / optimised"
    )
    head = (
        f"{'robot':6s} {'metric':22s} {'optimised':>11s} {'random':>11s} {'ratio':>7s} {'goal':>5s}"
    )
    print(head)
    goals = {"base_error": 2.0, "torque_rms": 2.0, "condition": 5.0}
    labels = {"base_error": "base-parameter error", "torque_rms": "held-out torque RMS",
              "condition": "condition number"}  # fmt: skip
    for name, r in results.items():
        for m, label in labels.items():
            ok = "met" if r["ratio"][m] >= goals[m] else "no"
            print(
                f"{name:6s} {label:22s} {r['optimised'][m]:11.4g} {r['random'][m]:11.4g} "
                f"{r['ratio'][m]:7.2f} {ok:>5s}"
            )
        print(f"{name:6s} {'optimisation s':22s} {r['optimised']['seconds']:11.1f}")


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1")
    p.add_argument("--robots", default="head,arm,panda", help="comma-separated: head, arm, panda")
    p.add_argument(
        "--criterion", choices=CRITERIA, default="d+condition", help="the excitation's criterion"
    )
    p.add_argument("--smoke", action="store_true", help="tiny sizes, one seed")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return page.add_option(p)


def main(argv=None) -> dict:
    a = parser().parse_args(argv)
    seeds = (0,) if a.smoke else tuple(range(a.seeds))
    with page.recording("bench_excitation", "bench_excitation", a.write_docs, argv, smoke=a.smoke):
        return run(
            robots=tuple(a.robots.split(",")),
            seeds=seeds,
            criterion=a.criterion,
            smoke=a.smoke,
            progress=not a.quiet,
        )


if __name__ == "__main__":
    main()
