"""Delete-one-block jackknife of any estimator, from fold moments.

`jackknife` refits a `LinearEstimator` on all blocks but one; `jackknife_std` is the variance
formula alone, for any estimate that is refitted K times (the base parameters, a payload, drive
gains): the one place it is written.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch

from .._util import progress_bar
from ..stats import Moments
from ._base import LinearEstimator

__all__ = ["jackknife", "jackknife_std", "refit_without"]


def refit_without(
    estimator: LinearEstimator, folds: Sequence[Moments], k: int
) -> tuple[LinearEstimator, Moments]:
    """A quiet copy of ``estimator`` (same hyper-parameters) fitted on all folds but the
    ``k``-th: on the remaining folds where it cross-validates (`LinearEstimator.needs_folds`),
    else on their sum. Returns ``(fitted copy, the remaining folds' summed Moments)``; the
    estimator itself is not modified."""
    rest = list(folds[:k]) + list(folds[k + 1 :])
    total = refit_totals(folds, k)
    est = copy.deepcopy(estimator)
    if hasattr(est, "verbose"):
        est.verbose = False
    est.fit_moments(rest if est.needs_folds else total)
    return est, total


def refit_totals(folds: Sequence[Moments], k: int) -> Moments:
    """The sum of all folds but the ``k``-th (a new `Moments`)."""
    rest = list(folds[:k]) + list(folds[k + 1 :])
    return sum(rest[1:], rest[0].copy())


def jackknife_std(estimates) -> torch.Tensor:
    """The delete-one-block jackknife standard deviation of K leave-one-block-out estimates.

    ``sqrt((K - 1) / K * sum_k (c_k - mean)^2)`` (Efron and Stein 1981; Kunsch 1989 for
    contiguous blocks of a series): two refits share K - 2 of their K - 1 blocks, so the
    refits' variance is (K - 1)^2 / K times smaller than the estimate's.

    Args:
        estimates: ``(K, ...)`` the estimate with each of K blocks left out in turn (a tensor
            or an array; any trailing shape).

    Returns:
        ``(...)`` float64 standard deviations, on the estimates' device.

    Raises:
        ValueError: on fewer than two estimates.
    """
    C = torch.as_tensor(estimates, dtype=torch.float64)
    K = C.shape[0] if C.ndim else 0
    if K < 2:
        raise ValueError(f"the jackknife needs at least 2 leave-one-out estimates, got {K}")
    return ((K - 1) / K * (C - C.mean(0)).pow(2).sum(0)).sqrt()


def jackknife(
    estimator: LinearEstimator, folds: Sequence[Moments], *, progress: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """The spread of an estimator's ``coef_`` by the delete-one-block jackknife.

    The estimator (a copy, with the same hyper-parameters) is refitted K times, each time on
    all the folds but one; the jackknife variance is ``(K - 1) / K * sum_k (c_k - mean)^2``
    (`jackknife_std`).
    With contiguous blocks of a log as folds it accounts for the correlation of neighbouring
    samples (filtered noise) that per-sample formulas miss, and it needs no model of the noise:
    it is the spread to quote when a posterior is not trusted.

    Args:
        estimator: a `LinearEstimator` (fitted or not; it is not modified).
        folds: K >= 2 `Moments` of disjoint blocks of the data. An estimator that chooses a
            hyper-parameter by cross-validation gets the K - 1 remaining folds each time.
        progress: show a progress bar over the K refits.

    Returns:
        ``(coefs, std)``: ``(K, d)`` the leave-one-block-out coefficients and ``(d,)`` the
        jackknife standard deviation, float64.

    Raises:
        ValueError: on fewer than two folds.
    """
    if not isinstance(estimator, LinearEstimator):
        raise TypeError(f"estimator must be a LinearEstimator, got {type(estimator).__name__}")
    folds = list(folds)
    K = len(folds)
    if K < 2:
        raise ValueError(f"the jackknife needs at least 2 folds, got {K}")
    coefs = []
    with progress_bar(total=K, desc="jackknife", enabled=progress, unit="fit") as bar:
        for k in range(K):
            est, _ = refit_without(estimator, folds, k)
            coefs.append(est.coef_.detach().to(torch.float64))
            bar.update(1)
    C = torch.stack(coefs)
    return C, jackknife_std(C)
