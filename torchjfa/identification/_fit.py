"""The `fit` stage: prepared logs -> regressor -> `Moments` -> estimator (and its jackknife).

Memory. The regression matrix (``n_samples * n_dof`` rows of ``n_params`` columns: 4.4 GB for
500,000 samples of a 10-DoF arm) is never formed. The logs are streamed through the batched
regressor ``Compute.chunk_size`` samples at a time (`stream_moments`; ``.npz`` files are read
member by member straight from the zip archive), so the peak memory is
``O(chunk_size * n_dof * n_params + n_params^2)`` whatever the length of the logs.

Several processes. With ``Compute(distributed=True)`` (``torch.distributed`` initialised, e.g.
by ``torchrun``, by Lightning or by `torchjfa.distributed.process_group`), each process reduces
its contiguous share of the samples of all logs to `Moments` and one all-reduce sums them;
every process then fits the same estimator on the same statistics.
"""

from __future__ import annotations

import torch

from .._validation import check_joint_weights
from ..distributed import rank_and_world_size
from ..dynamics import RigidBodyModel
from ..estimators import LinearEstimator
from ..estimators import jackknife as _jackknife
from ..report._result import IdentificationResult
from ..stats import Moments
from ._noise import NoiseChoice, choose_noise, noise_vector
from ._options import IdentificationError, Options
from ._prepare import PreparedData
from ._prior import PRIOR_BLOCKS
from ._stream import stream_moments

__all__ = ["fit", "make_estimator"]


def make_estimator(options: Options, input_noise: torch.Tensor | None = None) -> LinearEstimator:
    """``options.estimator``: made by name (`torchjfa.estimators.make`, no intercept, with
    ``options.estimator_options`` and, for an estimator that takes one
    (`torchjfa.estimators.takes`), the input noise), or the estimator given, as it is (checked:
    a `LinearEstimator` without an intercept)."""
    from .. import estimators

    if not isinstance(options.estimator, str):
        return _check_estimator(options.estimator)
    kw = {"fit_intercept": False, **dict(options.estimator_options)}
    if input_noise is not None and estimators.takes(options.estimator, "input_noise"):
        kw["input_noise"] = input_noise
    return estimators.make(options.estimator, **kw)


def _check_estimator(estimator) -> LinearEstimator:
    if not isinstance(estimator, LinearEstimator):
        raise TypeError(
            f"estimator must be a torchjfa.estimators estimator, got {type(estimator).__name__}"
        )
    if estimator.fit_intercept:
        raise IdentificationError(
            f"{type(estimator).__name__}(fit_intercept=True) would fit a torque offset that "
            "inverse dynamics cannot use; pass fit_intercept=False (add friction 'offset' "
            "terms to the model for a per-joint offset)"
        )
    return estimator


def _as_moments(data) -> list[Moments] | None:
    """``data`` as a list of `Moments` when it is moments already formed, else None."""
    if isinstance(data, Moments):
        return [data]
    if isinstance(data, list | tuple) and data and all(isinstance(m, Moments) for m in data):
        return list(data)
    return None


def _given_noise(options: Options) -> NoiseChoice:
    """The `NoiseChoice` of moments already formed: no weights to choose (the moments hold
    theirs), the input noise only when ``options`` gives it as variances."""
    if options.weighting != "none":
        raise IdentificationError(
            "the moments were formed already, with whatever joint weights they have: fit them "
            "with weighting='none' (or pass a NoiseChoice)"
        )
    mode = options.input_noise
    if isinstance(mode, str) and mode not in ("auto", "learn"):
        raise IdentificationError(
            f"input_noise={mode!r} needs the logs; give the moments' input noise as variances"
        )
    noise = None if isinstance(mode, str) else mode
    return NoiseChoice(None, None, noise, "learn" if noise is None else "given")


def _check_formed(formed: list[Moments], n_blocks, noise: NoiseChoice, model) -> list | Moments:
    """The moments given to `fit`: one whole, or contiguous blocks where they are needed."""
    if noise.joint_weights is not None:
        raise IdentificationError(
            "moments already formed carry their weights: a NoiseChoice with joint_weights does "
            "not apply to them"
        )
    if any(m.n_features != model.n_params for m in formed):
        raise IdentificationError(
            f"the moments have {formed[0].n_features} features, the model {model.n_params} "
            "parameters"
        )
    if n_blocks is None:
        return sum(formed[1:], formed[0].copy()) if len(formed) > 1 else formed[0]
    if len(formed) < 2:
        raise IdentificationError(
            "the estimator's cross-validation, the jackknife or the description prior's choice "
            "needs the moments in contiguous blocks: pass a list of them "
            "(stream_moments(..., n_folds=K))"
        )
    return formed


def _blocks(estimator: LinearEstimator, options: Options) -> int | None:
    """How many contiguous blocks of the samples the moments must come in, or None (one whole):
    the estimator's ``cv`` folds when it cross-validates, else the jackknife's blocks, else
    `PRIOR_BLOCKS` for the description prior's choice."""
    if estimator.needs_folds:
        return int(estimator.cv)
    if options.jackknife:
        return int(options.jackknife)
    auto_prior = options.project and options.description_prior == "auto"
    return PRIOR_BLOCKS if auto_prior else None


def fit(
    model: RigidBodyModel,
    data,
    noise: NoiseChoice | None = None,
    options: Options | None = None,
) -> IdentificationResult:
    """Fit the estimator on the training data's moments: the stage after `choose_noise`.

    The training logs are streamed through the regressor into `Moments` (contiguous blocks of
    them where the estimator cross-validates, the jackknife refits or the description prior's
    weight is to be chosen), the estimator of ``options`` is fitted on them (with the
    jackknife's refits for the spread); the result's ``theta`` is the unconstrained estimate
    until `make_consistent` projects it. With a `PreparedData`, the model's Coulomb term is
    smoothed as the preparation chose (`PreparedData.model_for`).

    Args:
        model: the robot (`load_model`).
        data: a `PreparedData` (`prepare_data`); or prepared logs: one or a list of ``.npz``
            paths, `torchjfa.data.JointLog` s with ``qdd`` (a `torchjfa.sim.SimulatedLog`
            too), mappings or objects with ``q, qd, qdd, tau`` ``(n_samples, n_dof)`` arrays
            (rad, rad/s, rad/s^2, N m); or their `Moments` already formed (one, or a list of
            contiguous blocks from `stream_moments`, to fit several estimators on one pass).
        noise: the `NoiseChoice` (joint weights, input noise); None runs `choose_noise` (for
            moments: none, with ``options.weighting="none"``, and the input noise only where
            ``options.input_noise`` gives variances).
        options: `Options` (the estimator, the jackknife, `Compute`).

    Returns:
        An `IdentificationResult` (``theta`` = ``theta_hat``, no projection yet).

    Raises:
        IdentificationError: on options that do not fit the estimator or the data.
        TypeError: on an estimator that is not a `torchjfa.estimators` estimator, or an unknown
            kind of log.
    """
    options = Options() if options is None else options
    if isinstance(data, PreparedData):
        model = data.model_for(model)
    if not isinstance(model, RigidBodyModel):
        raise TypeError(f"model must be a torchjfa.dynamics.RigidBodyModel, got {type(model)}")
    formed = _as_moments(data)
    if noise is None:
        noise = choose_noise(model, data, options) if formed is None else _given_noise(options)
    given = noise_vector(noise.input_noise, model.n_params)
    estimator = make_estimator(options, given)
    n_blocks = _blocks(estimator, options)
    compute = options.compute
    if formed is None:
        logs = data.train if isinstance(data, PreparedData) else data
        stats = stream_moments(model, logs, n_folds=n_blocks, joint_weights=noise.joint_weights,
                               **compute.stream())  # fmt: skip
    else:
        stats = _check_formed(formed, n_blocks, noise, model)
    blocks = stats if n_blocks is not None else None
    moments = sum(stats[1:], stats[0].copy()) if blocks is not None else stats
    folds = blocks if (options.jackknife or estimator.needs_folds) else None
    coefs = std = None
    if options.jackknife:
        coefs, std = _jackknife(estimator, blocks, progress=compute.progress)
    estimator.fit_moments(list(blocks) if estimator.needs_folds else moments)
    theta_hat = estimator.coef_.detach().to(torch.float64)
    metric = given
    if metric is None and hasattr(estimator, "noise_x_"):
        metric = estimator.noise_x_.detach().to(torch.float64).cpu()
    _, world = rank_and_world_size(compute.group) if compute.distributed else (0, 1)
    weights = noise.joint_weights
    return IdentificationResult(
        model=model,
        theta=theta_hat,
        theta_hat=theta_hat,
        estimator=estimator,
        moments=moments,
        folds=folds,
        projection=None,
        input_noise=metric,
        world_size=world,
        theta_hat_std=std,
        joint_weights=None if weights is None else check_joint_weights(weights, model.n_dof),
        theta_hat_jackknife=coefs,
        given_noise=given,
        blocks=blocks,
    )
