"""Benchmark: the batched regressor against Pinocchio and MuJoCo, per sample, on the Panda.

For each batch size, in one run on this machine:

* torchjfa ``RigidBodyModel.regressor`` (float64 and float32), samples per second, best of
  ``--repeats``; the output ``(B, 9, 99)`` is allocated by each call;
* Pinocchio ``computeJointTorqueRegressor`` called sample by sample from Python (the
  benchmark-only extra ``pin``), both discarding each result and storing it into a preallocated
  ``(B, 9, 90)`` array (the same job as a batched regressor);
* MuJoCo ``mj_inverse`` sample by sample (torques, not a regressor: a reference point).

It prints the ratios torchjfa / Pinocchio and the peak resident memory, and checks first that
Pinocchio's model is the same robot: ``Y_pin @ pi_pin`` against ``Y @ nominal_theta``.

    python scripts/bench_regressor.py                 # batches 1e3, 1e4, 1e5
    python scripts/bench_regressor.py --batches 1000 --repeats 1   # quick
    python scripts/bench_regressor.py --threads 0     # torch's default thread count

On a machine shared with other work, torch's multi-threaded kernels can be far slower than one
thread (OpenMP threads wait for busy cores); the default here is one thread.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

import torchjfa.robots
from torchjfa.dynamics import RigidBodyModel


def _best(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run(
    batches=(1_000, 10_000, 100_000), repeats: int = 3, seed: int = 0, threads: int | None = None
):
    """Run the benchmark and return a list of result dicts (also printed)."""
    import mujoco
    import pinocchio as pin

    if threads is not None:
        torch.set_num_threads(threads)
    path = torchjfa.robots.path("panda")
    model = RigidBodyModel.from_urdf(path)
    pm = pin.buildModelFromUrdf(path)
    pd = pm.createData()
    pi_pin = np.concatenate([pm.inertias[k].toDynamicParameters() for k in range(1, pm.njoints)])
    text = open(path, encoding="utf-8").read()
    start = text.index("<robot")
    end = text.index(">", start) + 1
    mj_xml = (
        text[:end]
        + '<mujoco><compiler discardvisual="true" fusestatic="false"/></mujoco>'
        + text[end:]
    )
    mm = mujoco.MjModel.from_xml_string(mj_xml)
    md = mujoco.MjData(mm)
    n = model.n_dof
    assert pm.nv == n and mm.nv == n

    rng = np.random.default_rng(seed)
    # sanity check: the same robot in Pinocchio
    qs, qds, qdds = (rng.standard_normal((50, n)) for _ in range(3))
    tau_pin = np.stack(
        [
            pin.computeJointTorqueRegressor(pm, pd, a, b, c) @ pi_pin
            for a, b, c in zip(qs, qds, qdds, strict=True)
        ]
    )
    tau_me = (model.regressor(qs, qds, qdds) @ model.nominal_theta).numpy()
    diff = float(np.abs(tau_pin - tau_me).max())
    print(f"same robot: max |Y_pin pi_pin - Y theta| = {diff:.2e} N m over 50 random states")
    print(f"torch threads: {torch.get_num_threads()}")

    results = []
    for B in batches:
        q, qd, qdd = (rng.standard_normal((B, n)) for _ in range(3))
        row = {"batch": B}
        for dtype in (torch.float64, torch.float32):
            tq, tqd, tqdd = (torch.as_tensor(v, dtype=dtype) for v in (q, qd, qdd))
            model.regressor(tq[:10], tqd[:10], tqdd[:10])  # warm-up
            t = _best(lambda tq=tq, tqd=tqd, tqdd=tqdd: model.regressor(tq, tqd, tqdd), repeats)
            row[f"torchjfa_{str(dtype)[6:]}"] = B / t

        def pin_discard(q=q, qd=qd, qdd=qdd, B=B):
            for i in range(B):
                pin.computeJointTorqueRegressor(pm, pd, q[i], qd[i], qdd[i])

        def pin_store(q=q, qd=qd, qdd=qdd, B=B):
            out = np.empty((B, n, 10 * n))
            for i in range(B):
                out[i] = pin.computeJointTorqueRegressor(pm, pd, q[i], qd[i], qdd[i])

        def mj(q=q, qd=qd, qdd=qdd, B=B):
            for i in range(B):
                md.qpos[:] = q[i]
                md.qvel[:] = qd[i]
                md.qacc[:] = qdd[i]
                mujoco.mj_inverse(mm, md)

        row["pinocchio"] = B / _best(pin_discard, repeats)
        row["pinocchio_store"] = B / _best(pin_store, repeats)
        row["mujoco_inverse"] = B / _best(mj, repeats)
        row["peak_rss_mb"] = _peak_rss_mb()
        results.append(row)
        print(
            f"B={B:>7d}  samples/s: torchjfa f64 {row['torchjfa_float64']:>10.0f}  "
            f"f32 {row['torchjfa_float32']:>10.0f} | pinocchio {row['pinocchio']:>9.0f} "
            f"(storing {row['pinocchio_store']:>9.0f}) | mj_inverse {row['mujoco_inverse']:>9.0f}"
        )
        print(
            f"           ratios: f64/pin {row['torchjfa_float64'] / row['pinocchio']:.2f}  "
            f"f64/pin_store {row['torchjfa_float64'] / row['pinocchio_store']:.2f}  "
            f"f32/pin {row['torchjfa_float32'] / row['pinocchio']:.2f}  "
            f"f64/mj_inverse {row['torchjfa_float64'] / row['mujoco_inverse']:.2f}  "
            f"| peak RSS so far {row['peak_rss_mb']:.0f} MB"
        )
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1_000, 10_000, 100_000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads; 1 (default) compares like with like against the single-threaded "
        "Pinocchio and MuJoCo loops; 0 keeps torch's default",
    )
    args = parser.parse_args()
    threads = None if args.threads == 0 else args.threads
    run(tuple(args.batches), repeats=args.repeats, seed=args.seed, threads=threads)
