"""The description as a prior of the projection: ``Options.description_prior`` of
`torchjfa.identification.make_consistent`.

The prior term ``w * sigma^2 * sum_k ((theta_k - nominal_k) / p_k)^2`` beside eq. 8's
``||y - X theta||^2 - const`` is a Gaussian prior of standard deviation ``p_k / sqrt(w)`` on each
parameter (``p``: `torchjfa.physical.parameter_scales` of the description, ``sigma^2`` the
residual variance per row). Directions the data determine barely move; along the null space the
prior decides. ``"auto"`` chooses ``w`` from `PRIOR_WEIGHTS` by cross-validation over contiguous
blocks of the training data (`choose_prior_weight`, `pick_prior_weight`), each block predicted by
the prior's posterior mean on the others (the projection's objective in closed form, without
the consistency constraints); the projection then runs once, with the chosen weight.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import torch

from ..estimators._jackknife import refit_totals, refit_without
from ..physical import check, parameter_scales, unconstrained_projection
from ..report._result import PRIOR_TOLERANCE as _PRIOR_TOLERANCE
from ..stats import Moments

__all__ = [
    "PRIOR_WEIGHTS",
    "PRIOR_TOLERANCE",
    "PRIOR_BLOCKS",
    "check_description_prior",
    "description_problems",
    "choose_prior_weight",
    "pick_prior_weight",
    "prior_options",
]

#: the weights ``Options(description_prior="auto")`` chooses from (0: no prior); a weight
#: w gives each parameter a prior standard deviation of its physical scale / sqrt(w). Above
#: ~100 the prior also shrinks the weakly determined directions towards the description (a
#: ridge towards it, not only a tie-break): the held-out block decides whether that helps
PRIOR_WEIGHTS = (0.0, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5)
#: "auto" takes the largest weight whose held-out error is within this fraction of the best
#: (defined beside `IdentificationResult.prior_choice`, which the report reads with it)
PRIOR_TOLERANCE = _PRIOR_TOLERANCE
#: contiguous blocks of the training data for that choice when there are no others
PRIOR_BLOCKS = 5


def prior_options(model, moments: Moments, theta_hat: torch.Tensor, weight: float) -> dict:
    """`project` options for the description prior of weight ``weight``.

    ``sigma^2 = rss(theta_hat) / N`` is the residual variance per row. Every direction the data
    determine has an eigenvalue of ``P X^T X P`` far above ``sigma^2``
    (`torchjfa.physical.base_parameters`: above 100 sigma^2 for a tenth of the scale), so a
    weight of order 1 moves it by a fraction ``weight sigma^2 / eigenvalue`` only. `project`'s
    ``prior_weight`` is relative to ``s_p = sum_k p_k^2 M_kk / n_params``, hence the ratio."""
    return _PriorUnits.of(model, moments, theta_hat).options(weight)


class _PriorUnits(NamedTuple):
    """What `prior_options` needs of a fit, whatever the weight: the description's
    ``prior`` and ``scale`` ``(n_params,)`` (`parameter_scales`) and ``per_weight``, the
    ``prior_weight`` of weight 1 (``sigma^2 / s_p``)."""

    prior: torch.Tensor
    scale: torch.Tensor
    per_weight: float

    @classmethod
    def of(cls, model, moments: Moments, theta_hat: torch.Tensor) -> _PriorUnits:
        dev = moments.xtx.device
        scale = parameter_scales(model.parameter_names, model.nominal_theta, moments).to(dev)
        sigma2 = float(moments.rss(theta_hat.to(dev)).clamp_min(0.0) / moments.n)
        s_p = float((scale.square() * torch.diagonal(moments.xtx)).sum()) / model.n_params
        return cls(model.nominal_theta.to(dev), scale, sigma2 / s_p if s_p > 0 else 0.0)

    def options(self, weight: float) -> dict:
        return {
            "prior": self.prior,
            "prior_scale": self.scale,
            "prior_weight": weight * self.per_weight,
        }


def description_problems(model) -> list[str]:
    """What makes the description's own inertials physically inconsistent, one entry per body
    (named by its link and joint): a mass that is not positive, an inertia at the centre of
    mass that is not positive semidefinite, principal moments that break the triangle
    inequality (`torchjfa.physical.check` of ``model.nominal_theta``); one entry where no body
    has a mass. Empty for a consistent description. A description with such a body is no prior
    to pull an estimate towards."""
    r = check(model.nominal_theta, model)
    if not bool(r.mass_ok.any()) and len(r.joint_names) > 1:
        return [f"every body: mass {float(r.mass.max()):.3g} kg or less (no inertials given)"]
    problems = []
    for k, (body, joint) in enumerate(zip(model.body_names, r.joint_names, strict=True)):
        name = f"{body} (joint {joint})"
        moments = ", ".join(f"{float(v):.3g}" for v in r.principal_moments[k])
        if not r.mass_ok[k]:
            problems.append(f"{name}: mass {float(r.mass[k]):.3g} kg")
        elif not r.inertia_ok[k]:
            problems.append(f"{name}: principal moments {moments} kg m^2, not all >= 0")
        elif not r.triangle_ok[k]:
            problems.append(
                f"{name}: principal moments {moments} kg m^2 break the triangle inequality"
            )
    return problems


def check_description_prior(value, options: Mapping, project: bool) -> bool:
    """Validate ``identify``'s ``description_prior``; True when it is ``"auto"``."""
    if value is None:
        return False
    if "prior" in options or "prior_weight" in options or "prior_scale" in options:
        raise ValueError(
            "description_prior sets the projection's prior; do not also pass prior, "
            "prior_weight or prior_scale in projection_options"
        )
    if not project:
        raise ValueError("description_prior needs project=True (it acts in the projection)")
    if isinstance(value, str):
        if value != "auto":
            raise ValueError(
                f"description_prior must be None, a weight >= 0 or 'auto', got {value!r}"
            )
        return True
    if isinstance(value, bool) or not float(value) >= 0 or float(value) == float("inf"):
        raise ValueError(f"description_prior must be None, a weight >= 0 or 'auto', got {value!r}")
    return False


def choose_prior_weight(
    estimator,
    folds: Sequence[Moments],
    model,
    noise,
    parametrization: str,
    options: Mapping,
    coefs: torch.Tensor | None = None,
) -> dict[float, float]:
    """weight -> held-out RMS over the blocks, each predicted from a fit on the others with the
    projection's objective minimised in closed form (cross-validation over the training blocks).

    Each block is predicted by `torchjfa.physical.unconstrained_projection`: the projection's
    objective (eq. 8 plus the prior term, the same weights) without the consistency
    constraints, the posterior mean of the description's Gaussian prior. It scores the prior's
    weight where the constrained projection would need one LBFGS run per block and weight; on
    a real arm's log (``scripts/real_panda.py``'s training part) its held-out errors follow the
    constrained projections' to within a few per cent and choose the same weight, in a
    fraction of the time.
    ``parametrization`` is not used (the constraints are what the closed form leaves out);
    ``options`` may set ``ridge``.

    ``coefs``: ``(K, n_params)`` the estimator's leave-one-block-out estimates on these folds
    where they are at hand (the jackknife's, ``IdentificationResult.theta_hat_jackknife``),
    so that it is not refitted K more times; only when ``noise`` is given or the estimator
    learns none (a fold's learned ``noise_x_`` needs the refit)."""
    del parametrization
    learns_noise = noise is None and hasattr(estimator, "noise_x_")
    if coefs is not None and (len(coefs) != len(folds) or learns_noise):
        coefs = None
    rss = dict.fromkeys(PRIOR_WEIGHTS, 0.0)
    n = 0.0
    for k, held in enumerate(folds):
        fold_noise = noise
        if coefs is None:
            est, moments = refit_without(estimator, folds, k)
            theta_hat = est.coef_.detach().to(torch.float64)
            if fold_noise is None and hasattr(est, "noise_x_"):
                fold_noise = est.noise_x_.detach().to(torch.float64)
        else:
            theta_hat, moments = coefs[k].to(torch.float64), refit_totals(folds, k)
        units = _PriorUnits.of(model, moments, theta_hat)  # the fold's, for every weight
        for w in PRIOR_WEIGHTS:
            theta = unconstrained_projection(
                theta_hat,
                layout=model,
                moments=moments,
                input_noise=None if fold_noise is None else fold_noise.to(moments.xtx.device),
                ridge=options.get("ridge", 0.0 if w > 0 else 1e-8),
                **units.options(w),
            )
            rss[w] += float(held.rss(theta.to(theta_hat.dtype)).clamp_min(0.0))
        n += float(held.n)
    return {w: (v / n) ** 0.5 for w, v in rss.items()}


def pick_prior_weight(choice: Mapping[float, float]) -> float:
    """The largest weight whose held-out RMS is within `PRIOR_TOLERANCE` of the lowest."""
    best = min(choice.values())
    return max(w for w, v in choice.items() if v <= best * (1.0 + PRIOR_TOLERANCE))
