"""How well do the report's two spreads measure the real error of Bayesian JFA's estimate?

Data drawn from the joint factor analysis model itself (t ~ N(0, I), x = w_x t + noise,
y = w_z t + noise: the estimator's own assumptions hold), ``--trials`` independent draws. For
each draw: Bayesian JFA's mean-field posterior spread ``coef_std_`` and the delete-one-block
jackknife spread (``torchjfa.estimators.jackknife``, K blocks); over the draws: the RMS error of
``coef_`` against the truth ``w_z / w_x``. Prints, per setting, the median over inputs of
spread / RMS error (1 is calibrated; below 1 over-confident).

    python scripts/spread_calibration.py            # 40 trials (about 3 minutes)
    python scripts/spread_calibration.py --trials 10
"""

from __future__ import annotations

import argparse

import torch

from torchjfa.estimators import BayesianJFA, jackknife
from torchjfa.stats import kfold_moments


def run(trials: int, blocks: int) -> list[tuple]:
    dt = torch.float64
    wx = torch.tensor([1.0, 2.0, 0.5, 1.5, 1.0], dtype=dt)
    wz = torch.tensor([1.0, -2.0, 3.0, 0.5, 2.0], dtype=dt)
    truth = wz / wx
    psx = 0.3 * wx**2
    rows = []
    for n in (500, 5000):
        for known in (True, False):
            errs, post, jack = [], [], []
            for s in range(trials):
                g = torch.Generator().manual_seed(s)
                t = torch.randn(n, 5, generator=g, dtype=dt)
                X = t * wx + torch.randn(n, 5, generator=g, dtype=dt) * psx.sqrt()
                y = t @ wz + 0.5 * torch.randn(n, generator=g, dtype=dt)
                est = BayesianJFA(fit_intercept=False, input_noise=psx if known else None)
                est.fit(X, y)
                errs.append(est.coef_ - truth)
                post.append(est.coef_std_)
                jack.append(jackknife(est, kfold_moments(X, y, blocks))[1])
            rms = torch.stack(errs).pow(2).mean(0).sqrt()
            p = float((torch.stack(post).median(0).values / rms).median())
            j = float((torch.stack(jack).median(0).values / rms).median())
            rows.append((n, "given" if known else "learned", float(rms.median()), p, j))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--blocks", type=int, default=10)
    args = ap.parse_args()
    print(f"{args.trials} trials, jackknife over {args.blocks} blocks")
    print(
        f"{'n':>6} {'input noise':>12} {'RMS error':>10} {'posterior/RMS':>14} {'jackknife/RMS':>14}"
    )
    for n, known, rms, p, j in run(args.trials, args.blocks):
        print(f"{n:>6} {known:>12} {rms:>10.4f} {p:>14.2f} {j:>14.2f}")


if __name__ == "__main__":
    main()
