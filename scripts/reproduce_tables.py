"""Reproduce the seed paper's Tables I and II (identification + computed torque) in simulation.

    python scripts/reproduce_tables.py                  # both robots, 500,000 samples each
    python scripts/reproduce_tables.py --smoke          # both robots end to end in tiny sizes
    python scripts/reproduce_tables.py --n-samples 100000 --robots head   # a smaller run
    python scripts/reproduce_tables.py --n-samples 100000 --seeds 0-4    # five seeds, summarised

Prints, per robot, the table in the paper's layout (RMS position / velocity / feedback command
of computed-torque control on a held-out trajectory, FAILURE where it fails, true parameters as
reference) with held-out torque nMSE and fit / projection time, then the issue's goal check.
Writes ``tables.csv``, ``tables.json`` and ``tracking_<robot>.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

from experiments import robots as exp
from experiments.seeds import for_each_seed, parse_seeds, seeds_help, summary_lines

from torchjfa.identification import joint_terms

NUMBERS = {"head": "I", "arm": "II"}  # the paper's table numbers


def run(
    *,
    robots: tuple[str, ...] = ("head", "arm"),
    smoke: bool = False,
    n_samples: int | None = None,
    test_duration: float | None = None,
    seed: int = 0,
    out: Path = Path("results/robots"),
    weighting: str = "none",
    friction: tuple[str, ...] = ("viscous",),
    progress: bool = True,
) -> dict:
    """Run the experiment, print the tables and the goal check, write CSV / JSON / PNG."""
    start = time.perf_counter()
    results = exp.run(
        robots,
        smoke=smoke,
        n_samples=n_samples,
        test_duration=test_duration,
        seed=seed,
        progress=progress,
        weighting=weighting,
        friction=friction,
    )
    wall = time.perf_counter() - start
    out.mkdir(parents=True, exist_ok=True)
    for robot, res in results.items():
        print(f"\nTable {NUMBERS.get(robot, '')}. {exp.format_table(res)}")
        print("stage times (s): " + ", ".join(f"{k} {v:.1f}" for k, v in res.timings.items()))
        exp.plot_tracking(res, out / f"tracking_{robot}.png")
    goal = exp.goal_check(results)
    print(
        "\nGoal: best Bayesian pipeline >= 10% lower RMS feedback than ridge + GD on every robot,"
    )
    print("and no FAILURE of it on any robot:")
    for robot, g in goal["robots"].items():
        print(
            f"  {robot}: ridge {g['ridge']:.4f} N m, best Bayesian {g['best_bayes']} "
            f"{g['best_bayes_feedback']:.4f} N m, reduction {100 * g['reduction']:+.1f}% -> "
            f"{'met' if g['met'] else 'NOT met'}"
        )
    print(f"goal {'MET' if goal['met'] else 'NOT MET'}; total wall time {wall:.0f} s")
    rows = [r for res in results.values() for r in res.rows]
    with open(out / "tables.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    payload = {
        "wall_s": wall,
        "goal": goal,
        "robots": {
            robot: {
                "settings": res.settings,
                "timings": res.timings,
                "rows": res.rows,
                "warnings": {m: list(i.warnings) for m, i in res.identified.items()},
            }
            for robot, res in results.items()
        },
    }
    (out / "tables.json").write_text(json.dumps(payload, indent=1, default=str))
    print(f"wrote {out / 'tables.csv'}, {out / 'tables.json'} and tracking_*.png")
    return {"results": results, "goal": goal, "wall_s": wall}


def summarize_seeds(runs: dict[int, dict]) -> list[str]:
    """Per robot and method over the seeds: nMSE (clean) and RMS feedback (successes only),
    the failures, and the goal's reduction; the lines printed."""
    lines = []
    seeds = list(runs)
    for robot in runs[seeds[0]]["results"]:
        per = {s: {r["method"]: r for r in runs[s]["results"][robot].rows} for s in seeds}
        lines.append(f"{robot}, {len(seeds)} seeds {seeds}:")
        for method, row in per[seeds[0]].items():
            nm = {s: per[s][method]["nmse_clean"] for s in seeds}
            ok = {s: per[s][method]["rms_feedback"] for s in seeds if per[s][method]["success"]}
            failed = [s for s in seeds if per[s][method]["success"] is False]
            label = row["label"]
            lines.append("  " + summary_lines({f"{label}, nMSE clean": nm})[0])
            if ok:
                lines.append("  " + summary_lines({f"{label}, RMS feedback (N m)": ok})[0])
            if failed:
                lines.append(f"  {label}: FAILURE on seeds {failed}")
        red = {s: runs[s]["goal"]["robots"][robot]["reduction"] for s in seeds}
        met = [s for s in seeds if runs[s]["goal"]["robots"][robot]["met"]]
        lines.append(
            f"  goal (best Bayesian >= 10% below ridge + GD): met on seeds {met}; reductions "
            + ", ".join(f"{100 * red[s]:+.1f}% (seed {s})" for s in seeds)
        )
    for line in lines:
        print(line)
    return lines


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--smoke", action="store_true", help="tiny sizes, both robots, < 1 min")
    parser.add_argument("--robots", nargs="+", default=["head", "arm"], choices=["head", "arm"])
    parser.add_argument("--n-samples", type=int, default=None, help="training samples per robot")
    parser.add_argument("--test-duration", type=float, default=None, help="control run, s")
    parser.add_argument("--seeds", default="0", help=seeds_help("0"))
    parser.add_argument(
        "--weighting",
        choices=["none", "residual"],
        default="none",
        help="weight each joint's equations by its inverse OLS residual variance",
    )
    parser.add_argument(
        "--friction",
        type=joint_terms,
        default=("viscous",),
        help="the identification model's joint terms, comma separated (the paper's: viscous; "
        "viscous,armature models the simulated robots' armature)",
    )
    parser.add_argument("--out", type=Path, default=Path("results/robots"))
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    args = parser.parse_args()
    seeds = parse_seeds(args.seeds)
    runs = for_each_seed(
        seeds,
        lambda seed, folder: run(
            robots=tuple(args.robots),
            smoke=args.smoke,
            n_samples=args.n_samples,
            test_duration=args.test_duration,
            seed=seed,
            out=folder,
            weighting=args.weighting,
            friction=args.friction,
            progress=not args.quiet,
        ),
        args.out,
    )
    if len(seeds) > 1:
        print("\nover the seeds:")
        lines = summarize_seeds(runs)
        (args.out / "seeds.txt").write_text("\n".join(lines) + "\n")
