"""Benchmark: the regressor's paths on a busy machine (other processes on every core).

    python scripts/bench_busy.py                  # batch 20,000, 7-DoF Panda arm, 2 torch threads
    python scripts/bench_busy.py --burners 0      # the same on an idle machine, for comparison

Starts ``--burners`` processes that spin on the CPU (default: one per core), then measures, in
the same run, samples per second of

* the torch path as it ran before 2026-12-01: `regressor_fast` with ``--threads`` intra-op
  threads (torch's default on this machine is the core count);
* the torch path now (``RigidBodyModel.regressor(..., compiled=False)``): its small ops on one
  intra-op thread;
* the compiled kernel (the default wherever a C++ compiler is found), ``--threads`` threads;

and prints the ratios to the first. Each figure is the best of ``--repeats`` calls. The burners
are stopped at the end (also on Ctrl-C).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time

import torch

import torchjfa
from torchjfa import RigidBodyModel
from torchjfa.dynamics._rnea_fast import regressor_fast


def _burn(stop) -> None:
    x = 0.0
    while not stop.is_set():
        for _ in range(100_000):
            x = x * 0.5 + 1.0


def _best(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def run(*, batch: int = 20_000, threads: int = 2, burners: int | None = None, repeats: int = 5):
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    g = torch.Generator().manual_seed(0)
    q, qd, qdd = (torch.randn(batch, model.n_dof, generator=g, dtype=torch.float64) for _ in "abc")
    out = torch.empty(batch, model.n_dof, model.n_params, dtype=torch.float64)
    consts = model._consts(torch.float64, q.device)
    paths = {
        f"torch path, {threads} intra-op threads (before)": lambda: regressor_fast(
            out, q, qd, qdd, consts, model.friction, chunk_size=1024
        ),
        "torch path, 1 intra-op thread (now)": lambda: model.regressor(
            q, qd, qdd, compiled=False, out=out
        ),
        "compiled kernel (the default)": lambda: model.regressor(
            q, qd, qdd, compiled=True, out=out
        ),
    }
    burners = os.cpu_count() if burners is None else burners
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    stop = mp.Event()
    procs = [mp.Process(target=_burn, args=(stop,), daemon=True) for _ in range(burners)]
    try:
        for fn in paths.values():
            fn()  # warm-up (and the kernel's build)
        for p in procs:
            p.start()
        time.sleep(0.5 if procs else 0.0)
        rates = {name: batch / _best(fn, repeats) for name, fn in paths.items()}
    finally:
        stop.set()
        for p in procs:
            p.join(timeout=5)
        torch.set_num_threads(previous)
    first = next(iter(rates.values()))
    print(f"panda_arm, batch {batch}, float64, torch threads {threads}, {burners} busy processes")
    for name, r in rates.items():
        print(f"  {name:44s} {r:10.0f} samples/s  {r / first:6.2f}x")
    return rates


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batch", type=int, default=20_000)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--burners", type=int, default=None, help="busy processes (default: cores)")
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args()
    run(batch=a.batch, threads=a.threads, burners=a.burners, repeats=a.repeats)
