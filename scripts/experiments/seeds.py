"""Several seeds for the headline scripts: ``--seeds``, and a metric's mean, spread and worst case.

A figure from one seed says what one random excitation, noise draw and network initialisation
gave; the scripts that print the README's and the docs' figures take ``--seeds`` and print, for
each metric, the mean, the sample standard deviation, the best and the worst seed, and the ratio
worst / best, so a claim that holds on some seeds only shows it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

__all__ = [
    "parse_seeds",
    "for_each_seed",
    "summarize",
    "format_summary",
    "summary_lines",
    "seeds_help",
]


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0,1,2"``, ``"0-4"`` or a mix (``"0-2,7"``) as a tuple of distinct ints, in order."""
    seeds: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            span = range(int(lo), int(hi) + 1) if sep else (int(lo),)
        except ValueError:
            raise ValueError(f"--seeds: {part!r} is not an int or a range a-b") from None
        if not span:
            raise ValueError(f"--seeds: the range {part!r} is empty")
        seeds.extend(s for s in span if s not in seeds)
    if not seeds:
        raise ValueError(f"--seeds: no seed in {text!r}")
    return tuple(seeds)


def for_each_seed(
    seeds: Sequence[int], fn: Callable[[int, Path | None], object], out: Path | None = None
) -> dict[int, object]:
    """``{seed: fn(seed, folder)}`` in order. With one seed ``folder`` is ``out``; with several,
    ``out / f"seed_{seed}"``, and a line ``=== seed N`` is printed before each run."""
    results = {}
    for seed in seeds:
        folder = out
        if len(seeds) > 1:
            print(f"\n=== seed {seed}", flush=True)
            folder = None if out is None else Path(out) / f"seed_{seed}"
        results[seed] = fn(seed, folder)
    return results


def summarize(values: Mapping[int, float], *, lower_is_better: bool = True) -> dict:
    """Mean, sample std, best and worst (with their seeds) and max / min of ``{seed: value}``."""
    if not values:
        raise ValueError("no values to summarise")
    items = sorted((seed, float(v)) for seed, v in values.items())
    xs = [v for _, v in items]
    n = len(xs)
    mean = sum(xs) / n
    std = math.sqrt(sum((x - mean) ** 2 for x in xs) / (n - 1)) if n > 1 else 0.0
    low, high = min(items, key=lambda kv: kv[1]), max(items, key=lambda kv: kv[1])
    best, worst = (low, high) if lower_is_better else (high, low)
    return {
        "n": n,
        "mean": mean,
        "std": std,
        "best": best[1],
        "best_seed": best[0],
        "worst": worst[1],
        "worst_seed": worst[0],
        "max_over_min": high[1] / low[1] if low[1] > 0 else math.inf,
    }


def format_summary(name: str, values: Mapping[int, float], *, lower_is_better: bool = True) -> str:
    """One line: ``name: mean m, std s over n seeds; best b (seed i), worst w (seed j), max/min r``."""
    s = summarize(values, lower_is_better=lower_is_better)
    return (
        f"{name}: mean {s['mean']:.4g}, std {s['std']:.2g} over {s['n']} seeds; best "
        f"{s['best']:.4g} (seed {s['best_seed']}), worst {s['worst']:.4g} (seed "
        f"{s['worst_seed']}), max/min {s['max_over_min']:.2f}"
    )


def summary_lines(table: Mapping[str, Mapping[int, float]], **kw) -> list[str]:
    """`format_summary` of each metric of ``{metric: {seed: value}}``."""
    return [format_summary(name, values, **kw) for name, values in table.items()]


def seeds_help(default: str) -> str:
    """The ``--seeds`` option's help text."""
    return f"seeds, e.g. 0-4 or 0,3,7 (default {default}); several print mean, spread and worst"
