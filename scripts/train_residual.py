"""Identified dynamics + learned residual vs identified-only vs MLP-only on the simulated head.

    python scripts/train_residual.py                 # the full run (about 10 minutes on 2 CPUs)
    python scripts/train_residual.py --seeds 0-4     # five seeds: mean, spread and worst case
    python scripts/train_residual.py --smoke         # tiny sizes, a few seconds of training
    python scripts/train_residual.py --identify-only --seeds 0-4   # the identified model alone

Steps: simulate a training and a held-out test log of the 7-DoF head with its unmodeled effects
on (armature, dry friction, joint stiffness), each on its own random excitation (a long period,
so the training log does not repeat itself). Then, for each training size n, on the first n
training samples only: identify the rigid-body parameters (per-joint weighted least squares,
`torchjfa.identification.residual_joint_weights`, then the projection onto physically consistent
parameters), save them with `torchjfa.io.save_identified`, and train with Lightning an MLP on
(q, qd, qdd) alone and the identified model plus a residual (theta frozen): the joint-local
`JointResidual` and, with ``--residuals joint,mlp``, a whole-state MLP residual too. Report the
held-out torque nMSE (measured inputs, noise-free target torques) of every model at every n, and
plot the data-efficiency curves. Every network is trained for the same number of gradient steps.

The excitations draw their harmonics from ``--min-harmonic``..100 of 0.02 Hz (0.2-2 Hz by
default; `torchjfa.sim.random_trajectory`). With the full band 1..100 (the runs before
2026-12-01) a joint that drew a low harmonic barely moved, and a test log that moved it fast was
extrapolation: seed 2's identified model was 15x worse than seed 0's. Each run prints where the
test log's motion goes beyond the training log's (`torchjfa.data.coverage`).
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
from experiments.seeds import for_each_seed, parse_seeds, seeds_help, summary_lines
from torch.utils.data import DataLoader, RandomSampler

import torchjfa.io
from torchjfa.data import coverage
from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import (
    NoiseChoice,
    Options,
    fit,
    make_consistent,
    residual_joint_weights,
)
from torchjfa.learning import ResidualDynamicsModule, StateTorqueDataset, log_tensors, nmse
from torchjfa.sim import generate_log, load_robot, model_path, random_trajectory

#: the identification of the rigid-body parameters: least squares on the weighted equations
#: (the weights given), the virtual parametrisation, no description prior (in simulation the
#: description is the truth), no jackknife, no bias correction
IDENTIFY = Options(
    weighting="none",
    jackknife=0,
    bias_correction=0,
    parametrization="virtual",
    description_prior=None,
)

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
    residuals: tuple[str, ...] = ("joint",),
    steps: int = 2000,
    batch_size: int = 256,
    hidden: tuple[int, ...] = (64, 64),
    joint_hidden: tuple[int, ...] = (16, 16),
    lr: float = 3e-3,
    weight_decay: float = 1e-2,
    base_frequency: float = 0.02,
    min_harmonic: int = 10,
    friction: tuple[str, ...] = ("viscous",),
    out_dir: str = "residual_results",
    seed: int = 0,
    plot: bool = True,
) -> dict:
    """Run the comparison; returns (and writes to ``out_dir/results.json``) the nMSEs.

    ``residuals``: the residual networks on top of the identified model, ``"joint"``
    (`JointResidual`, hidden ``joint_hidden``) and/or ``"mlp"`` (an `MLP` of the whole state,
    hidden ``hidden``, as the MLP-only model).
    """
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
            min_harmonic=min_harmonic,
            seed=s,
        )
        logs[name] = generate_log(robot, n_samples=n, trajectory=traj, seed=s)
        logs[name].save(out / f"{robot}_{name}.npz")
    t_sim = time.perf_counter() - t0

    model = RigidBodyModel.from_mjcf(model_path(robot), friction=friction)
    q, qd, qdd, tau = log_tensors(logs["train"], "measured", model.joint_names)
    t2 = time.perf_counter()
    Y = model.regressor(q, qd, qdd)  # once, for every residual model
    t_reg = time.perf_counter() - t2
    tensors = {"q": q, "qd": qd, "qdd": qdd, "tau": tau, "Y": Y}
    qt, qdt, qddt, taut = log_tensors(logs["test"], "measured_inputs", model.joint_names)
    with torch.no_grad():
        Yt = model.regressor(qt, qdt, qddt)

    beyond = coverage((q, qd, qdd), (qt, qdt, qddt), joint_names=model.joint_names).warnings()
    for line in beyond:
        print(f"  test log beyond the training log's motion: {line}", flush=True)
    sizes = tuple(n for n in sizes if n <= n_train)
    kinds = ("mlp", *(f"residual_{r}" for r in residuals)) if residuals else ()
    curves = {k: {} for k in ("identified", *kinds)}
    t_id = t_train = 0.0
    for n in sizes:
        # identification from the first n samples only: weighted least squares, projected
        t1 = time.perf_counter()
        part = {"q": q[:n], "qd": qd[:n], "qdd": qdd[:n], "tau": tau[:n]}
        weights = residual_joint_weights(model, part)
        result = make_consistent(fit(model, part, NoiseChoice.given(weights), IDENTIFY), IDENTIFY)
        t_id += time.perf_counter() - t1
        id_path = out / f"{robot}_identified_{n}.npz"
        torchjfa.io.save_identified(
            id_path,
            model,
            result.theta,
            estimator="weighted OLS + projection (virtual)",
            n_samples=n,
            joint_weights=weights,
        )
        idyn = torchjfa.io.load_identified(id_path)  # the file's model, as every user loads it
        with torch.no_grad():
            curves["identified"][n] = float(nmse(Yt @ idyn.theta, taut))
            per_joint = nmse(Yt @ idyn.theta, taut, per_joint=True).tolist()
        print(f"  n={n:6d} {'identified':12s} test nMSE {curves['identified'][n]:.5f}", flush=True)
        t3 = time.perf_counter()
        for kind in kinds:
            if kind == "mlp":
                kw = {"n_dof": model.n_dof, "hidden": hidden}
            else:
                r = kind.removeprefix("residual_")
                kw = {
                    "identified": str(id_path),
                    "residual_kind": r,
                    "hidden": joint_hidden if r == "joint" else hidden,
                }
            module = ResidualDynamicsModule(lr=lr, weight_decay=weight_decay, seed=seed, **kw)
            net = _train(module, tensors, n, steps=steps, batch_size=batch_size, seed=seed)
            with torch.no_grad():
                pred = net(qt, qdt, qddt, regressor=None if kind == "mlp" else Yt)
            curves[kind][n] = float(nmse(pred, taut))
            print(f"  n={n:6d} {kind:12s} test nMSE {curves[kind][n]:.5f}", flush=True)
        t_train += time.perf_counter() - t3
    n_full = sizes[-1]
    results = {k: c[n_full] for k, c in curves.items()}
    best = min((k for k in kinds if k != "mlp"), key=lambda k: results[k], default=None)
    reach = [n for n in sizes if best and curves[best][n] <= results["mlp"]]
    summary = {
        "robot": robot,
        "n_train": n_train,
        "n_test": n_test,
        "steps": steps,
        "weight_decay": weight_decay,
        "identification": "weighted OLS + projection, on the first n samples",
        "friction": list(friction),
        "min_harmonic": min_harmonic,
        "test_beyond_training": beyond,
        "nmse_at_full_data": results,
        "identified_per_joint": dict(zip(model.joint_names, per_joint, strict=True)),
        "curves": {k: {str(n): v for n, v in c.items()} for k, c in curves.items()},
        "best_residual": best,
        "residual_beats_both": bool(best)
        and results[best] < min(results["identified"], results["mlp"]),
        "smallest_n_residual_reaches_mlp_full": min(reach) if reach else None,
        "fraction_of_data": (min(reach) / n_full) if reach else None,
        "seconds": {"simulate": t_sim, "identify": t_id, "regressor": t_reg, "train": t_train},
    }
    (out / "results.json").write_text(json.dumps(summary, indent=2))
    if plot and kinds:
        _plot(summary, sizes, curves, out)
    return summary


_LABELS = {
    "identified": "identified only",
    "mlp": "MLP only",
    "residual_joint": "identified + joint residual",
    "residual_mlp": "identified + MLP residual",
}


def _plot(summary, sizes, curves, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = summary["nmse_at_full_data"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    a.bar([_LABELS[k].replace(" + ", " +\n") for k in res], list(res.values()))
    a.set_yscale("log")
    a.set_ylabel("held-out torque nMSE")
    a.set_title(f"n = {sizes[-1]} training samples")
    for kind, curve in curves.items():
        style = "ks--" if kind == "identified" else "o-"
        b.loglog(sizes, [curve[n] for n in sizes], style, label=_LABELS[kind], mfc="none")
    b.axhline(res["mlp"], color="gray", ls=":", label="MLP only at full data")
    b.set_xlabel("training samples (identification and training)")
    b.set_ylabel("held-out torque nMSE")
    b.legend()
    fig.tight_layout()
    fig.savefig(out / "residual_dynamics.png", dpi=120)
    plt.close(fig)


def _print_one(s: dict) -> None:
    res = s["nmse_at_full_data"]
    best = s["best_residual"]
    print(f"held-out torque nMSE with {s['n_train']} training samples ({s['robot']}):")
    joints = ", ".join(f"{j} {v:.3g}" for j, v in s["identified_per_joint"].items())
    if best is None:
        print(f"  {_LABELS['identified']:28s} {res['identified']:.5f}  (per joint: {joints})")
        return
    for k, v in res.items():
        print(f"  {_LABELS[k]:28s} {v:.5f}   ratio to {_LABELS[best]}: {v / res[best]:.2f}")
    print(f"{_LABELS[best]} beats both identified only and MLP only: {s['residual_beats_both']}")
    print(
        f"{_LABELS[best]} reaches MLP only's error ({res['mlp']:.5f}) with "
        f"{s['smallest_n_residual_reaches_mlp_full']} samples "
        f"(fraction {s['fraction_of_data']} of MLP only's {s['n_train']})"
    )
    print("seconds:", {k: round(v, 1) for k, v in s["seconds"].items()})


def _print_seeds(runs: dict[int, dict], out: Path) -> dict:
    """The per-seed table and each metric's mean, spread and worst seed."""
    kinds = list(next(iter(runs.values()))["nmse_at_full_data"])
    table = {
        _LABELS[k]: {seed: r["nmse_at_full_data"][k] for seed, r in runs.items()} for k in kinds
    }
    head = " | ".join(f"{_LABELS[k]:>14s}" for k in kinds)
    print(
        f"\nheld-out torque nMSE at full data, per seed\nseed | {head} | MLP-only's error reached with"
    )
    for seed, r in runs.items():
        vals = " | ".join(f"{r['nmse_at_full_data'][k]:14.4f}" for k in kinds)
        frac = r["fraction_of_data"]
        reached = "-" if len(kinds) == 1 else "never" if frac is None else f"{frac:.0%} of the data"
        print(f"{seed:4d} | {vals} | {reached}")
    lines = summary_lines(table)
    for line in lines:
        print(line)
    never = [seed for seed, r in runs.items() if r["fraction_of_data"] is None]
    beats = [seed for seed, r in runs.items() if r["residual_beats_both"]]
    if len(kinds) > 1:
        print(f"the best residual beats both identified only and MLP only on seeds {beats}")
    if never and len(kinds) > 1:
        print(f"the best residual never reaches MLP only's full-data error on seeds {never}")
    summary = {
        "seeds": list(runs),
        "nmse_at_full_data": {k: {str(s): v for s, v in t.items()} for k, t in table.items()},
        "summary": lines,
        "fraction_of_data": {str(s): r["fraction_of_data"] for s, r in runs.items()},
        "test_beyond_training": {str(s): r["test_beyond_training"] for s, r in runs.items()},
    }
    (out / "seeds.json").write_text(json.dumps(summary, indent=2))
    return summary


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", default="head", choices=["head", "arm"])
    p.add_argument("--n-train", type=int, default=20_000)
    p.add_argument("--n-test", type=int, default=5_000)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out-dir", default="residual_results")
    p.add_argument("--seeds", default="0", help=seeds_help("0"))
    p.add_argument("--seed", type=int, default=None, help="one seed (the same as --seeds N)")
    p.add_argument("--weight-decay", type=float, default=1e-2, help="Adam's, both models")
    p.add_argument(
        "--min-harmonic", type=int, default=10, help="lowest harmonic of the 0.02 Hz excitations"
    )
    p.add_argument(
        "--friction", default="viscous", help="identified friction terms: viscous,coulomb,offset"
    )
    p.add_argument(
        "--residuals",
        default="joint",
        help="residual networks on the identified model, comma-separated: joint, mlp",
    )
    p.add_argument(
        "--identify-only", action="store_true", help="the identified model alone, no networks"
    )
    p.add_argument("--smoke", action="store_true", help="tiny sizes (a quick check)")
    args = p.parse_args()
    seeds = (args.seed,) if args.seed is not None else parse_seeds(args.seeds)
    kw = dict(
        robot=args.robot,
        n_train=args.n_train,
        n_test=args.n_test,
        steps=args.steps,
        weight_decay=args.weight_decay,
        min_harmonic=args.min_harmonic,
        friction=tuple(f.strip() for f in args.friction.split(",") if f.strip()),
        residuals=()
        if args.identify_only
        else tuple(r.strip() for r in args.residuals.split(",") if r.strip()),
    )
    if args.smoke:
        kw.update(n_train=1000, n_test=500, steps=100, sizes=(100, 1000))
    out = Path(args.out_dir)

    def one(seed, folder):
        result = run(**kw, seed=seed, out_dir=str(folder))
        _print_one(result)
        return result

    runs = for_each_seed(seeds, one, out)
    if len(seeds) > 1:
        _print_seeds(runs, out)


if __name__ == "__main__":
    main()
