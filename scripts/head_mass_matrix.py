"""Why do identified head models fail in computed-torque control? Their mass matrices.

Identifies the simulated head as `scripts/reproduce_tables.py --robots head --n-samples 100000
--weighting residual` does (ridge, stepwise, LASSO, with the projection), runs the control
evaluation, and prints the median over the held-out test trajectory of the diagonal of each
identified mass matrix M(q), next to the true parameters' and the simulator's armature (which
adds to the joint's own inertia and is not in the rigid-body model).

    python scripts/head_mass_matrix.py                     # about 1 minute
    python scripts/head_mass_matrix.py --n-samples 30000
"""

from __future__ import annotations

import argparse

import torch

from torchjfa.dynamics import RigidBodyModel
from torchjfa.experiments import robots
from torchjfa.sim import load_robot, model_path, random_trajectory, robot_effects


def mass_matrix(model: RigidBodyModel, theta: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """``(n, n_dof, n_dof)`` M(q) from the regressor: column k is ``ID(q, 0, e_k) - ID(q, 0, 0)``."""
    z = torch.zeros_like(q)
    bias = model.regressor(q, z, z) @ theta
    cols = []
    for k in range(model.n_dof):
        e = torch.zeros_like(q)
        e[:, k] = 1.0
        cols.append(model.regressor(q, z, e) @ theta - bias)
    return torch.stack(cols, dim=-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-samples", type=int, default=100_000)
    args = ap.parse_args()
    methods = ("ridge", "stepwise", "lasso")
    res = robots.run_robot("head", n_samples=args.n_samples, methods=methods, weighting="residual")
    model = RigidBodyModel.from_mjcf(model_path("head"))
    traj = random_trajectory(load_robot("head"), seed=1000)  # run_robot's test trajectory
    q = traj(torch.linspace(0.0, 4.0, 100, dtype=torch.float64))[0]
    names = [load_robot("head").joint(i).name for i in range(model.n_dof)]
    armature = robot_effects("head")["armature"]
    thetas = {m: res.identified[m].theta for m in methods}
    thetas["true"] = robots.true_theta(model, "head")
    control = {r["method"]: r["success"] for r in res.rows}
    print(f"median diagonal of M(q) on the test trajectory, kg m^2 ({args.n_samples} samples)")
    print(f"{'joint':<16}" + "".join(f"{m:>11}" for m in thetas) + f"{'armature':>11}")
    diag = {
        m: mass_matrix(model, th, q).diagonal(dim1=-2, dim2=-1).median(0).values
        for m, th in thetas.items()
    }
    for j, name in enumerate(model.joint_names):
        arm = armature[names.index(name)]
        print(
            f"{name:<16}"
            + "".join(f"{float(d[j]):>11.2e}" for d in diag.values())
            + f"{arm:>11.2e}"
        )
    print(
        "tracks:         "
        + "".join(f"{str(control.get(m, control.get('true'))):>11}" for m in thetas)
    )


if __name__ == "__main__":
    main()
