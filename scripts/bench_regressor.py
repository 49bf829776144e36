"""Benchmark: the batched regressor against Pinocchio and MuJoCo, per sample, on a 7-DoF arm.

The robot is ``torchjfa/robots/panda_arm.urdf`` (the Panda with its finger joints fixed: 7
revolute joints, 77 parameters with viscous friction); Pinocchio and MuJoCo load the same file.
For each batch size, in one run on this machine:

* torchjfa ``RigidBodyModel.regressor(..., compiled=False)``, the torch path (float64 and
  float32) with 1 and with 2 torch threads set (``--threads``; the torch path runs its small ops
  on one intra-op thread whatever is set, so the two differ only by noise), samples per second,
  best of ``--repeats``; the output ``(B, 7, 77)`` is allocated by each call;
* Pinocchio ``computeJointTorqueRegressor`` called sample by sample from Python (the
  benchmark-only extra ``pin``), both discarding each result and storing it into a preallocated
  ``(B, 7, 70)`` array (the same job as a batched regressor);
* MuJoCo ``mj_inverse`` sample by sample (torques, not a regressor: a reference point);
* torchjfa ``RigidBodyModel.regressor(..., compiled=True)`` (the C++ kernel generated for the
  robot, ``torchjfa.dynamics._codegen``), float64 and float32, 1 and 2 threads, the output
  allocated by each call as above; its generation and compile time, in an empty kernel cache
  (a temporary ``TORCHJFA_CACHE_DIR``), is printed first and not part of the timings.

It prints the ratios torchjfa / Pinocchio and the peak resident memory, checks first that
Pinocchio's model is the same robot (``Y_pin @ pi_pin`` against ``Y @ nominal_theta``) and that
the compiled kernel (the default wherever a C++ compiler is found) gives the torch path's regressor, and ends with a summary table.

    python scripts/bench_regressor.py                 # batches 1e3, 1e4, 1e5; 1 and 2 threads
    python scripts/bench_regressor.py --batches 1000 --repeats 1   # quick
    python scripts/bench_regressor.py --threads 1 --robot panda    # one thread, 9-DoF Panda
    python scripts/bench_regressor.py --repeats 3 --write-docs     # the summary into the docs

On a machine shared with other work, torch's multi-threaded kernels can be slower than one
thread (OpenMP threads wait for busy cores); Pinocchio and MuJoCo run on one thread.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import _benchmarks_page as page
import numpy as np
import torch

import torchjfa.robots
from torchjfa.dynamics import RigidBodyModel


def _best(fn, repeats: int, clock=time.perf_counter) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = clock()
        fn()
        best = min(best, clock() - t)
    return best


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _robot_path(robot: str) -> str:
    if robot in torchjfa.robots.available():
        return torchjfa.robots.path(robot)
    path = Path(torchjfa.robots.__file__).resolve().parent / f"{robot}.urdf"
    if not path.is_file():
        raise ValueError(f"unknown robot {robot!r}: no {path}")
    return str(path)


def run(
    batches=(1_000, 10_000, 100_000),
    repeats: int = 3,
    seed: int = 0,
    threads=(1, 2),
    robot: str = "panda_arm",
):
    """Run the benchmark and return a list of result dicts (also printed).

    Args:
        batches: batch sizes.
        repeats: timings per measurement; the best is kept.
        seed: seed of the random states.
        threads: torch thread counts to time the regressor with (0: torch's default).
        robot: a URDF shipped in ``torchjfa/robots`` (``panda_arm``: 7 DoF; ``panda``: 9 DoF).
    """
    import mujoco
    import pinocchio as pin

    path = _robot_path(robot)
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
    print(f"{robot}: {n} DoF, {model.n_params} parameters, output (B, {n}, {model.n_params})")
    print(f"same robot: max |Y_pin pi_pin - Y theta| = {diff:.2e} N m over 50 random states")
    default_threads = torch.get_num_threads()
    # the compiled kernel, built in an empty cache so that the time is a full build
    previous = os.environ.get("TORCHJFA_CACHE_DIR")
    with tempfile.TemporaryDirectory(prefix="torchjfa-bench-kernels-") as kernels:
        os.environ["TORCHJFA_CACHE_DIR"] = kernels
        try:
            build = {dt: model.compile_regressor(dt) for dt in (torch.float64, torch.float32)}
        finally:
            if previous is None:
                del os.environ["TORCHJFA_CACHE_DIR"]
            else:
                os.environ["TORCHJFA_CACHE_DIR"] = previous
    Y_c = model.regressor(qs, qds, qdds, compiled=True)
    Y_d = model.regressor(qs, qds, qdds, compiled=False)
    rel = float((Y_c - Y_d).abs().max() / Y_d.abs().max())
    print(
        f"compiled kernel: generated and compiled in {build[torch.float64]:.1f} s (float64), "
        f"{build[torch.float32]:.1f} s (float32), empty cache; not in the timings below. "
        f"max |Y_compiled - Y| / max |Y| = {rel:.1e}"
    )

    results = []
    for B in batches:
        q, qd, qdd = (rng.standard_normal((B, n)) for _ in range(3))
        row = {"batch": B}
        for nt in threads:
            torch.set_num_threads(nt if nt > 0 else default_threads)
            for dtype in (torch.float64, torch.float32):
                tq, tqd, tqdd = (torch.as_tensor(v, dtype=dtype) for v in (q, qd, qdd))
                model.regressor(tq[:10], tqd[:10], tqdd[:10], compiled=False)  # warm-up
                t = _best(
                    lambda tq=tq, tqd=tqd, tqdd=tqdd: model.regressor(
                        tq, tqd, tqdd, compiled=False
                    ),
                    repeats,
                )
                row[f"torchjfa_{str(dtype)[6:]}_t{nt}"] = B / t

                def compiled(tq=tq, tqd=tqd, tqdd=tqdd):
                    model.regressor(tq, tqd, tqdd, compiled=True)

                compiled()  # warm-up
                row[f"compiled_{str(dtype)[6:]}_t{nt}"] = B / _best(compiled, repeats)
                if nt == threads[0] and dtype == torch.float64:
                    row["cpu_compiled_float64"] = B / _best(compiled, repeats, time.process_time)
                if nt == 1 and dtype == torch.float64:
                    row["cpu_torchjfa_float64"] = B / _best(
                        lambda tq=tq, tqd=tqd, tqdd=tqdd: model.regressor(
                            tq, tqd, tqdd, compiled=False
                        ),
                        repeats,
                        time.process_time,
                    )
                    reuse = torch.empty(B, n, model.n_params, dtype=dtype)

                    def into(tq=tq, tqd=tqd, tqdd=tqdd, reuse=reuse):
                        model.regressor(tq, tqd, tqdd, out=reuse, compiled=False)

                    into()  # first touch of the reused output
                    row["torchjfa_float64_out"] = B / _best(into, repeats)
                    row["cpu_torchjfa_float64_out"] = B / _best(into, repeats, time.process_time)
                    del reuse
        torch.set_num_threads(default_threads)

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
        row["cpu_pinocchio"] = B / _best(pin_discard, repeats, time.process_time)
        row["pinocchio_store"] = B / _best(pin_store, repeats)
        row["mujoco_inverse"] = B / _best(mj, repeats)
        row["peak_rss_mb"] = _peak_rss_mb()
        results.append(row)
        print(
            f"B={B:>7d}  samples/s: pinocchio {row['pinocchio']:>9.0f} "
            f"(storing {row['pinocchio_store']:>9.0f}) | mj_inverse {row['mujoco_inverse']:>9.0f}"
            f" | peak RSS so far {row['peak_rss_mb']:.0f} MB"
        )
        if "torchjfa_float64_out" in row:
            pin_wall, pin_cpu = row["pinocchio"], row["cpu_pinocchio"]
            print(
                f"  torchjfa 1 thread f64 into a reused out=: {row['torchjfa_float64_out']:>10.0f}"
                f" (f64/pin {row['torchjfa_float64_out'] / pin_wall:.2f}) | CPU-time ratios "
                f"(process_time, robust to other load): f64/pin "
                f"{row['cpu_torchjfa_float64'] / pin_cpu:.2f}, out= f64/pin "
                f"{row['cpu_torchjfa_float64_out'] / pin_cpu:.2f} (pinocchio {pin_cpu:.0f}/s CPU)"
            )
        for path in ("torchjfa", "compiled"):
            for nt in threads:
                f64, f32 = row[f"{path}_float64_t{nt}"], row[f"{path}_float32_t{nt}"]
                last = (
                    f"f64/mj_inverse {f64 / row['mujoco_inverse']:.2f}"
                    if path == "torchjfa"
                    else f"f64/default {f64 / row[f'torchjfa_float64_t{nt}']:.2f}"
                )
                print(
                    f"  {path} {nt or default_threads} thread(s): f64 {f64:>10.0f}  "
                    f"f32 {f32:>10.0f} | ratios f64/pin {f64 / row['pinocchio']:.2f}  "
                    f"f64/pin_store {f64 / row['pinocchio_store']:.2f}  "
                    f"f32/pin {f32 / row['pinocchio']:.2f}  {last}"
                )
        if "cpu_compiled_float64" in row:
            print(
                f"  compiled CPU-time ratio f64/pin ({threads[0] or default_threads} thread(s)): "
                f"{row['cpu_compiled_float64'] / row['cpu_pinocchio']:.2f}"
            )
    _summary(results, threads, default_threads, build)
    return results


def _k(x: float) -> str:
    return f"{x / 1e3:.0f}k"


def _summary(results, threads, default_threads, build) -> None:
    """The table of docs/benchmarks.md: samples per second, ratios to Pinocchio."""
    names = [str(nt or default_threads) for nt in threads]
    head = ["batch", "Pinocchio /s", "mj_inverse /s"]
    for kind in ("default", "compiled"):
        head += [f"{kind} f64, {t} thr" for t in names] + [f"{kind} f32, {names[-1]} thr"]
    head += [f"f64/Pinocchio default ({' / '.join(names)} thr)", "compiled", "peak RSS"]
    print(
        f"\nsummary (samples/s; compiled kernel build {build[torch.float64]:.1f} s f64, "
        f"{build[torch.float32]:.1f} s f32, excluded):"
    )
    print("| " + " | ".join(head) + " |")
    print("| " + " | ".join(["---"] * len(head)) + " |")
    for row in results:
        pin_rate = row["pinocchio"]
        cells = [f"{row['batch']:.0e}".replace("+0", ""), _k(pin_rate), _k(row["mujoco_inverse"])]
        for kind in ("torchjfa", "compiled"):
            cells += [_k(row[f"{kind}_float64_t{nt}"]) for nt in threads]
            cells.append(_k(row[f"{kind}_float32_t{threads[-1]}"]))
        for kind in ("torchjfa", "compiled"):
            cells.append(
                " / ".join(f"{row[f'{kind}_float64_t{nt}'] / pin_rate:.2f}" for nt in threads)
            )
        cells.append(f"{row['peak_rss_mb'] / 1024:.1f} GB")
        print("| " + " | ".join(cells) + " |")


def summary_markdown(printed: str) -> str:
    """The summary table of a run's output (what ``--write-docs`` writes): from its title on."""
    at = printed.rfind("\nsummary (")
    return printed[at + 1 :] if at >= 0 else page.fenced(printed)


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--batches", type=int, nargs="+", default=[1_000, 10_000, 100_000], help="batch sizes"
    )
    p.add_argument("--repeats", type=int, default=3, help="timed calls (the best is kept)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random states")
    p.add_argument(
        "--threads",
        type=int,
        nargs="+",
        default=[1, 2],
        help="torch thread counts to time the regressor with (default 1 and 2; 0: torch's "
        "default); Pinocchio and MuJoCo loops run on one thread",
    )
    p.add_argument("--robot", default="panda_arm", help="panda_arm (7 DoF) or panda (9 DoF)")
    return page.add_option(p)


def main(argv=None) -> list[dict]:
    args = parser().parse_args(argv)
    with page.recording(
        "bench_regressor", "bench_regressor", args.write_docs, argv, markdown=summary_markdown
    ):
        return run(
            tuple(args.batches),
            repeats=args.repeats,
            seed=args.seed,
            threads=tuple(args.threads),
            robot=args.robot,
        )


if __name__ == "__main__":
    main()
