"""Parametric bootstrap of any estimator: refits on data re-drawn with the estimated noise.

`bootstrap` refits an estimator on each of B re-drawn data sets (given as `Moments`) and
returns the spread of its ``coef_``. Where the draws come from is the caller's choice:

* `redraw_moments` re-draws the regression itself, ``y* = X coef + e`` with white noise ``e``
  of a given variance per row, exactly in moment space (``X^T X`` stays, ``X^T y*`` and
  ``y*^T y*`` are drawn from their joint Gaussian / chi-square law), for B draws at the cost
  of B fits. White noise on fixed inputs: for OLS this reproduces the textbook
  ``sigma^2 (X^T X)^-1``, so it adds nothing where the rows' noise is correlated or the
  inputs are noisy.
* `torchjfa.identification.signal_bootstrap` re-draws the raw log's sensor noise and runs the
  whole preparation again (the zero-phase filter, the derivatives, the regressor), so the
  draws carry the filtered (correlated) output noise and the input noise of the real flow.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable

import torch

from ..stats import Moments
from ._base import LinearEstimator

__all__ = ["bootstrap", "redraw_moments"]


def bootstrap(
    estimator: LinearEstimator, draws: Iterable[Moments]
) -> tuple[torch.Tensor, torch.Tensor]:
    """The spread of an estimator's ``coef_`` over refits on re-drawn data.

    Args:
        estimator: a `LinearEstimator` (fitted or not; it is not modified). Each draw is
            fitted by a quiet copy with the same hyper-parameters; one that cross-validates
            (`LinearEstimator.needs_folds`) gets each draw as a sequence of fold `Moments`.
        draws: B >= 2 re-drawn data sets: `Moments` (or, for a cross-validating estimator,
            sequences of fold `Moments`), e.g. from `redraw_moments`.

    Returns:
        ``(coefs, std)``: ``(B, d)`` the refits' coefficients and ``(d,)`` their standard
        deviation (``B - 1`` in the denominator), float64.

    Raises:
        TypeError: if ``estimator`` is not a `LinearEstimator`.
        ValueError: on fewer than two draws.
    """
    if not isinstance(estimator, LinearEstimator):
        raise TypeError(f"estimator must be a LinearEstimator, got {type(estimator).__name__}")
    coefs = []
    for data in draws:
        est = copy.deepcopy(estimator)
        if hasattr(est, "verbose"):
            est.verbose = False
        est.fit_moments(data)
        coefs.append(est.coef_.detach().to(torch.float64).reshape(-1))
    if len(coefs) < 2:
        raise ValueError(f"the bootstrap needs at least 2 draws, got {len(coefs)}")
    C = torch.stack(coefs)
    return C, C.std(dim=0, correction=1)


def redraw_moments(
    moments: Moments,
    coef,
    noise_var: float,
    n_draws: int,
    *,
    generator: torch.Generator | None = None,
) -> list[Moments]:
    """Moments of ``y* = X coef + e``, ``e ~ N(0, noise_var I)`` white, for ``n_draws`` draws.

    Only ``X^T X`` (and ``n``, ``sum_x``) of ``moments`` is used: with ``G = X^T X``,
    ``X^T y* = G coef + X^T e`` with ``X^T e ~ N(0, noise_var G)``, and
    ``y*^T y* = coef^T G coef + 2 coef^T X^T e + e^T e`` where ``e^T e`` less its part in the
    span of X is ``noise_var chi^2_(n - rank)`` independent of ``X^T e``. Unweighted rows
    (``moments.n`` is the number of rows) and no intercept: ``sum_y`` is set to
    ``sum_x . coef`` (its mean).

    Args:
        moments: `Moments` of the regression (``d`` features).
        coef: ``(d,)`` the coefficients to re-draw from (the estimate).
        noise_var: the rows' noise variance, output units squared (e.g. the residual
            variance ``rss / (n - d)``).
        n_draws: draws, at least 2.
        generator: seeds the draws.

    Returns:
        ``n_draws`` `Moments` on ``moments``' device, float64.

    Raises:
        ValueError: on a wrong shape, a negative or non-finite variance or ``n_draws < 2``.
    """
    if not isinstance(moments, Moments):
        raise TypeError(f"moments must be a torchjfa.Moments, got {type(moments).__name__}")
    G = moments.xtx
    d = G.shape[0]
    coef = torch.as_tensor(coef, dtype=torch.float64, device=G.device).reshape(-1)
    if coef.shape != (d,):
        raise ValueError(f"coef must have shape ({d},), got {tuple(coef.shape)}")
    noise_var = float(noise_var)
    if not (math.isfinite(noise_var) and noise_var >= 0):
        raise ValueError(f"noise_var must be finite and >= 0, got {noise_var}")
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 2:
        raise ValueError(f"n_draws must be an int of at least 2, got {n_draws!r}")
    # a square root of G that tolerates its null space (G = V diag(lam) V^T)
    lam, V = torch.linalg.eigh(0.5 * (G + G.T))
    lam = lam.clamp_min(0)
    root = V * lam.sqrt()  # (d, d): root @ root.T = G
    live = lam > lam.max() * d * torch.finfo(torch.float64).eps  # (d,) the span of X
    dof = max(float(moments.n) - int(live.sum()), 0.0)
    Gc = G @ coef
    out = []
    for _ in range(n_draws):
        z = torch.randn(d, generator=generator, dtype=torch.float64).to(G.device)
        xte = math.sqrt(noise_var) * (root @ z)  # X^T e ~ N(0, noise_var G)
        # e^T e = its part in span(X) (z^T z restricted to the rank) + the rest
        in_span = noise_var * float(z[live].square().sum())
        rest = noise_var * float(_chi2(dof, generator))
        out.append(
            Moments(
                moments.n.clone(),
                moments.sum_x.clone(),
                moments.sum_x @ coef,
                G.clone(),
                Gc + xte,
                coef @ Gc + 2.0 * (coef @ xte) + in_span + rest,
                n_rows=moments.n_rows,
            )
        )
    return out


def _chi2(dof: float, generator: torch.Generator | None) -> torch.Tensor:
    """One chi-square draw with ``dof`` degrees of freedom (a Gamma(dof / 2, 2))."""
    if dof <= 0:
        return torch.zeros((), dtype=torch.float64)
    if generator is None:
        return torch.distributions.Chi2(torch.tensor(dof, dtype=torch.float64)).sample()
    # torch's Gamma sampler takes no generator: the sum of squares of normals for small dof,
    # the Wilson-Hilferty cube of a normal (relative error below 1e-3 for dof > 100) else
    if dof <= 100:
        k = int(round(dof))
        return torch.randn(k, generator=generator, dtype=torch.float64).square().sum()
    z = torch.randn((), generator=generator, dtype=torch.float64)
    h = 2.0 / (9.0 * dof)
    return dof * (1.0 - h + z * math.sqrt(h)).clamp_min(0).pow(3)
