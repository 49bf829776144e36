"""Time the estimators of `torchjfa.estimators` end to end from raw data, against numpy lstsq.

    python scripts/bench_estimators.py            # N = 500,000 rows, d = 77 and d = 110
    python scripts/bench_estimators.py --quick    # a smoke run (N = 20,000, d = 20)
    python scripts/bench_estimators.py --write-docs   # also into docs/benchmarks.md

Data follow the paper's synthetic protocol (10 relevant inputs with a random covariance
seen with noise at input SNR 2, redundant inputs that are convex combinations of the noisy
relevant ones, irrelevant N(0, 1) inputs, output SNR 5), float64. Printed, all measured in the
same run on the same data: ``numpy.linalg.lstsq``; the single pass ``X^T X``; building
`Moments`; ``fit(X, y)`` of every estimator found in `torchjfa.estimators` (from raw data, so
each includes its own pass over the data); the time per Bayesian JFA iteration from moments at
N = 10^4 and N = 10^6 (it must not grow with N); and the ratios of the Bayesian JFA fit to
lstsq (target <= 0.3) and to the ``X^T X`` pass (target <= 3), with the iterations it ran, for
the seed's estimator and for the noise-informed variant (``input_noise`` = the noise each column
carries).
"""

from __future__ import annotations

import argparse
import time

import _benchmarks_page as page
import numpy as np
import torch

import torchjfa.estimators as estimators
from torchjfa.stats import Moments

F64 = torch.float64
_NAMES = ("OLS", "Ridge", "TLS", "PLS", "Lasso", "Stepwise", "JFA", "BayesianJFA")


def _setup(d: int, seed: int):
    """The protocol's fixed parts for ``d`` inputs: the generator after drawing them, the 10
    relevant inputs' covariance factor, the slopes, the noise variances and the mixing."""
    g = torch.Generator().manual_seed(seed)
    k = 10
    r = (d - k) // 3
    a = torch.randn(k, k, generator=g, dtype=F64)
    cov = a @ a.T / k
    chol = torch.linalg.cholesky(cov)
    b = torch.arange(1, k + 1, dtype=F64)
    noise_in = torch.diagonal(cov) / 2.0
    noise_out = float(b @ cov @ b) / 5.0
    mix = -torch.log(torch.rand(r, k, generator=g, dtype=F64))
    mix = mix / mix.sum(1, keepdim=True)
    return g, chol, b, noise_in, noise_out, mix


def column_noise(d: int, *, seed: int = 0) -> torch.Tensor:
    """The input-noise variance each column of `make_data` carries ``(d,)``: the relevant
    inputs' noise, a redundant input's ``sum_k mix_k^2 noise_k``, 0 for irrelevant inputs."""
    _, _, _, noise_in, _, mix = _setup(d, seed)
    u = d - 10 - mix.shape[0]
    return torch.cat([noise_in, (mix**2) @ noise_in, torch.zeros(u, dtype=F64)])


def make_data(n: int, d: int, *, seed: int = 0, chunk: int = 100_000):
    """Yield ``(X, y)`` chunks of the paper's protocol with ``d`` inputs (10 relevant)."""
    g, chol, b, noise_in, noise_out, mix = _setup(d, seed)
    k, u = 10, d - 10 - mix.shape[0]
    done = 0
    while done < n:
        m = min(chunk, n - done)
        t = torch.randn(m, k, generator=g, dtype=F64) @ chol.T
        x_rel = t + torch.randn(m, k, generator=g, dtype=F64) * noise_in.sqrt()
        X = torch.cat([x_rel, x_rel @ mix.T, torch.randn(m, u, generator=g, dtype=F64)], 1)
        y = t @ b + torch.randn(m, generator=g, dtype=F64) * noise_out**0.5
        yield X, y
        done += m


def _time(fn, repeat: int = 1) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def per_iteration(moments: Moments, n_iter: int) -> float:
    """Seconds per plain EM sweep of BayesianJFA fitted from ``moments``."""
    est = estimators.BayesianJFA(max_iter=n_iter, tol=0.0, coef_tol=0.0, method="em")
    t, est = _time(lambda: est.fit_moments(moments))
    return t / est.n_iter_


def run(
    *,
    n: int = 500_000,
    dims: tuple[int, ...] = (77, 110),
    n_small: int = 10_000,
    n_large: int = 1_000_000,
    iter_probe: int = 2000,
    repeat: int = 2,
    seed: int = 0,
) -> list[dict]:
    """Run the benchmark, print a table per ``d`` and return the measurements."""
    results = []
    available = [name for name in _NAMES if hasattr(estimators, name)]
    missing = [name for name in _NAMES if name not in available]
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, numpy {np.__version__}")
    if missing:
        print(f"estimators not in torchjfa.estimators (skipped): {', '.join(missing)}")
    # the first fit of a process warms torch's kernels up: a fixed cost, kept out of the timings
    X, y = next(make_data(200, 20, seed=seed))
    t, _ = _time(lambda: estimators.BayesianJFA(max_iter=10).fit(X, y))
    print(f"first Bayesian JFA fit in this process (warm-up): {t:.2f} s")
    for d in dims:
        results.append(_bench_one(n, d, available, n_small, n_large, iter_probe, repeat, seed))
    return results


def _bench_one(n, d, available, n_small, n_large, iter_probe, repeat, seed) -> dict:
    """Every measurement for one ``d``, on one data set."""
    X, y = (torch.cat(p) for p in zip(*make_data(n, d, seed=seed), strict=True))
    Xn, yn = X.numpy(), y.numpy()
    Moments.from_data(X[:1000], y[:1000])  # warm-up (first-call overheads)
    print(f"\nN = {n:,}, d = {d}, float64")
    row: dict = {"n": n, "d": d}
    row["lstsq"], _ = _time(lambda: np.linalg.lstsq(Xn, yn, rcond=None), repeat)
    row["xtx"], _ = _time(lambda: X.T @ X, repeat)
    row["moments"], _ = _time(lambda: Moments.from_data(X, y), repeat)
    print(f"  {'numpy.linalg.lstsq':34s} {row['lstsq']:8.3f} s")
    print(f"  {'X^T X (one pass)':34s} {row['xtx']:8.3f} s")
    print(f"  {'Moments.from_data':34s} {row['moments']:8.3f} s")
    fits = {}
    for name in available:
        est = getattr(estimators, name)()
        try:
            t, est = _time(lambda e=est: e.fit(X, y), repeat if name == "BayesianJFA" else 1)
        except (ValueError, RuntimeError) as exc:  # another estimator's limits, not ours
            print(f"  fit {name:30s}   failed: {exc}")
            continue
        fits[name] = t
        extra = ""
        if hasattr(est, "n_iter_"):
            extra = f"  ({est.n_iter_} iterations"
            if hasattr(est, "stop_reason_"):
                extra += f", converged {est.converged_}, stop: {est.stop_reason_}"
            extra += ")"
        if name == "BayesianJFA":
            row["bjfa_iter"], row["bjfa_stop"] = est.n_iter_, est.stop_reason_
        print(f"  fit {name:30s} {t:8.3f} s  {t / row['lstsq']:6.2f}x lstsq{extra}")
    # the noise-informed variant (the input noise each column carries, as the repeated periods
    # of a robot's excitation give it): the seed's estimator with psi_x known and held fixed
    noise = column_noise(d, seed=seed)
    t, est = _time(lambda: estimators.BayesianJFA(input_noise=noise).fit(X, y), repeat)
    row["bjfa_noise"] = t
    print(
        f"  fit {'BayesianJFA(input_noise=known)':30s} {t:8.3f} s  {t / row['lstsq']:6.2f}x lstsq"
        f"  ({est.n_iter_} iterations, stop: {est.stop_reason_})"
    )
    row["fits"] = fits
    # the iteration cost from moments must not depend on N
    small = Moments.from_chunks(make_data(n_small, d, seed=seed + 1))
    large = Moments.from_chunks(make_data(n_large, d, seed=seed + 2))
    row["iter_small"] = per_iteration(small, iter_probe)
    for method in ("em", "newton"):  # plain EM against the Newton optimiser: same moments
        t, e = _time(lambda m=method: estimators.BayesianJFA(method=m).fit_moments(small))
        print(
            f"  BayesianJFA N = {n_small:,}, {method}: {t:6.2f} s "
            f"= {t / row['iter_small']:.0f} EM sweeps of time, {e.n_iter_} iterations, "
            f"converged {e.converged_}, stop: {e.stop_reason_}, bound "
            f"{float(e.lower_bound_[-1]):.6g}"
        )
    row["iter_large"] = per_iteration(large, iter_probe)
    print(
        f"  BayesianJFA time per iteration: N = {n_small:,}: {1e6 * row['iter_small']:.1f} us, "
        f"N = {n_large:,}: {1e6 * row['iter_large']:.1f} us "
        f"(ratio {row['iter_large'] / row['iter_small']:.2f})"
    )
    if "BayesianJFA" in fits:
        r1, r2 = fits["BayesianJFA"] / row["lstsq"], fits["BayesianJFA"] / row["xtx"]
        row["ratio_lstsq"], row["ratio_xtx"] = r1, r2
        print(
            f"  BayesianJFA fit / lstsq = {r1:.3f} (target <= 0.3: "
            f"{'met' if r1 <= 0.3 else 'NOT met'})"
        )
        print(
            f"  BayesianJFA fit / X^T X pass = {r2:.2f} (target <= 3: "
            f"{'met' if r2 <= 3.0 else 'NOT met'}); {row['bjfa_iter']} iterations, "
            f"stopped by {row['bjfa_stop']}"
        )
    r1, r2 = row["bjfa_noise"] / row["lstsq"], row["bjfa_noise"] / row["xtx"]
    print(
        f"  BayesianJFA(input_noise=known) fit / lstsq = {r1:.3f} (target <= 0.3: "
        f"{'met' if r1 <= 0.3 else 'NOT met'}); / X^T X pass = {r2:.2f} (target <= 3: "
        f"{'met' if r2 <= 3.0 else 'NOT met'})"
    )
    return row


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--quick", action="store_true", help="smoke run: N = 20,000, d = 20")
    p.add_argument("--n", type=int, default=500_000, help="rows of the data")
    p.add_argument("--dims", type=int, nargs="+", default=[77, 110], help="input dimensions d")
    p.add_argument("--seed", type=int, default=0, help="seed of the data")
    return page.add_option(p)


def main(argv=None) -> list[dict]:
    args = parser().parse_args(argv)
    with page.recording(
        "bench_estimators", "bench_estimators", args.write_docs, argv, smoke=args.quick
    ):
        if args.quick:
            return run(
                n=20_000, dims=(20,), n_small=10_000, n_large=100_000, iter_probe=300, repeat=2
            )
        return run(n=args.n, dims=tuple(args.dims), seed=args.seed)


if __name__ == "__main__":
    main()
