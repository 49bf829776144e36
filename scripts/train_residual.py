"""Identified dynamics + learned residual vs identified-only vs MLP-only on the simulated head.

    python scripts/train_residual.py                 # the full run (several minutes on 2 CPUs)
    python scripts/train_residual.py --smoke         # tiny sizes, a few seconds of training

Steps: simulate a training and a held-out test log of the 7-DoF head with its unmodeled effects
on (armature, dry friction, joint stiffness), each on its own random excitation (a long period,
so the training log does not repeat itself); identify the rigid-body parameters from the
training log (OLS on the moments, then the projection onto physically consistent parameters) and
save them with `torchjfa.io.save_identified`; train, with Lightning, an MLP on (q, qd, qdd) alone
and the identified model plus an MLP residual (theta frozen), on the first n training samples
for several n; report the held-out torque nMSE (measured inputs, noise-free target torques) of
identified-only, MLP-only and identified + residual, and plot the data-efficiency curves.
Every model is trained for the same number of gradient steps.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from pathlib import Path

import lightning as L
import torch
from torch.utils.data import DataLoader, RandomSampler

import torchjfa.io
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import OLS
from torchjfa.learning import ResidualDynamicsModule, StateTorqueDataset, log_tensors, nmse
from torchjfa.physical import project
from torchjfa.sim import generate_log, load_robot, model_path, random_trajectory

QUIET = (
    r".*does not have many workers.*",
    r".*is smaller than the logging interval.*",
    r".*LeafSpec.*",
    r".*exists and is not empty.*",
    r".*no `val_dataloader`.*",
)


def _train(module, tensors, n, *, steps, batch_size, seed):
    data = {k: v[:n] for k, v in tensors.items()}
    module.fit_statistics(data)
    # epochs of a fixed 100 batches drawn with replacement, whatever n: the same number of
    # gradient steps (and learning-rate schedule) for every training-set size
    dataset = StateTorqueDataset(data["q"], data["qd"], data["qdd"], data["tau"], data.get("Y"))
    sampler = RandomSampler(
        dataset,
        replacement=True,
        num_samples=100 * batch_size,
        generator=torch.Generator().manual_seed(seed),
    )
    loader = DataLoader(dataset, batch_size=batch_size, sampler=sampler)
    epochs = max(1, math.ceil(steps / 100))
    trainer = L.Trainer(
        accelerator="cpu",
        devices=1,
        max_epochs=epochs,
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        enable_checkpointing=False,
        limit_val_batches=0,
    )
    with warnings.catch_warnings():
        for message in QUIET:
            warnings.filterwarnings("ignore", message=message)
        trainer.fit(module, train_dataloaders=loader)
    return module.model.eval()


def run(
    *,
    robot: str = "head",
    n_train: int = 20_000,
    n_test: int = 5_000,
    sizes: tuple[int, ...] = (200, 500, 2000, 20_000),
    steps: int = 2000,
    batch_size: int = 256,
    hidden: tuple[int, ...] = (64, 64),
    lr: float = 3e-3,
    weight_decay: float = 1e-2,
    base_frequency: float = 0.02,
    out_dir: str = "residual_results",
    seed: int = 0,
    plot: bool = True,
) -> dict:
    """Run the comparison; returns (and writes to ``out_dir/results.json``) the nMSEs."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    mj = load_robot(robot)
    logs = {}
    for name, n, s in (("train", n_train, seed), ("test", n_test, seed + 1)):
        traj = random_trajectory(
            mj,
            base_frequency=base_frequency,
            n_terms=5,
            max_harmonic=int(round(2.0 / base_frequency)),
            seed=s,
        )
        logs[name] = generate_log(robot, n_samples=n, trajectory=traj, seed=s)
        logs[name].save(out / f"{robot}_{name}.npz")
    t_sim = time.perf_counter() - t0

    # identification: OLS on the moments of the measured signals, then projection (eq. 8)
    model = RigidBodyModel.from_mjcf(model_path(robot))
    q, qd, qdd, tau = log_tensors(logs["train"], "measured", model.joint_names)
    t1 = time.perf_counter()
    moments = model.moments(q, qd, qdd, tau)
    theta_ols = OLS(fit_intercept=False).fit_moments(moments).coef_
    theta = project(theta_ols, layout=model, moments=moments).theta
    t_id = time.perf_counter() - t1
    id_path = out / f"{robot}_identified.npz"
    torchjfa.io.save_identified(
        id_path, model, theta, estimator="OLS + projection (virtual)", n_samples=n_train
    )
    idyn = torchjfa.io.load_identified(id_path)  # the file's model, as every user loads it

    t2 = time.perf_counter()
    Y = model.regressor(q, qd, qdd)  # once, for every residual model
    t_reg = time.perf_counter() - t2
    tensors = {"q": q, "qd": qd, "qdd": qdd, "tau": tau, "Y": Y}
    qt, qdt, qddt, taut = log_tensors(logs["test"], "measured_inputs", model.joint_names)
    with torch.no_grad():
        Yt = model.regressor(qt, qdt, qddt)
        results = {"identified": float(nmse(Yt @ idyn.theta, taut))}

    sizes = tuple(n for n in sizes if n <= n_train)
    curves = {"mlp": {}, "residual": {}}
    t3 = time.perf_counter()
    for n in sizes:
        for kind in curves:
            kw = {"n_dof": model.n_dof} if kind == "mlp" else {"identified": str(id_path)}
            module = ResidualDynamicsModule(
                hidden=hidden, lr=lr, weight_decay=weight_decay, seed=seed, **kw
            )
            net = _train(module, tensors, n, steps=steps, batch_size=batch_size, seed=seed)
            with torch.no_grad():
                pred = net(qt, qdt, qddt, regressor=Yt if kind == "residual" else None)
            curves[kind][n] = float(nmse(pred, taut))
            print(f"  n={n:6d} {kind:9s} test nMSE {curves[kind][n]:.5f}", flush=True)
    t_train = time.perf_counter() - t3
    n_full = sizes[-1]
    results["mlp"] = curves["mlp"][n_full]
    results["residual"] = curves["residual"][n_full]
    reach = [n for n in sizes if curves["residual"][n] <= results["mlp"]]
    summary = {
        "robot": robot,
        "n_train": n_train,
        "n_test": n_test,
        "steps": steps,
        "weight_decay": weight_decay,
        "nmse_at_full_data": results,
        "curves": {k: {str(n): v for n, v in c.items()} for k, c in curves.items()},
        "residual_beats_both": results["residual"] < min(results["identified"], results["mlp"]),
        "smallest_n_residual_reaches_mlp_full": min(reach) if reach else None,
        "fraction_of_data": (min(reach) / n_full) if reach else None,
        "seconds": {"simulate": t_sim, "identify": t_id, "regressor": t_reg, "train": t_train},
    }
    (out / "results.json").write_text(json.dumps(summary, indent=2))
    if plot:
        _plot(summary, sizes, curves, out)
    return summary


def _plot(summary, sizes, curves, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = summary["nmse_at_full_data"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    names = ["identified", "mlp", "residual"]
    a.bar(["identified only", "MLP only", "identified + residual"], [res[k] for k in names])
    a.set_yscale("log")
    a.set_ylabel("held-out torque nMSE")
    a.set_title(f"n = {sizes[-1]} training samples")
    for kind, label in (("mlp", "MLP only"), ("residual", "identified + residual")):
        b.loglog(sizes, [curves[kind][n] for n in sizes], "o-", label=label)
    b.axhline(res["identified"], color="k", ls="--", label="identified only")
    b.set_xlabel("training samples")
    b.set_ylabel("held-out torque nMSE")
    b.legend()
    fig.tight_layout()
    fig.savefig(out / "residual_dynamics.png", dpi=120)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", default="head", choices=["head", "arm"])
    p.add_argument("--n-train", type=int, default=20_000)
    p.add_argument("--n-test", type=int, default=5_000)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out-dir", default="residual_results")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--weight-decay", type=float, default=1e-2, help="Adam's, both models")
    p.add_argument("--smoke", action="store_true", help="tiny sizes (a quick check)")
    args = p.parse_args()
    kw = dict(
        robot=args.robot,
        n_train=args.n_train,
        n_test=args.n_test,
        steps=args.steps,
        out_dir=args.out_dir,
        seed=args.seed,
        weight_decay=args.weight_decay,
    )
    if args.smoke:
        kw.update(n_train=1000, n_test=500, steps=100, sizes=(100, 1000))
    s = run(**kw)
    res = s["nmse_at_full_data"]
    print(f"held-out torque nMSE with {s['n_train']} training samples ({s['robot']}):")
    for k in ("identified", "mlp", "residual"):
        print(
            f"  {k:10s} {res[k]:.5f}   ratio to identified + residual: "
            f"{res[k] / res['residual']:.2f}"
        )
    print(f"identified + residual beats both: {s['residual_beats_both']}")
    print(
        f"identified + residual reaches MLP-only's error ({res['mlp']:.5f}) with "
        f"{s['smallest_n_residual_reaches_mlp_full']} samples "
        f"(fraction {s['fraction_of_data']} of MLP-only's {s['n_train']})"
    )
    print("seconds:", {k: round(v, 1) for k, v in s["seconds"].items()})


if __name__ == "__main__":
    main()
