"""The terms of `project`'s objective, checked: the data's metric, the prior, the scales.

`objective_terms` turns `project`'s (and `unconstrained_projection`'s) arguments into the
terms of eq. 8 plus the prior: the metric ``M = X^T X + N diag(input_noise)`` (`data_metric`),
the prior and its per-parameter weights (`prior_terms`) and the power of two that scales M;
`unit_of` is the size of theta_hat that `project` divides out; `normalised_problem` is the
`Problem` in those units, as `project` and `torchjfa.physical.project_convex` solve it.
"""

from __future__ import annotations

import torch

from .._validation import as_tensor, check_finite
from ..dynamics._parametrizations import _check_theta, _power_of_two_scale, resolve_layout
from ..stats import Moments
from ._optimize import Problem

__all__ = [
    "DEFAULT_PARAMETRIZATION",
    "check_non_negative",
    "data_metric",
    "normalised_problem",
    "objective_terms",
    "prior_terms",
    "unit_of",
]

#: the projection's parametrisation unless one is asked for (`torchjfa.physical.project`,
#: `project_convex`, `torchjfa.Options`): log-Cholesky, fully consistent (triangle
#: inequalities too)
DEFAULT_PARAMETRIZATION = "log-cholesky"


def data_metric(moments, metric, input_noise, d: int, device) -> torch.Tensor:
    """The metric of eq. 8, ``(d, d)`` float64 on ``device``, symmetrised.

    Args:
        moments: a `torchjfa.Moments` (``X^T X`` and the sample count N), or None.
        metric: a ``(d, d)`` matrix given instead of ``moments``, or None.
        input_noise: per-column input-noise variances ``(d,)`` or a scalar (with ``moments``
            only): ``N diag(input_noise)`` is added.
        d: the number of parameters.
        device: where theta_hat lives.

    Raises:
        ValueError: unless exactly one of ``moments`` and ``metric`` is given; on wrong shapes,
            NaN or inf, negative variances, or a metric without a positive trace.
        TypeError: if ``moments`` is not a `torchjfa.Moments`.
    """
    if (moments is None) == (metric is None):
        raise ValueError("give exactly one of moments= (a Moments) and metric= (a (d, d) matrix)")
    if metric is not None:
        if input_noise is not None:
            raise ValueError(
                "input_noise needs the number of samples: pass moments= instead of metric=, or "
                "add N diag(input_noise) to the metric yourself"
            )
        M = as_tensor(metric, name="metric", dtype=torch.float64, device=device)
        if tuple(M.shape) != (d, d):
            raise ValueError(f"metric must have shape ({d}, {d}), got {tuple(M.shape)}")
        check_finite(M, "metric")
    else:
        if not isinstance(moments, Moments):
            raise TypeError(f"moments must be a torchjfa.Moments, got {type(moments).__name__}")
        if moments.n_features != d:
            raise ValueError(f"moments have {moments.n_features} features, theta has {d}")
        M = moments.xtx.to(device=device, dtype=torch.float64)
        if input_noise is not None:
            noise = as_tensor(input_noise, name="input_noise", dtype=torch.float64, device=device)
            if noise.ndim > 1 or (noise.ndim == 1 and noise.shape[0] != d):
                raise ValueError(
                    f"input_noise must be a scalar or have shape ({d},), got {tuple(noise.shape)}"
                )
            check_finite(noise, "input_noise")
            if bool((noise < 0).any()):
                raise ValueError("input_noise holds variances and must be non-negative")
            M = M + moments.n.to(device) * torch.diag(noise.expand(d))
    M = 0.5 * (M + M.T)
    diag = torch.diagonal(M)
    if bool((diag < 0).any()) or not float(diag.sum()) > 0:
        raise ValueError(
            "the metric must be positive semidefinite with a positive trace (X^T X of data that "
            "excites at least one parameter)"
        )
    return M


def objective_terms(theta_hat, layout, moments, metric, input_noise, prior, prior_weight, scale):
    """The checked terms of `project`'s objective (shared with `unconstrained_projection`):
    ``(layout, theta_hat, M, prior, prior_w, m_unit)``: the `ParameterLayout`, theta_hat
    ``(n_params,)`` detached (a fitted estimator's ``coef_``), the metric ``M`` (`data_metric`),
    the prior and its per-parameter weights (`prior_terms`), and ``m_unit``, the even power of
    two nearest M's mean diagonal (the scale of M that the problem divides out, exactly)."""
    layout = resolve_layout(layout)
    if hasattr(theta_hat, "coef_"):
        theta_hat = theta_hat.coef_
    theta_hat = _check_theta(theta_hat, layout, "theta_hat").detach()
    M = data_metric(moments, metric, input_noise, layout.n_params, theta_hat.device)
    prior, prior_w = prior_terms(prior, prior_weight, scale, layout, M)
    m_unit = float(_power_of_two_scale(torch.diagonal(M).mean().reshape(1)))
    return layout, theta_hat, M, prior, prior_w, m_unit


def check_non_negative(**values) -> None:
    """ValueError naming the first of ``values`` that is negative (or NaN)."""
    for name, value in values.items():
        if not float(value) >= 0:
            raise ValueError(f"{name} must be non-negative, got {value}")


def prior_terms(prior, prior_weight, prior_scale, layout, M: torch.Tensor):
    """The checked prior ``(n_params,)`` float64 (or None) and its per-parameter weights.

    Returns:
        ``(prior, prior_w)``: ``prior_w`` is None without ``prior_scale``, else ``(n_params,)``
        ``(sum_k p_k^2 M_kk / sum_k M_kk) / p^2``.
    """
    device = M.device
    if prior is not None:
        prior = _check_theta(prior, layout, "prior").to(device=device, dtype=torch.float64)
    if float(prior_weight) > 0 and prior is None:
        raise ValueError("prior_weight > 0 needs prior= (nominal parameters, shape (n_params,))")
    if prior_scale is None:
        return prior, None
    p = _check_theta(prior_scale, layout, "prior_scale").to(device=device, dtype=torch.float64)
    if not bool((p > 0).all()):
        raise ValueError("prior_scale must be positive (a scale per parameter, its units)")
    # (sum_k p_k^2 M_kk / d) / p_k^2 relative to the isotropic term's tr(M) / d: invariant
    # under the problem's rescaling in `project`
    diag = torch.diagonal(M)
    return prior, (p.square() * diag).sum() / diag.sum() / p.square()


def unit_of(theta_hat: torch.Tensor, M: torch.Tensor, prior: torch.Tensor | None) -> float:
    """The size of theta_hat as the data see it, ``sqrt(theta_hat^T M theta_hat / tr(M))``
    (theta_hat's largest magnitude when that is 0, the prior's when theta_hat is 0, else 1).

    Homogeneous of degree 1 and not rounded: the normalised problem of s theta_hat is then the
    same as theta_hat's to rounding, so that the optimiser takes the same path (the same start,
    the same local minimum of the non-convex problem in phi) for any s > 0. Weighted by M, so
    that huge components along directions the data do not excite (unregularised estimates on
    poor data) do not set the scale.
    """
    for t in (theta_hat, prior):
        if t is None or not bool((t != 0).any()):
            continue
        big = t.abs().max()
        u = t / big  # no overflow in the quadratic form
        size = float((u @ (M @ u) / torch.diagonal(M).sum()).clamp_min(0).sqrt() * big)
        return size if 0 < size < float("inf") else float(big)
    return 1.0


def normalised_problem(
    theta_hat, layout, moments, metric, input_noise, prior, prior_weight, prior_scale, ridge
):
    """``(layout, theta_hat, problem, unit, m_unit)``: `project`'s objective as a `Problem` in
    units where theta_hat's size (`unit_of`) and M's mean diagonal are about 1 (theta and M
    divided by ``unit`` and ``m_unit``; the objective then scales back by
    ``unit^2 m_unit``). Eq. 8 and the consistent set are invariant under theta -> s theta
    (s > 0), so the answer for s theta_hat is s times the answer for theta_hat, however large
    or small s (the solvers' floors, damping and default body are O(1) numbers)."""
    layout, theta_hat, M, prior, prior_w, m_unit = objective_terms(
        theta_hat, layout, moments, metric, input_noise, prior, prior_weight, prior_scale
    )
    th = theta_hat.to(torch.float64)
    M_n = M / m_unit
    unit = unit_of(th, M_n, prior)
    prior_n = prior / unit if prior is not None and float(prior_weight) > 0 else None
    problem = Problem(th / unit, M_n, float(ridge), prior_n, float(prior_weight), prior_w)
    return layout, theta_hat, problem, unit, m_unit
