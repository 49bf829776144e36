"""Cost of identification against the number of regression rows N, in bounded memory.

For N from 10^4 to 10^7 rows of d = 77 columns (the 7-DoF head's regressor width), synthetic
noisy-input rows ``x = A z + noise``, ``y = (A z)^T theta + noise`` are generated on the fly in
chunks (so 10^7 x 77 never sits in memory), and each measurement runs in a fresh subprocess
whose peak resident memory (``ru_maxrss``) is reported:

- ``lstsq``: ``numpy.linalg.lstsq`` on the full matrix (built first, not timed), only while
  the matrix is below ``--lstsq-cap-gb``;
- ``xtx``: one pass forming ``X^T X`` (``torch.addmm`` per chunk): the floor of any method
  that reads the data;
- ``bjfa``: the streaming Bayesian JFA path of `torchjfa.identification.fit`: `Moments.update` per chunk,
  then ``BayesianJFA(fit_intercept=False).fit_moments`` (the Newton optimiser; time per
  iteration = fit time / ``n_iter_``); the once-per-process warm-up (a first fit before the
  timed one) is printed apart and not counted;
- ``idle``: a process that only imports torch and torchjfa (the memory floor).

Times exclude generating the rows (measured and subtracted per chunk). Prints the ratios
``bjfa end to end / lstsq``, ``bjfa / xtx pass`` and the fit's time per iteration at each N, and
saves a log-log plot. Usage::

    python scripts/bench_scale.py            # 10^4 .. 10^7 rows, a few minutes
    python scripts/bench_scale.py --quick    # smoke run, 10^4 and 3 10^4 rows
    python scripts/bench_scale.py --write-docs   # also into docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import _benchmarks_page as page
import numpy as np
import torch

D = 77
FULL_NS = (10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000, 10_000_000)
QUICK_NS = (10_000, 30_000)


def _chunks(n: int, d: int, chunk: int, seed: int):
    """Yield ``(X, y, seconds spent generating)`` chunks of a fixed random linear model."""
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(d, d, generator=g, dtype=torch.float64) / d**0.5 + torch.eye(
        d, dtype=torch.float64
    )
    theta = torch.randn(d, generator=g, dtype=torch.float64)
    for s in range(0, n, chunk):
        t0 = time.perf_counter()
        c = min(chunk, n - s)
        Xt = torch.randn(c, d, generator=g, dtype=torch.float64) @ A
        X = Xt + 0.1 * torch.randn(c, d, generator=g, dtype=torch.float64)
        y = Xt @ theta + 0.1 * torch.randn(c, generator=g, dtype=torch.float64)
        yield X, y, time.perf_counter() - t0


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def measure(method: str, n: int, *, d: int = D, chunk: int = 65_536, seed: int = 0) -> dict:
    """One measurement in this process (call it in a fresh process for its peak memory)."""
    import torchjfa  # noqa: F401  (the memory floor includes the library)
    from torchjfa.estimators import BayesianJFA
    from torchjfa.stats import Moments

    out = {"method": method, "n": n, "d": d, "threads": torch.get_num_threads()}
    if method == "lstsq":
        X = np.empty((n, d))
        y = np.empty(n)
        s = 0
        for Xc, yc, _ in _chunks(n, d, chunk, seed):
            X[s : s + Xc.shape[0]] = Xc.numpy()
            y[s : s + Xc.shape[0]] = yc.numpy()
            s += Xc.shape[0]
        t0 = time.perf_counter()
        np.linalg.lstsq(X, y, rcond=None)
        out["seconds"] = time.perf_counter() - t0
    elif method == "xtx":
        xtx = torch.zeros(d, d, dtype=torch.float64)
        t0, gen = time.perf_counter(), 0.0
        for X, _, tg in _chunks(n, d, chunk, seed):
            xtx.addmm_(X.T, X)
            gen += tg
        out["seconds"] = time.perf_counter() - t0 - gen
    elif method == "bjfa":
        # the first fit of a process warms torch's kernels up: a fixed cost, measured here and
        # kept out of the timings
        t0 = time.perf_counter()
        BayesianJFA(max_iter=10).fit(*next(_chunks(200, d, 200, seed + 1))[:2])
        out["load_seconds"] = time.perf_counter() - t0
        m = Moments.zeros(d)
        t0, gen = time.perf_counter(), 0.0
        for X, y, tg in _chunks(n, d, chunk, seed):
            m.update(X, y)
            gen += tg
        out["pass_seconds"] = time.perf_counter() - t0 - gen
        t1 = time.perf_counter()
        est = BayesianJFA(fit_intercept=False).fit_moments(m)
        out["fit_seconds"] = time.perf_counter() - t1
        out["n_iter"] = int(est.n_iter_)
        out["stop_reason"] = str(getattr(est, "stop_reason_", "?"))
        out["converged"] = bool(getattr(est, "converged_", False))
        out["seconds"] = out["pass_seconds"] + out["fit_seconds"]
        out["seconds_per_iter"] = out["fit_seconds"] / max(out["n_iter"], 1)
    elif method != "idle":
        raise ValueError(f"unknown method {method!r}")
    out["peak_mb"] = _peak_mb()
    return out


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _isolated(method: str, n: int, d: int, chunk: int, seed: int, threads: int) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", method, "--n", str(n)]
    cmd += ["--d", str(d), "--chunk", str(chunk), "--seed", str(seed)]
    env = dict(os.environ, **{k: str(threads) for k in _THREAD_VARS})
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"{method} at N={n} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def run(
    ns=FULL_NS,
    *,
    d: int = D,
    chunk: int = 65_536,
    lstsq_cap_gb: float = 1.0,
    seed: int = 0,
    isolate: bool = True,
    threads: int = 1,
    plot: str | None = None,
) -> list[dict]:
    """Measure every method at every N; print a table and the ratios; optionally plot.

    Args:
        ns: numbers of rows.
        d: columns.
        chunk: rows per generated chunk (the streaming memory is O(chunk d + d^2)).
        lstsq_cap_gb: skip lstsq when the full matrix (N d 8 bytes) exceeds this, GB.
        seed: data seed.
        isolate: each measurement in a fresh subprocess (needed for peak memory).
        threads: BLAS/OpenMP threads of every method (the same for all, so ratios are fair;
            applied through the environment of the subprocesses).
        plot: PNG path for the log-log plot, or None.

    Returns:
        One dict per N with the measurements of each method.
    """
    if isolate:
        meas = lambda m, n, d, c, s: _isolated(m, n, d, c, s, threads)
    else:
        meas = lambda m, n, d, c, s: measure(m, n, d=d, chunk=c, seed=s)
    idle = meas("idle", 0, d, chunk, seed)
    print(f"idle process (imports only): peak {idle['peak_mb']:.0f} MB")
    rows = []
    for n in ns:
        row = {"n": n, "idle_mb": idle["peak_mb"]}
        if n * d * 8 <= lstsq_cap_gb * 1e9:
            row["lstsq"] = meas("lstsq", n, d, chunk, seed)
        row["xtx"] = meas("xtx", n, d, chunk, seed)
        row["bjfa"] = meas("bjfa", n, d, chunk, seed)
        rows.append(row)
        _print_row(row)
    if plot:
        _plot(rows, plot)
        print(f"plot saved to {plot}")
    return rows


def _print_row(row: dict) -> None:
    b, x = row["bjfa"], row["xtx"]
    ls = row.get("lstsq")
    ls_txt = (
        f"lstsq {ls['seconds']:8.3f} s {ls['peak_mb']:7.0f} MB | "
        if ls
        else f"lstsq {'skipped':>8}   {'':>7}    | "
    )
    ratio_ls = f"{b['seconds'] / ls['seconds']:7.3f}" if ls else f"{'-':>7}"
    print(
        f"N={row['n']:>9,d} | {ls_txt}xtx pass {x['seconds']:7.3f} s | bjfa pass "
        f"{b['pass_seconds']:7.3f} s + fit {b['fit_seconds']:6.3f} s ({b['n_iter']} it., "
        f"converged {b['converged']}, "
        f"{b['stop_reason']}), {b['peak_mb']:6.0f} MB | bjfa/lstsq {ratio_ls} | "
        f"bjfa/xtx {b['seconds'] / x['seconds']:6.2f} | "
        f"fit {1e6 * b['seconds_per_iter']:6.1f} us/iter | "
        f"fit load {b['load_seconds']:.2f} s (once per process, not counted)"
    )


def _plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = np.array([r["n"] for r in rows], dtype=float)
    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(11, 4.2))
    ls = [(r["n"], r["lstsq"]) for r in rows if "lstsq" in r]
    if ls:
        ax_t.loglog([n for n, _ in ls], [m["seconds"] for _, m in ls], "o-", label="numpy lstsq")
        ax_m.loglog([n for n, _ in ls], [m["peak_mb"] for _, m in ls], "o-", label="numpy lstsq")
    series = {
        "one pass X^T X": [r["xtx"]["seconds"] for r in rows],
        "BJFA pass (Moments)": [r["bjfa"]["pass_seconds"] for r in rows],
        "BJFA fit": [r["bjfa"]["fit_seconds"] for r in rows],
        "BJFA end to end": [r["bjfa"]["seconds"] for r in rows],
    }
    for label, ys in series.items():
        ax_t.loglog(ns, ys, "s-" if "end" in label else ".--", label=label)
    ax_m.loglog(ns, [r["bjfa"]["peak_mb"] for r in rows], "s-", label="BJFA streaming")
    ax_m.loglog(ns, [r["xtx"]["peak_mb"] for r in rows], ".--", label="one pass X^T X")
    ax_m.axhline(rows[0]["idle_mb"], color="gray", lw=0.8, label="imports only")
    ax_t.set(xlabel="rows N (d = 77)", ylabel="seconds", title="time (data generation excluded)")
    ax_m.set(xlabel="rows N (d = 77)", ylabel="peak RSS, MB", title="peak memory (fresh process)")
    for ax in (ax_t, ax_m):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="smoke run: 1e4 and 3e4 rows")
    p.add_argument("--ns", type=float, nargs="+", help="numbers of rows (default 1e4 .. 1e7)")
    p.add_argument("--d", type=int, default=D, help="columns")
    p.add_argument("--chunk", type=int, default=65_536, help="rows per generated chunk")
    p.add_argument(
        "--lstsq-cap-gb", type=float, default=1.0, help="skip lstsq above this matrix size, GB"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the data")
    p.add_argument("--threads", type=int, default=1, help="BLAS threads of every method")
    p.add_argument(
        "--plot", help="PNG path (default docs/img/scale.png; none with --quick unless given)"
    )
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--n", type=int, help=argparse.SUPPRESS)
    return page.add_option(p)


def main(argv=None) -> list[dict] | None:
    a = parser().parse_args(argv)
    if a.worker:
        print(json.dumps(measure(a.worker, a.n, d=a.d, chunk=a.chunk, seed=a.seed)))
        return None
    ns = QUICK_NS if a.quick else tuple(int(v) for v in a.ns) if a.ns else FULL_NS
    with page.recording("bench_scale", "bench_scale", a.write_docs, argv, smoke=a.quick):
        return run(
            ns,
            d=a.d,
            chunk=a.chunk,
            lstsq_cap_gb=a.lstsq_cap_gb,
            seed=a.seed,
            threads=a.threads,
            plot=a.plot if a.plot is not None else (None if a.quick else "docs/img/scale.png"),
        )


if __name__ == "__main__":
    main()
