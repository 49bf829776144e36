"""Benchmark: the cost of gradients through `InverseDynamics`, backward time over forward time.

For each dtype (float64, float32) and batch size (1, 256, 10000), in one run on this machine,
with the Panda arm (7 revolute joints, 77 parameters) by default:

* ``infer``: ``dynamics(q, qd, qdd)`` under ``torch.no_grad`` (the compiled C++ regressor where
  a compiler exists; the reference point);
* for two gradient targets, ``theta`` (theta trainable, the states plain data: the regressor
  needs no gradient of its own, so the forward pass still runs the compiled kernel) and
  ``theta+states`` (q, qd and qdd require grad too: the forward pass runs the torch regressor
  with autograd), the forward ``dynamics(q, qd, qdd)`` with its graph, then
  ``loss.backward()`` of ``loss = sum(tau^2)``;
* the ratios backward / forward and (forward + backward) / infer.

Times are the best of ``--repeats`` after one warm-up call. Where the ``theta+states`` ratio at
batch 256 exceeds 5, the backward pass is profiled (``torch.profiler``) and its most expensive
operators are printed, to show where the time goes.

    python scripts/bench_gradients.py                       # batches 1, 256, 10000
    python scripts/bench_gradients.py --batches 256 --repeats 3 --threads 1
    python scripts/bench_gradients.py --threads 1 --write-docs   # also into docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import time

import _benchmarks_page as page
import torch

import torchjfa.robots
from torchjfa.dynamics import InverseDynamics, RigidBodyModel

TARGETS = ("theta", "theta+states")


def _best(fn, repeats: int) -> float:
    fn()  # warm-up: kernels compiled, constants cached, memory touched
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _states(model: RigidBodyModel, batch: int, dtype: torch.dtype, seed: int):
    g = torch.Generator().manual_seed(seed)
    return [
        torch.randn(batch, model.n_dof, generator=g, dtype=torch.float64).to(dtype) for _ in "qva"
    ]


def _time_target(idyn: InverseDynamics, states, target: str, repeats: int) -> tuple[float, float]:
    """Best forward and best backward seconds for one gradient target."""
    leaves = [s.clone().requires_grad_(target == "theta+states") for s in states]

    def forward() -> torch.Tensor:
        return idyn(*leaves).square().sum()

    def backward(loss: torch.Tensor) -> None:
        idyn.zero_grad(set_to_none=True)
        for v in leaves:
            v.grad = None
        loss.backward()

    t_fwd = _best(forward, repeats)
    backward(forward())  # warm-up
    t_bwd = float("inf")
    for _ in range(repeats):
        loss = forward()
        t = time.perf_counter()
        backward(loss)
        t_bwd = min(t_bwd, time.perf_counter() - t)
    return t_fwd, t_bwd


def _profile_backward(idyn: InverseDynamics, states, top: int = 8) -> str:
    leaves = [s.clone().requires_grad_(True) for s in states]
    loss = idyn(*leaves).square().sum()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        loss.backward()
    return prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=top)


def run(batches=(1, 256, 10_000), repeats: int = 5, robot: str = "panda_arm", threads: int = 0):
    """Time forward and backward passes; return a list of result dicts (also printed).

    Args:
        batches: batch sizes.
        repeats: timed calls per measurement (the best is kept).
        robot: a robot of `torchjfa.robots.available`.
        threads: torch threads (0 keeps torch's default).
    """
    if threads > 0:
        torch.set_num_threads(threads)
    model = RigidBodyModel.from_urdf(torchjfa.robots.path(robot))
    print(
        f"{robot}: {model.n_dof} joints, {model.n_params} parameters, "
        f"{torch.get_num_threads()} torch threads"
    )
    idyn = InverseDynamics(model, trainable="unconstrained")
    head = (
        f"{'dtype':<8} {'batch':>6} {'target':<13} {'infer ms':>9} {'fwd ms':>9} "
        f"{'bwd ms':>9} {'bwd/fwd':>8} {'(f+b)/infer':>11}"
    )
    print(head)
    print("-" * len(head))
    rows, profiles = [], []
    for dtype in (torch.float64, torch.float32):
        for batch in batches:
            states = _states(model, batch, dtype, seed=batch)
            with torch.no_grad():
                t_inf = _best(lambda s=states: idyn(*s), repeats)
            for target in TARGETS:
                t_fwd, t_bwd = _time_target(idyn, states, target, repeats)
                row = {
                    "dtype": str(dtype).removeprefix("torch."),
                    "batch": batch,
                    "target": target,
                    "infer_s": t_inf,
                    "forward_s": t_fwd,
                    "backward_s": t_bwd,
                    "ratio": t_bwd / t_fwd,
                    "train_over_infer": (t_fwd + t_bwd) / t_inf,
                }
                rows.append(row)
                print(
                    f"{row['dtype']:<8} {batch:>6} {target:<13} {1e3 * t_inf:>9.3f} "
                    f"{1e3 * t_fwd:>9.3f} {1e3 * t_bwd:>9.3f} {row['ratio']:>8.2f} "
                    f"{row['train_over_infer']:>11.2f}"
                )
                if batch == 256 and target == "theta+states" and row["ratio"] > 5:
                    profiles.append((row["dtype"], _profile_backward(idyn, states)))
    for dtype, table in profiles:
        print(f"\nbackward at batch 256, {dtype}, theta+states (ratio > 5): the top operators")
        print(table)
    return rows


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--batches", type=int, nargs="+", default=[1, 256, 10_000], help="batch sizes")
    p.add_argument("--repeats", type=int, default=5, help="timed calls (the best is kept)")
    p.add_argument(
        "--robot", default="panda_arm", choices=torchjfa.robots.available(), help="the robot"
    )
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    return page.add_option(p)


def main(argv=None) -> list[dict]:
    args = parser().parse_args(argv)
    with page.recording("bench_gradients", "bench_gradients", args.write_docs, argv):
        return run(tuple(args.batches), args.repeats, args.robot, args.threads)


if __name__ == "__main__":
    main()
