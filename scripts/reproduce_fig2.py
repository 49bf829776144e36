"""Reproduce the seed paper's Fig. 2 (synthetic data) for every estimator of the library.

    python scripts/reproduce_fig2.py                 # the full protocol: 4 scenarios x 2 SNRs x 10 trials
    python scripts/reproduce_fig2.py --quick         # a smoke run (seconds)
    python scripts/reproduce_fig2.py --snrs 2 --out results/fig2_snr2   # one SNR per process,
    python scripts/reproduce_fig2.py --snrs 5 --out results/fig2_snr5   # run side by side, then
    python scripts/reproduce_fig2.py --merge results/fig2_snr*/fig2.json --out results/fig2
    python scripts/reproduce_fig2.py --seeds 0-2     # the protocol three times, other data sets

Prints the table (method x scenario x input SNR, clean and noisy test, mean and spread of nMSE,
fit time), the improvement of the best Bayesian method over the best other one, and writes
``fig2.csv``, ``fig2.json`` and ``fig2.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from experiments import fig2
from experiments.seeds import for_each_seed, parse_seeds, seeds_help, summary_lines


def format_table(summary: list[dict]) -> str:
    """The summary as a fixed-width text table, one block per (scenario, SNR)."""
    lines = []
    blocks: dict[tuple, list[dict]] = {}
    for s in summary:
        blocks.setdefault((s["redundant"], s["irrelevant"], s["input_snr"]), []).append(s)
    for (r, u, snr), cells in blocks.items():
        lines.append(f"\nr={r}, u={u}, input SNR {snr:g}")
        lines.append(
            f"  {'method':36s} {'clean nMSE':>18s} {'noisy nMSE':>18s} {'fit s':>8s} {'iters':>7s}"
        )
        methods = list(dict.fromkeys(c["method"] for c in cells))
        for m in methods:
            by_test = {c["test"]: c for c in cells if c["method"] == m}
            clean, noisy = by_test["clean"], by_test["noisy"]
            iters = f"{clean['n_iter_mean']:7.0f}" if clean["n_iter_mean"] >= 0 else "      -"
            lines.append(
                f"  {m:36s} {clean['nmse_mean']:9.4f} ± {clean['nmse_std']:6.4f}"
                f" {noisy['nmse_mean']:9.4f} ± {noisy['nmse_std']:6.4f}"
                f" {clean['fit_s_mean']:8.3f} {iters}"
            )
    return "\n".join(lines)


def report(rows: list[dict], methods, out: Path) -> dict:
    """Summarise rows, print the table and the improvement, write CSV/JSON/PNG to ``out``."""
    summary = fig2.summarize(rows)
    gains = fig2.improvement_table(summary, methods=methods, test="clean")
    print(format_table(summary))
    print("\nBest Bayesian method vs best other method, noiseless (clean) test, nMSE reduction:")
    for g in gains:
        print(
            f"  r={g['redundant']:2d} u={g['irrelevant']:2d} SNR {g['input_snr']:g}: "
            f"{g['best_bayes']} {g['best_bayes_nmse']:.4f} vs {g['best_other']} "
            f"{g['best_other_nmse']:.4f}: {100 * g['reduction']:+.1f}%"
        )
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "fig2.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(summary[0]))
        writer.writeheader()
        writer.writerows(summary)
    (out / "fig2.json").write_text(
        json.dumps({"summary": summary, "improvement": gains, "rows": rows}, indent=1)
    )
    fig2.plot(summary, out / "fig2.png")
    print(f"\nwrote {out / 'fig2.csv'}, {out / 'fig2.json'}, {out / 'fig2.png'}")
    return {"summary": summary, "improvement": gains}


def run(
    *,
    quick: bool = False,
    n_trials: int = 10,
    n_train: int = 1000,
    input_snrs: tuple[float, ...] = (2.0, 5.0),
    scenarios: tuple[tuple[int, int], ...] = fig2.SCENARIOS,
    lasso_options: dict | None = None,
    seed: int = 0,
    out: Path = Path("results/fig2"),
    progress: bool = True,
) -> dict:
    """Run the protocol (or its smoke version), print and write the results."""
    if quick:
        kwargs = dict(
            scenarios=((0, 20), (20, 0)),
            input_snrs=(2.0,),
            n_trials=2,
            n_train=200,
            n_test=200,
            methods=fig2.default_methods(bayes_max_iter=300),
        )
    else:
        kwargs = dict(
            n_trials=n_trials,
            n_train=n_train,
            n_test=n_train,
            input_snrs=input_snrs,
            scenarios=scenarios,
            methods=fig2.default_methods(lasso_options=lasso_options),
        )
    rows = fig2.run(seed=seed, progress=progress, **kwargs)
    return report(rows, kwargs.get("methods"), out)


def summarize_seeds(gains: dict[int, list[dict]]) -> list[str]:
    """Per cell, the best Bayesian method's nMSE reduction over the best other one across seeds
    (each seed a fresh set of trials): mean, spread and worst; the lines printed."""
    lines = []
    seeds = list(gains)
    for k, cell in enumerate(gains[seeds[0]]):
        name = f"r={cell['redundant']:2d} u={cell['irrelevant']:2d} SNR {cell['input_snr']:g}"
        red = {s: 100 * gains[s][k]["reduction"] for s in seeds}
        lines.append("  " + summary_lines({f"{name}, reduction %": red}, lower_is_better=False)[0])
        held = [s for s in seeds if gains[s][k]["reduction"] >= 0.10]
        lines.append(f"    >= 10% on {len(held)} of {len(seeds)} seeds")
    for line in lines:
        print(line)
    return lines


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: 2 scenarios, 1 SNR, 2 trials"
    )
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--n-train", type=int, default=1000)
    parser.add_argument("--seeds", default="0", help=seeds_help("0"))
    parser.add_argument("--snrs", type=float, nargs="+", default=[2.0, 5.0], help="input SNRs")
    parser.add_argument(
        "--scenarios", type=int, nargs="+", help="redundant/irrelevant pairs, e.g. 60 30 90 0"
    )
    parser.add_argument(
        "--lasso-max-iter", type=int, help="cap on LASSO's coordinate-descent sweeps per penalty"
    )
    parser.add_argument("--out", type=Path, default=Path("results/fig2"))
    parser.add_argument(
        "--merge",
        type=Path,
        nargs="+",
        help="summarise the rows of these fig2.json files together (e.g. one run per SNR) "
        "instead of running anything",
    )
    args = parser.parse_args()
    if args.merge:
        rows = [r for path in args.merge for r in json.loads(path.read_text())["rows"]]
        report(rows, None, args.out)
    else:
        seeds = parse_seeds(args.seeds)
        gains = for_each_seed(
            seeds,
            lambda seed, folder: run(
                quick=args.quick,
                n_trials=args.trials,
                n_train=args.n_train,
                input_snrs=tuple(args.snrs),
                scenarios=tuple(zip(args.scenarios[::2], args.scenarios[1::2], strict=True))
                if args.scenarios
                else fig2.SCENARIOS,
                lasso_options=None
                if args.lasso_max_iter is None
                else {"max_iter": args.lasso_max_iter},
                seed=seed,
                out=folder,
            )["improvement"],
            args.out,
        )
        if len(seeds) > 1:
            print("\nbest Bayesian vs best other method over the seeds (clean test):")
            lines = summarize_seeds(gains)
            (args.out / "seeds.txt").write_text("\n".join(lines) + "\n")
