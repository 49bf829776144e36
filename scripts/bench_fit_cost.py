"""What a Bayesian JFA fit costs on the cells of Fig. 2: iterations, E-step equivalents and the
bound reached, per cell and variant.

    python scripts/bench_fit_cost.py                  # input SNR 2, seeds 0-1, N = 1000, d = 100
    python scripts/bench_fit_cost.py --snr 5 --seeds 0 1 2
    python scripts/bench_fit_cost.py --quick          # one cell, one seed

Every Fig. 2 cell (r redundant, u irrelevant inputs; `torchjfa.experiments.fig2.SCENARIOS`) is
drawn by `torchjfa.experiments.synthetic.make_problem` and fitted by `BayesianJFA` at its
defaults in the six Bayesian variants of the figure: the seed's (input noise learned), the
noise known, and the noise from the repeated inputs, each with ``ard="shared"`` and
``ard="output"``. Printed per fit: iterations, E-step equivalents (``n_estep_``, the cost in
``d x d`` mat-vecs: `torchjfa.estimators._jfa_fit.Result`), whether it converged, and the
bound; then the mean and the worst count per cell, and over all fits (issue 19's goal: at most
600 on every cell at input SNR 2). ``--save F`` writes the rows as JSON, ``--compare F`` prints
each fit's bound against those of an earlier run (a different optimiser can end at another
optimum: the difference says which is higher).
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from torchjfa.estimators import BayesianJFA
from torchjfa.experiments.fig2 import SCENARIOS
from torchjfa.experiments.synthetic import make_problem

VARIANTS = (
    ("seed's", "none", "shared"),
    ("seed's, ARD w_z", "none", "output"),
    ("known", "known", "shared"),
    ("known, ARD w_z", "known", "output"),
    ("repeats", "repeats", "shared"),
    ("repeats, ARD w_z", "repeats", "output"),
)


def _noise(p, kind: str):
    if kind == "known":
        return p.input_noise
    if kind == "repeats":
        return (p.X_train - p.X_train_repeat).var(0) / 2
    return None


def run(snr: float, seeds, n: int, cells, variants, max_iter: int) -> list[dict]:
    rows = []
    for r, u in cells:
        for seed in seeds:
            p = make_problem(r, u, input_snr=snr, n_train=n, n_test=10, seed=seed)
            for name, kind, ard in variants:
                est = BayesianJFA(input_noise=_noise(p, kind), ard=ard, max_iter=max_iter)
                t0 = time.perf_counter()
                est.fit(p.X_train, p.y_train)
                rows.append(
                    {
                        "cell": f"r={r} u={u}",
                        "seed": seed,
                        "variant": name,
                        "n_iter": int(est.n_iter_),
                        "n_estep": int(est.n_estep_),
                        "converged": bool(est.converged_),
                        "bound": float(est.lower_bound_[-1]),
                        "seconds": time.perf_counter() - t0,
                    }
                )
    return rows


def _print(rows: list[dict], earlier: dict | None) -> None:
    head = f"{'cell':<12} {'seed':>4} {'variant':<18} {'iter':>6} {'E-step eq.':>10} conv {'bound':>14}"
    print(head + ("  vs earlier" if earlier else ""))
    for row in rows:
        line = (
            f"{row['cell']:<12} {row['seed']:>4} {row['variant']:<18} {row['n_iter']:>6} "
            f"{row['n_estep']:>10} {'yes ' if row['converged'] else 'NO  '} {row['bound']:>14.4f}"
        )
        key = (row["cell"], row["seed"], row["variant"])
        if earlier and key in earlier:
            line += f"  {row['bound'] - earlier[key]:+10.3f}"
        print(line)
    print("\nper cell: mean and worst E-step equivalents, fits converged")
    cells = dict.fromkeys(row["cell"] for row in rows)
    for cell in list(cells) + ["all"]:
        sel = [row for row in rows if cell in ("all", row["cell"])]
        counts = [row["n_estep"] for row in sel]
        conv = sum(row["converged"] for row in sel)
        print(
            f"  {cell:<12} mean {sum(counts) / len(counts):8.0f}   worst {max(counts):6d}   "
            f"converged {conv}/{len(sel)}   {sum(row['seconds'] for row in sel):6.1f} s"
        )
    if earlier:
        diffs = [
            row["bound"] - earlier[(row["cell"], row["seed"], row["variant"])]
            for row in rows
            if (row["cell"], row["seed"], row["variant"]) in earlier
        ]
        if diffs:
            print(
                f"bound vs earlier: mean {sum(diffs) / len(diffs):+.3f}, lowest {min(diffs):+.3f}, "
                f"highest {max(diffs):+.3f} nats over {len(diffs)} fits"
            )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--snr", type=float, default=2.0, help="input SNR (2 or 5 in the paper)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--n", type=int, default=1000, help="training rows (the paper's 1000)")
    ap.add_argument("--max-iter", type=int, default=20_000)
    ap.add_argument("--quick", action="store_true", help="one cell, one seed, two variants")
    ap.add_argument("--save", help="write the rows as JSON to this file")
    ap.add_argument("--compare", help="a JSON file of an earlier run to compare bounds with")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    cells, variants, seeds = SCENARIOS, VARIANTS, args.seeds
    if args.quick:
        cells, variants, seeds = SCENARIOS[1:2], VARIANTS[::3], seeds[:1]
    rows = run(args.snr, seeds, args.n, cells, variants, args.max_iter)
    earlier = None
    if args.compare:
        with open(args.compare) as f:
            earlier = {(r["cell"], r["seed"], r["variant"]): r["bound"] for r in json.load(f)}
    _print(rows, earlier)
    if args.save:
        with open(args.save, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
