"""The `make_consistent` stage: the unconstrained estimate projected onto physically consistent
parameters (the paper's eq. 8), pulled towards the description where the data are silent."""

from __future__ import annotations

from dataclasses import replace

import torch

from .._util import single_thread
from ..physical import project
from ..report._result import IdentificationResult
from ._options import IdentificationError, Options
from ._prior import (
    check_description_prior,
    choose_prior_weight,
    description_problems,
    pick_prior_weight,
    prior_options,
)

__all__ = ["make_consistent"]

#: `torchjfa.physical.project` keywords that the stage sets itself
_RESERVED = ("layout", "moments", "metric", "input_noise", "parametrization", "theta_hat")


@single_thread()  # small matrices: threads only wait on each other
def make_consistent(
    result: IdentificationResult, options: Options | None = None
) -> IdentificationResult:
    """Project ``result.theta_hat`` onto physically consistent parameters: the stage after
    `correct_bias`.

    The projection (`torchjfa.physical.project`, ``options.parametrization``) minimises the
    paper's eq. 8 in the metric ``X^T X + N diag(result.input_noise)``. With
    ``options.description_prior`` it adds a Gaussian prior towards the description's
    parameters (``model.nominal_theta``: its inertials, zero friction) of standard deviation
    ``p_k / sqrt(w)`` per parameter (``p``: `torchjfa.physical.parameter_scales`), so that the
    directions the data determine barely move; ``"auto"`` chooses ``w`` by cross-validation over
    the training blocks of ``result.blocks`` (`torchjfa.identification.PRIOR_WEIGHTS`: the
    largest weight whose held-out RMS error is within 1 % of the lowest).
    A description whose own inertials are not physically consistent (`description_problems`:
    a mass that is not positive, an inertia that is not, a broken triangle inequality) is no
    prior: with ``"auto"`` the prior is off; either way a warning names its bodies.

    Args:
        result: the `IdentificationResult` of `fit` (or `correct_bias`).
        options: `Options` (``parametrization``, ``description_prior``,
            ``projection_options``).

    Returns:
        A copy of ``result`` with ``theta`` the consistent parameters, ``projection``,
        ``prior_weight`` and ``prior_choice`` set.

    Raises:
        IdentificationError: on ``projection_options`` that set what this stage sets, or
            ``description_prior="auto"`` without the training blocks (`fit` streams them when
            ``options`` asks for the prior).
    """
    options = Options() if options is None else options
    extra = dict(options.projection_options)
    bad = sorted(set(extra) & set(_RESERVED))
    if bad:
        raise IdentificationError(f"projection_options may not set {bad}; the stage sets them")
    weight = options.description_prior
    choice, warnings = None, list(result.warnings)
    problems = description_problems(result.model) if weight is not None else []
    if problems:
        warnings.append(_inconsistent_description(problems, weight))
        if weight == "auto":
            weight = None
    if check_description_prior(weight, extra, True):
        if not result.blocks or len(result.blocks) < 2:
            raise IdentificationError(
                "description_prior='auto' needs the training data in at least two blocks: fit "
                "with the same Options (which stream them), or give a weight"
            )
        choice = choose_prior_weight(
            result.estimator,
            result.blocks,
            result.model,
            result.given_noise,
            options.parametrization,
            extra,
            coefs=result.theta_hat_jackknife,
        )
        weight = pick_prior_weight(choice)
    if weight is not None:
        extra.update(prior_options(result.model, result.moments, result.theta_hat, float(weight)))
        if float(weight) > 0:  # the prior breaks the ties; a ridge pulls to 0
            extra.setdefault("ridge", 0.0)
    noise = result.input_noise
    projection = project(
        result.theta_hat,
        layout=result.model,
        moments=result.moments,
        input_noise=None if noise is None else noise.to(result.moments.xtx.device),
        parametrization=options.parametrization,
        **extra,
    )
    return replace(
        result,
        theta=projection.theta.detach().to(torch.float64),
        projection=projection,
        prior_weight=None if weight is None else float(weight),
        prior_choice=choice,
        warnings=warnings,
    )


def _inconsistent_description(problems: list[str], weight) -> str:
    """The warning for a description whose own inertials are not physically consistent."""
    what = "; ".join(problems)
    if weight == "auto":
        return (
            f"the description's inertials are not physically consistent ({what}): the "
            "projection does not pull towards the description (no description prior); fix "
            "those bodies' inertials in the description, or give the prior's weight "
            "(--description-prior W) to use them as they are"
        )
    return (
        f"the description's inertials are not physically consistent ({what}), and the "
        f"projection pulls towards them with the weight {weight} given"
    )
