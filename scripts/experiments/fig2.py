"""The seed paper's synthetic comparison (Fig. 2), run for every estimator of the library.

`run` draws trials with `experiments.synthetic.make_problem`, fits every method on
the noisy training set (hyper-parameters chosen on the training set only: GCV for ridge,
contiguous 5-fold cross-validation for PLS and LASSO, an F-test for stepwise) and scores
normalised MSE (`torchjfa.metrics.nmse`: MSE / var(y_test)) on a noiseless and a noisy test set. `summarize` averages over
trials and `plot` draws the grouped bar chart. ``scripts/reproduce_fig2.py`` and
``notebooks/fig2.ipynb`` are thin shells over these functions.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import torch

from torchjfa._util import progress_bar
from torchjfa.estimators import JFA, OLS, PLS, TLS, BayesianJFA, Lasso, Ridge, Stepwise
from torchjfa.metrics import nmse

from .synthetic import SyntheticProblem, make_problem

__all__ = [
    "Method",
    "default_methods",
    "run",
    "summarize",
    "improvement_table",
    "claim_table",
    "plot",
    "SCENARIOS",
    "PAPER_BASELINES",
    "CLAIM",
    "SEED_STRIDE",
]

#: (redundant, irrelevant) pairs of the paper; 10 relevant inputs make 100 in all
SCENARIOS = ((0, 90), (30, 60), (60, 30), (90, 0))
#: the paper's baselines: its claim is the best Bayesian method against the better of these
PAPER_BASELINES = ("OLS", "Stepwise")
#: the paper's claim: the best Bayesian method's clean-test nMSE at least 10 % below theirs
CLAIM = 0.10
#: seed ``s`` of `run` draws trial ``t`` with ``SEED_STRIDE * s + t``: seeds share no trial
SEED_STRIDE = 1000


@dataclass(frozen=True)
class Method:
    """A named way to fit a problem and get the coefficients used for each test set.

    ``fit(problem)`` returns ``(estimator, coef_clean, coef_noisy)``; intercepts come from the
    estimator (``intercept_``, or for the Bayesian model the intercept of the estimate used).
    """

    name: str
    fit: Callable[
        [SyntheticProblem], tuple[object, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]
    ]
    bayesian: bool = False


def _plain(factory: Callable[[], object]) -> Callable:
    def fit(p: SyntheticProblem):
        est = factory().fit(p.X_train, p.y_train)
        return est, est.coef_, est.intercept_, est.coef_, est.intercept_

    return fit


def _bayes(
    which: str,
    noise: Callable[[SyntheticProblem], torch.Tensor | None],
    max_iter: int,
    cache: dict | None = None,
    ard: str = "shared",
    n_starts: int | None = None,
) -> Callable:
    """A Bayesian JFA method; methods that share ``cache``, ``noise`` and ``ard`` share one fit
    per problem (eq. 3 and eq. 4 are two read-outs of the same fitted model)."""

    def fit(p: SyntheticProblem):
        key = (id(p), noise, ard)
        if cache is not None and key in cache and cache[key][0] is p:
            est, elapsed = cache[key][1:]
        else:
            start = time.perf_counter()
            kw = {} if n_starts is None else {"n_starts": n_starts}
            est = BayesianJFA(input_noise=noise(p), max_iter=max_iter, ard=ard, **kw)
            est.fit(p.X_train, p.y_train)
            elapsed = time.perf_counter() - start
            if cache is not None:
                cache.clear()  # one problem at a time
                cache[key] = (p, est, elapsed)
        fit.last_fit_s = elapsed
        if which == "eq3":  # the noisy-input predictor for both test sets
            return est, est.coef_noisy_, est.intercept_noisy_, est.coef_noisy_, est.intercept_noisy_
        # system identification: eq. (4) on noiseless inputs, eq. (3) on noisy inputs
        return est, est.coef_, est.intercept_, est.coef_noisy_, est.intercept_noisy_

    return fit


def _no_noise(p: SyntheticProblem) -> None:
    return None


def _known_noise(p: SyntheticProblem) -> torch.Tensor:
    return p.input_noise


def _noise_from_repeats(p: SyntheticProblem) -> torch.Tensor:
    return (p.X_train - p.X_train_repeat).var(0) / 2


def default_methods(
    *,
    bayes_max_iter: int = 100_000,
    lasso_options: dict | None = None,
    n_starts: int | None = None,
    paper_only: bool = False,
) -> list[Method]:
    """Every method of the comparison: the paper's baselines, TLS and ridge, JFA, and Bayesian
    JFA as written (eq. 3 and eq. 4) and noise-informed (true noise; noise from repeats), the
    latter with the paper's shared relevance prior and with ``ard="output"``.

    ``n_starts``: `BayesianJFA`'s number of starts (its default where None). ``paper_only``:
    only the methods of the paper's claim, the baselines `PAPER_BASELINES` and the Bayesian
    methods."""
    shared: dict = {}

    def bayes(which, noise, cache=None, ard="shared"):
        return _bayes(which, noise, bayes_max_iter, cache, ard=ard, n_starts=n_starts)

    others = [
        Method("OLS", _plain(OLS)),
        Method("Ridge (GCV)", _plain(Ridge)),
        Method("Stepwise", _plain(Stepwise)),
        Method("PLS (CV)", _plain(PLS)),
        Method("LASSO (CV)", _plain(lambda: Lasso(**(lasso_options or {})))),
        Method("TLS", _plain(TLS)),
        Method("JFA", _plain(JFA)),
    ]
    if paper_only:
        others = [m for m in others if m.name in PAPER_BASELINES]
    return others + [
        Method("Bayes JFA, eq. 3", bayes("eq3", _no_noise, shared), True),
        Method("Bayes JFA, eq. 4", bayes("eq4", _no_noise, shared), True),
        Method("Bayes JFA, noise from repeats", bayes("eq4", _noise_from_repeats), True),
        Method("Bayes JFA, known noise", bayes("eq4", _known_noise), True),
        Method(
            "Bayes JFA, repeats, ARD on w_z",
            bayes("eq4", _noise_from_repeats, ard="output"),
            True,
        ),
        Method(
            "Bayes JFA, known noise, ARD on w_z",
            bayes("eq4", _known_noise, ard="output"),
            True,
        ),
    ]


def _nmse(X: torch.Tensor, y: torch.Tensor, coef: torch.Tensor, intercept: torch.Tensor) -> float:
    """`torchjfa.metrics.nmse` of the linear model's predictions ``X coef + intercept`` of
    ``y``; ``X (n, d)``, ``y (n,)``."""
    return float(nmse(X @ coef.to(X) + intercept.to(X), y))


def run(
    *,
    scenarios: Sequence[tuple[int, int]] = SCENARIOS,
    input_snrs: Sequence[float] = (2.0, 5.0),
    n_trials: int = 10,
    n_train: int = 1000,
    n_test: int = 1000,
    methods: Iterable[Method] | None = None,
    seed: int = 0,
    progress: bool = False,
) -> list[dict]:
    """Run the protocol and return one row per (scenario, SNR, trial, method, test set).

    Each row: ``redundant``, ``irrelevant``, ``input_snr``, ``trial``, ``method``, ``test``
    (``"clean"`` or ``"noisy"``), ``nmse``, ``fit_s`` (seconds) and ``n_iter`` (the fit's
    iterations, or -1). Trial ``t`` of every scenario and SNR draws its data with seed
    ``SEED_STRIDE * seed + t`` so that methods and settings see the same draws, and two seeds
    share no trial (up to ``SEED_STRIDE`` trials).
    """
    methods = list(default_methods() if methods is None else methods)
    rows: list[dict] = []
    total = len(scenarios) * len(input_snrs) * n_trials * len(methods)
    with progress_bar(total=total, desc="Fig. 2", enabled=progress, unit="fit") as bar:
        for r, u in scenarios:
            for snr in input_snrs:
                for trial in range(n_trials):
                    p = make_problem(
                        r,
                        u,
                        input_snr=snr,
                        n_train=n_train,
                        n_test=n_test,
                        seed=SEED_STRIDE * seed + trial,
                    )
                    for m in methods:
                        start = time.perf_counter()
                        est, c_clean, i_clean, c_noisy, i_noisy = m.fit(p)
                        # a read-out of a shared fit reports the time of that fit
                        elapsed = getattr(m.fit, "last_fit_s", time.perf_counter() - start)
                        base = {
                            "redundant": r,
                            "irrelevant": u,
                            "input_snr": snr,
                            "trial": trial,
                            "method": m.name,
                            "fit_s": elapsed,
                            "n_iter": int(getattr(est, "n_iter_", -1)),
                        }
                        rows.append(
                            {
                                **base,
                                "test": "clean",
                                "nmse": _nmse(p.X_test_clean, p.y_test_clean, c_clean, i_clean),
                            }
                        )
                        rows.append(
                            {
                                **base,
                                "test": "noisy",
                                "nmse": _nmse(p.X_test_noisy, p.y_test_noisy, c_noisy, i_noisy),
                            }
                        )
                        bar.update(1)
    return rows


def summarize(rows: Sequence[dict]) -> list[dict]:
    """Mean and standard deviation over trials of nMSE and fit time, one row per
    (scenario, SNR, method, test set), in the order first seen."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        key = (row["redundant"], row["irrelevant"], row["input_snr"], row["method"], row["test"])
        groups.setdefault(key, []).append(row)
    out = []
    for (r, u, snr, method, test), g in groups.items():
        nmse = torch.tensor([x["nmse"] for x in g], dtype=torch.float64)
        fit_s = torch.tensor([x["fit_s"] for x in g], dtype=torch.float64)
        out.append(
            {
                "redundant": r,
                "irrelevant": u,
                "input_snr": snr,
                "method": method,
                "test": test,
                "nmse_mean": float(nmse.mean()),
                "nmse_std": float(nmse.std()) if len(g) > 1 else 0.0,
                "fit_s_mean": float(fit_s.mean()),
                "n_trials": len(g),
                "n_iter_mean": sum(x["n_iter"] for x in g) / len(g),
            }
        )
    return out


def improvement_table(
    summary: Sequence[dict],
    *,
    methods: Sequence[Method] | None = None,
    test: str = "clean",
    baselines: Sequence[str] | None = None,
) -> list[dict]:
    """Per scenario and SNR: the best Bayesian method, the best other method (of ``baselines``
    where given, e.g. `PAPER_BASELINES`), and the relative nMSE reduction ``1 - best_bayes /
    best_other`` (positive: the Bayesian method is better)."""
    bayes_names = {m.name for m in (methods or default_methods()) if m.bayesian}
    cells: dict[tuple, dict[str, float]] = {}
    for s in summary:
        if s["test"] == test:
            cells.setdefault((s["redundant"], s["irrelevant"], s["input_snr"]), {})[s["method"]] = (
                s["nmse_mean"]
            )
    out = []
    for (r, u, snr), by_method in cells.items():
        bayes = {k: v for k, v in by_method.items() if k in bayes_names}
        other = {
            k: v
            for k, v in by_method.items()
            if k not in bayes_names and (baselines is None or k in baselines)
        }
        if not bayes or not other:
            continue
        b_name, o_name = min(bayes, key=bayes.get), min(other, key=other.get)
        out.append(
            {
                "redundant": r,
                "irrelevant": u,
                "input_snr": snr,
                "test": test,
                "best_bayes": b_name,
                "best_bayes_nmse": bayes[b_name],
                "best_other": o_name,
                "best_other_nmse": other[o_name],
                "reduction": 1.0 - bayes[b_name] / other[o_name],
            }
        )
    return out


def claim_table(gains: Mapping[int, Sequence[dict]], claim: float = CLAIM) -> list[dict]:
    """The paper's claim per cell over seeds: ``gains`` maps each seed to its
    `improvement_table` (the same cells in the same order). Per cell: the reductions of each
    seed, their ``mean`` and sample standard deviation ``spread`` (0 for one seed), how many
    seeds reach ``claim``, and ``holds``: the mean is at least ``claim``; ``within_spread``:
    the mean falls short of ``claim`` by at most its spread."""
    seeds = list(gains)
    out = []
    for k, cell in enumerate(gains[seeds[0]]):
        red = [float(gains[s][k]["reduction"]) for s in seeds]
        mean = sum(red) / len(red)
        spread = (
            math.sqrt(sum((x - mean) ** 2 for x in red) / (len(red) - 1)) if len(red) > 1 else 0.0
        )
        out.append(
            {
                "redundant": cell["redundant"],
                "irrelevant": cell["irrelevant"],
                "input_snr": cell["input_snr"],
                "reductions": dict(zip(seeds, red, strict=True)),
                "mean": mean,
                "spread": spread,
                "worst": min(red),
                "n_held": sum(x >= claim for x in red),
                "holds": mean >= claim,
                "within_spread": mean >= claim - spread,
            }
        )
    return out


def plot(summary: Sequence[dict], path=None):
    """Grouped bar chart as in the paper's Fig. 2: one panel per (input SNR, test set), groups
    are scenarios, bars are methods, error bars one standard deviation. Saves to ``path`` (PNG)
    when given and returns the matplotlib figure."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    snrs = sorted({s["input_snr"] for s in summary})
    tests = ["clean", "noisy"]
    methods = list(dict.fromkeys(s["method"] for s in summary))
    scenarios = list(dict.fromkeys((s["redundant"], s["irrelevant"]) for s in summary))
    fig, axes = plt.subplots(len(snrs), 2, figsize=(14, 3.6 * len(snrs)), squeeze=False)
    width = 0.8 / len(methods)
    cmap = plt.get_cmap("tab20")
    for i, snr in enumerate(snrs):
        for j, test in enumerate(tests):
            ax = axes[i][j]
            cells = [s for s in summary if s["input_snr"] == snr and s["test"] == test]
            # methods that blow up (TLS, maximum-likelihood JFA's eq. 4) would flatten the
            # others: the axis stops at 1.4 x the worst mean below 1 (nMSE 1 = predicting the
            # mean), and bars beyond it are cut and labelled with their value
            sane = [c["nmse_mean"] for c in cells if c["nmse_mean"] < 1.0]
            top = 1.4 * max(sane) if sane else None
            for k, method in enumerate(methods):
                means, stds = [], []
                for sc in scenarios:
                    cell = [
                        c
                        for c in cells
                        if (c["redundant"], c["irrelevant"]) == sc and c["method"] == method
                    ]
                    means.append(cell[0]["nmse_mean"] if cell else float("nan"))
                    stds.append(cell[0]["nmse_std"] if cell else 0.0)
                xs = [n + (k - (len(methods) - 1) / 2) * width for n in range(len(scenarios))]
                shown = [min(m, top) if top else m for m in means]
                errs = [0.0 if top and m > top else e for m, e in zip(means, stds, strict=True)]
                ax.bar(
                    xs,
                    shown,
                    width,
                    yerr=errs,
                    label=method,
                    color=cmap(k % 20),
                    edgecolor="black" if "Bayes" in method else "none",
                    linewidth=0.6,
                    capsize=1.5,
                )
                for x, m in zip(xs, means, strict=True):
                    if top and m > top:
                        ax.text(x, top, f"{m:.3g}", rotation=90, ha="center", va="top", fontsize=6)
            if top:
                ax.set_ylim(0, top)
            ax.set_xticks(range(len(scenarios)))
            ax.set_xticklabels([f"r={r}, u={u}" for r, u in scenarios])
            ax.set_ylabel("nMSE")
            ax.set_title(f"input SNR {snr:g}, {test} test data")
    axes[0][1].legend(fontsize=7, ncol=2, loc="upper right")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig
