"""The one flow of identification: logs -> regressor -> `Moments` -> estimator -> projection.

`identify` takes a `RigidBodyModel` and one or more joint logs (``.npz`` files, `SimulatedLog` s
or arrays), streams the logs ``chunk_size`` samples at a time through the batched regressor into
`Moments`, fits an estimator (Bayesian JFA by default) on the moments, projects the estimate
onto physically consistent parameters and returns an `IdentificationResult`, whose
`IdentificationResult.inverse_dynamics` is the identified model as an ``nn.Module``.

Memory. The regression matrix (``n_samples * n_dof`` rows of ``n_params`` columns: 4.4 GB for
500,000 samples of a 10-DoF arm) is never formed. ``.npz`` files are read member by member,
``chunk_size`` rows at a time, straight from the zip archive (compressed or not), so the peak
memory is ``O(chunk_size * n_dof * n_params + n_params^2)`` whatever the length of the logs
(about 36 MB of regressor rows for the default 4096 samples of a 10-DoF arm). In-memory logs are
sliced the same way (``np.load(path, mmap_mode="r")`` arrays of ``.npy`` files stay on disk).

Several processes. With ``distributed=True`` (``torch.distributed`` initialised, e.g. by
``torchrun``, by Lightning or by `torchjfa.distributed.process_group`), each process reduces its
contiguous share of the samples of all logs to `Moments` and one all-reduce sums them; every
process then fits the same estimator on the same statistics. See `torchjfa.distributed`.

Use `stream_moments` alone to fit several estimators on the same data; use the pieces
(`RigidBodyModel.moments`, the estimators, `torchjfa.physical.project`) directly for anything
this flow does not cover.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import torch

from ._prior import (
    PRIOR_BLOCKS,
    PRIOR_TOLERANCE,
    PRIOR_WEIGHTS,
    check_description_prior,
    choose_prior_weight,
    pick_prior_weight,
    prior_options,
)
from ._stream import residual_joint_weights, stream_moments
from ._validation import as_tensor, check_finite, check_joint_weights
from .data import log_length
from .distributed import rank_and_world_size
from .dynamics import InverseDynamics, RigidBodyModel
from .estimators import BayesianJFA, LinearEstimator
from .estimators import jackknife as _jackknife
from .physical import ProjectionResult
from .physical import project as _project
from .stats import Moments

__all__ = [
    "Estimate",
    "IdentificationResult",
    "PRIOR_TOLERANCE",
    "PRIOR_WEIGHTS",
    "Projected",
    "blocks_needed",
    "check_estimator",
    "correct_bias",
    "estimate",
    "identify",
    "noise_vector",
    "project_estimate",
    "log_length",
    "residual_joint_weights",
    "stream_moments",
]

_RESERVED = ("layout", "moments", "metric", "input_noise", "parametrization", "theta_hat")


# ---------------------------------------------------------------------------------- identify
@dataclass
class IdentificationResult:
    """What `identify` returns.

    Attributes:
        model: the `RigidBodyModel`.
        theta: ``(n_params,)`` float64, the identified parameters: projected (physically
            consistent) when a projection was made, else ``theta_hat``.
        theta_hat: ``(n_params,)`` the unconstrained estimate: the estimator's ``coef_``, less
            ``theta_hat_bias`` where a bias was corrected.
        estimator: the fitted estimator.
        moments: the `Moments` of all the data (``n_features = n_params``).
        folds: the fold `Moments` (the cross-validation folds or the jackknife blocks), or None.
        projection: the `torchjfa.physical.ProjectionResult`, or None.
        input_noise: ``(n_params,)`` the input-noise variances in the projection's metric
            ``X^T X + N diag(input_noise)`` (None: ``X^T X`` alone).
        world_size: processes that shared the pass over the data.
        theta_hat_std: ``(n_params,)`` the delete-one-block jackknife spread of ``theta_hat``
            (`torchjfa.estimators.jackknife`) when ``identify(..., jackknife=K)``, else None.
        joint_weights: ``(n_dof,)`` the weights of each joint's equations, or None (all 1);
            the moments, and so `rmse`, are of the weighted equations.
        theta_hat_jackknife: ``(K, n_params)`` the leave-one-block-out coefficients behind
            ``theta_hat_std`` (for the spread of combinations, e.g. base parameters), or None.
        prior_weight: the weight of the description prior in the projection (see
            ``identify(..., description_prior=...)``), or None when there was none.
        prior_choice: with ``description_prior="auto"``: weight -> cross-validated RMS torque
            error over the blocks of the training data (N m, weighted equations), else None.
        theta_hat_bias: ``(n_params,)`` the bias estimate subtracted from the estimator's
            ``coef_`` (and from the jackknife's refits) to give ``theta_hat``
            (``identify(..., bias=...)``), or None when none was.
        theta_hat_redrawn: ``(B, n_params)`` the refits on re-drawn noise behind a
            `torchjfa.identify` bias correction (`torchjfa.identification.simex_bias`; their
            spread is a parametric bootstrap's), or None.
        warnings: what the fit found that the user should know (`torchjfa.identify` adds
            them to the report's).
    """

    model: RigidBodyModel
    theta: torch.Tensor
    theta_hat: torch.Tensor
    estimator: LinearEstimator
    moments: Moments = field(repr=False)
    folds: list[Moments] | None = field(repr=False)
    projection: ProjectionResult | None = field(repr=False)
    input_noise: torch.Tensor | None = field(repr=False)
    world_size: int = 1
    theta_hat_std: torch.Tensor | None = field(default=None, repr=False)
    joint_weights: torch.Tensor | None = field(default=None, repr=False)
    theta_hat_jackknife: torch.Tensor | None = field(default=None, repr=False)
    prior_weight: float | None = None
    prior_choice: dict[float, float] | None = field(default=None, repr=False)
    theta_hat_bias: torch.Tensor | None = field(default=None, repr=False)
    theta_hat_redrawn: torch.Tensor | None = field(default=None, repr=False)
    warnings: list[str] = field(default_factory=list, repr=False)

    def __repr__(self) -> str:
        return (
            f"IdentificationResult(n_samples={self.n_samples}, n_params={self.model.n_params}, "
            f"estimator={type(self.estimator).__name__}, projected={self.projection is not None}, "
            f"rmse={self.rmse():.4g}, world_size={self.world_size})"
        )

    @property
    def n_samples(self) -> int:
        """Samples used (rows of the regression divided by the number of joints)."""
        return self.moments.n_rows // self.model.n_dof

    def rmse(self, theta=None) -> float:
        """Training RMS torque error ``sqrt(||tau - Y theta||^2 / (n_samples n_dof))`` from the
        moments (N m), for ``theta`` (default `theta`); with ``joint_weights``, of the weighted
        equations (each joint's residual times its weight)."""
        theta = self.theta if theta is None else theta
        rss = self.moments.rss(theta)
        return float(torch.sqrt(rss.clamp_min(0.0) / self.moments.n))

    def inverse_dynamics(self, *, projected: bool = True, trainable: bool = False):
        """The identified model as an `InverseDynamics` ``nn.Module``.

        Args:
            projected: use `theta` (default) or the unconstrained ``theta_hat``.
            trainable: make theta a trainable parameter (e.g. to learn a residual on top).
        """
        theta = self.theta if projected else self.theta_hat
        return InverseDynamics(self.model, theta.detach().cpu(), trainable=trainable)


def noise_vector(input_noise, d: int) -> torch.Tensor | None:
    """``input_noise`` (None, a scalar or ``(d,)`` variances) as a float64 ``(d,)`` tensor, with
    a clear error on a wrong shape, NaN or a negative variance."""
    if input_noise is None:
        return None
    v = as_tensor(input_noise, name="input_noise", dtype=torch.float64)
    if v.ndim == 0:
        v = v.expand(d).clone()
    if tuple(v.shape) != (d,):
        raise ValueError(
            f"input_noise must be a scalar or have shape ({d},) (one variance per regressor "
            f"column), got {tuple(v.shape)}"
        )
    check_finite(v, "input_noise")
    if bool((v < 0).any()):
        raise ValueError("input_noise holds variances and must be non-negative")
    return v


def check_estimator(estimator) -> LinearEstimator:
    """``estimator`` if it is an unfitted-or-fitted `LinearEstimator` without an intercept."""
    if not isinstance(estimator, LinearEstimator):
        raise TypeError(
            f"estimator must be a torchjfa.estimators estimator, got {type(estimator).__name__}"
        )
    if estimator.fit_intercept:
        raise ValueError(
            f"{type(estimator).__name__}(fit_intercept=True) would fit a torque offset that "
            "inverse dynamics cannot use; pass fit_intercept=False (add friction 'offset' "
            "terms to the model for a per-joint offset)"
        )
    return estimator


def blocks_needed(estimator: LinearEstimator, *, jackknife: int = 0, auto_prior: bool = False):
    """How many contiguous blocks of the samples the moments must come in, or None (one whole).

    The estimator's ``cv`` folds when it chooses a hyper-parameter by cross-validation, else the
    jackknife's blocks, else `PRIOR_BLOCKS` for the description prior's choice."""
    jackknife = int(jackknife)
    if jackknife == 1 or jackknife < 0:
        raise ValueError(f"jackknife must be 0 (off) or at least 2 blocks, got {jackknife}")
    if estimator.needs_folds:
        return int(estimator.cv)
    if jackknife:
        return int(jackknife)
    return PRIOR_BLOCKS if auto_prior else None


@dataclass
class Estimate:
    """What `estimate` returns: the fitted estimator and its unconstrained coefficients.

    Attributes:
        estimator: the fitted estimator.
        theta_hat: ``(n_params,)`` float64, its ``coef_``.
        input_noise: ``(n_params,)`` the input-noise variances given to `estimate`, or None.
        theta_hat_std: ``(n_params,)`` the delete-one-block jackknife spread, or None.
        theta_hat_jackknife: ``(K, n_params)`` the leave-one-block-out coefficients, or None.
        bias: ``(n_params,)`` the bias subtracted from ``coef_`` (`correct_bias`), or None.
    """

    estimator: LinearEstimator
    theta_hat: torch.Tensor
    input_noise: torch.Tensor | None = None
    theta_hat_std: torch.Tensor | None = None
    theta_hat_jackknife: torch.Tensor | None = None
    bias: torch.Tensor | None = None

    @property
    def metric_noise(self) -> torch.Tensor | None:
        """The input noise of the projection's metric ``X^T X + N diag(noise)``: the given
        `input_noise`, else the estimator's own estimate ``noise_x_`` (Bayesian JFA), else None."""
        if self.input_noise is not None or not hasattr(self.estimator, "noise_x_"):
            return self.input_noise
        return self.estimator.noise_x_.detach().to(torch.float64).cpu()


def estimate(
    estimator: LinearEstimator,
    moments: Moments,
    folds: Sequence[Moments] | None = None,
    *,
    input_noise=None,
    jackknife: bool = False,
    progress: bool = False,
) -> Estimate:
    """Fit ``estimator`` (in place) on the training moments: the stage after `stream_moments`.

    Args:
        estimator: an estimator with ``fit_intercept=False`` (see `check_estimator`).
        moments: `Moments` of all the training data.
        folds: their contiguous blocks (`stream_moments(n_folds=...)`), needed by an estimator
            that cross-validates and by the jackknife; None otherwise.
        input_noise: the input-noise variances the projection will use (``(n_params,)``), or
            None to take the estimator's ``noise_x_`` where it has one.
        jackknife: also refit on all blocks but one for the spread (`jackknife`).
        progress: show a progress bar over the jackknife's refits.
    """
    check_estimator(estimator)
    if (estimator.needs_folds or jackknife) and not folds:
        raise ValueError(
            f"{type(estimator).__name__} needs the fold moments here (cross-validation or the "
            "jackknife): pass folds=stream_moments(..., n_folds=K)"
        )
    coefs = theta_hat_std = None
    if jackknife:
        coefs, theta_hat_std = _jackknife(estimator, folds, progress=progress)
    estimator.fit_moments(list(folds) if estimator.needs_folds else moments)
    return Estimate(
        estimator=estimator,
        theta_hat=estimator.coef_.detach().to(torch.float64),
        input_noise=noise_vector(input_noise, moments.n_features),
        theta_hat_std=theta_hat_std,
        theta_hat_jackknife=coefs,
    )


def correct_bias(fit: Estimate, bias) -> Estimate:
    """``fit`` with ``bias`` ``(n_params,)`` subtracted from the estimate and from each of the
    jackknife's refits (so the jackknife spread, now about the corrected estimate, stays)."""
    bias = torch.as_tensor(bias, dtype=fit.theta_hat.dtype, device=fit.theta_hat.device)
    if bias.shape != fit.theta_hat.shape or not bool(torch.isfinite(bias).all()):
        raise ValueError(
            f"the bias must be {tuple(fit.theta_hat.shape)} finite values, got shape "
            f"{tuple(bias.shape)}"
        )
    jack = fit.theta_hat_jackknife
    return replace(
        fit,
        theta_hat=fit.theta_hat - bias,
        theta_hat_jackknife=None if jack is None else jack - bias,
        bias=bias if fit.bias is None else fit.bias + bias,
    )


@dataclass
class Projected:
    """What `project_estimate` returns.

    Attributes:
        theta: ``(n_params,)`` float64 physically consistent parameters.
        projection: the `torchjfa.physical.ProjectionResult`.
        prior_weight: the description prior's weight, or None.
        prior_choice: weight -> cross-validated RMS error when the weight was chosen ("auto").
    """

    theta: torch.Tensor
    projection: ProjectionResult
    prior_weight: float | None = None
    prior_choice: dict[float, float] | None = None


def project_estimate(
    model: RigidBodyModel,
    fit: Estimate,
    moments: Moments,
    folds: Sequence[Moments] | None = None,
    *,
    parametrization: str = "virtual",
    description_prior: float | str | None = None,
    options: Mapping | None = None,
) -> Projected:
    """Project an `Estimate` onto physically consistent parameters (the seed paper's eq. 8).

    The metric is ``X^T X + N diag(fit.metric_noise)``; ``description_prior`` is as for
    `identify` (``"auto"`` needs ``folds``, the training blocks it cross-validates over);
    ``options`` are more `torchjfa.physical.project` keywords."""
    options = dict(options or {})
    bad = sorted(set(options) & set(_RESERVED))
    if bad:
        raise ValueError(f"projection_options may not set {bad}; identify sets them")
    auto = check_description_prior(description_prior, options, True)
    choice = None
    if auto:
        if not folds or len(folds) < 2:
            raise ValueError("description_prior='auto' needs at least two training blocks")
        choice = choose_prior_weight(
            fit.estimator,
            folds,
            model,
            fit.input_noise,
            parametrization,
            options,
            coefs=fit.theta_hat_jackknife,
        )
        description_prior = pick_prior_weight(choice)
    if description_prior is not None:
        options.update(prior_options(model, moments, fit.theta_hat, float(description_prior)))
        if float(description_prior) > 0:  # the prior breaks the ties; a ridge pulls to 0
            options.setdefault("ridge", 0.0)
    noise = fit.metric_noise
    projection = _project(
        fit.theta_hat,
        layout=model,
        moments=moments,
        input_noise=None if noise is None else noise.to(moments.xtx.device),
        parametrization=parametrization,
        **options,
    )
    return Projected(
        theta=projection.theta.detach().to(torch.float64),
        projection=projection,
        prior_weight=None if description_prior is None else float(description_prior),
        prior_choice=choice,
    )


def identify(
    model: RigidBodyModel,
    logs,
    *,
    estimator: LinearEstimator | None = None,
    project: bool = True,
    parametrization: str = "virtual",
    input_noise=None,
    projection_options: Mapping | None = None,
    chunk_size: int = 4096,
    distributed: bool = False,
    group=None,
    device: torch.device | str | None = None,
    progress: bool = False,
    jackknife: int = 0,
    joint_weights=None,
    compiled: bool | None = None,
    description_prior: float | str | None = None,
    bias: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> IdentificationResult:
    """Identify a robot's parameters from prepared joint logs in one streaming pass.

    logs -> `stream_moments` (regressor rows ``chunk_size`` samples at a time) -> `estimate`
    -> `project_estimate` (the seed paper's eq. 8) -> `IdentificationResult`. The regression
    matrix is never formed (see the module docstring); the result equals fitting the same
    estimator on ``Moments.from_data`` of the whole regressor, up to rounding. For a raw log
    (filtering, differentiation, validation split, weighting and noise from the log) use
    `torchjfa.identify`, which calls this.

    Args:
        model: the robot (`RigidBodyModel`).
        logs: one log or a list of logs: ``.npz`` paths, `SimulatedLog` s, mappings or objects
            with ``q, qd, qdd, tau`` ``(n_samples, n_dof)`` arrays (see `stream_moments`).
        estimator: an unfitted estimator with ``fit_intercept=False`` (the torques have no
            intercept: use friction ``"offset"`` terms for one). Default
            ``BayesianJFA(input_noise=input_noise, fit_intercept=False)``. It is fitted in
            place. Estimators that choose a hyper-parameter by cross-validation get
            ``estimator.cv`` contiguous folds of the samples.
        project: project the estimate onto physically consistent parameters.
        parametrization: ``"virtual"`` (eq. 5) or ``"log-cholesky"`` (also the triangle
            inequalities), see `torchjfa.physical.project`.
        input_noise: per-column input-noise variance of the regressor, scalar or
            ``(n_params,)`` (e.g. `torchjfa.data.regressor_noise` ``.input_noise``). Used by the
            default estimator and in the projection's metric ``X^T X + N diag(input_noise)``;
            when None, the metric takes the estimator's ``noise_x_`` if it has one (Bayesian
            JFA's estimate), else ``X^T X`` alone.
        projection_options: more keyword arguments of `torchjfa.physical.project` (``prior``,
            ``prior_weight``, ``ridge``, ``max_iter``, ``tol``, ``warm_start``).
        chunk_size, distributed, group, device, progress, compiled: how the pass over the data
            runs (see `stream_moments`): samples per chunk (memory ``O(chunk_size * n_dof *
            n_params)``), sharing it between the processes of an initialised
            ``torch.distributed`` group (every process gets the same result), the device of the
            regressor, moments and fits (default CPU), progress bars, the regressor's path.
        jackknife: K >= 2 refits the estimator on all but one of K contiguous blocks of the
            samples for ``theta_hat_std`` (K more fits; 0 skips it). An estimator that
            cross-validates uses its ``cv`` folds as the blocks.
        joint_weights: ``(n_dof,)`` weight of each joint's equations (weighted least squares;
            e.g. `residual_joint_weights`). ``input_noise`` must then be of the weighted rows
            (`torchjfa.data.regressor_noise` takes the same weights).
        description_prior: pull the projection towards the description (``model.nominal_theta``:
            its inertials, zero friction) along the directions the data do not determine
            (`torchjfa._prior`): a weight w >= 0 gives each parameter a Gaussian prior of
            standard deviation ``p_k / sqrt(w)`` (``p``: `torchjfa.physical.parameter_scales`,
            each kind in its own typical size) against the residual noise, so that directions
            the data determine barely move; ``"auto"`` chooses it from `PRIOR_WEIGHTS` by
            cross-validation over contiguous blocks of the training data (the jackknife's or
            cross-validation's, else `PRIOR_BLOCKS`): the largest weight whose held-out RMS
            error is within `PRIOR_TOLERANCE` (1%) of the lowest wins. None (default): no
            prior. Needs ``project=True``.
        bias: a function of the estimator's ``(n_params,)`` coefficients returning their bias
            ``(n_params,)``, subtracted from them and from the jackknife's refits before the
            projection (`correct_bias`; e.g. `torchjfa.identification.simex_bias`, which
            `torchjfa.identify` uses), or None to leave them as they are; or None.

    Returns:
        An `IdentificationResult` (``.theta``, ``.theta_hat``, ``.estimator``, ``.moments``,
        ``.projection``, ``.inverse_dynamics()``).

    Raises:
        TypeError: on a model that is not a `RigidBodyModel`, an estimator that is not a
            `LinearEstimator`, or an unknown kind of log.
        ValueError: on an estimator with ``fit_intercept=True``, logs that do not match the
            model, NaN in the logs, a bad ``input_noise`` or bad options.

    Example:
        >>> model = RigidBodyModel.from_mjcf(torchjfa.sim.model_path("head"))  # doctest: +SKIP
        >>> result = identify(model, ["run1.npz", "run2.npz"], progress=True)  # doctest: +SKIP
        >>> tau = result.inverse_dynamics()(q, qd, qdd)                       # doctest: +SKIP
    """
    if not isinstance(model, RigidBodyModel):
        raise TypeError(f"model must be a torchjfa.dynamics.RigidBodyModel, got {type(model)}")
    noise = noise_vector(input_noise, model.n_params)
    if estimator is None:
        estimator = BayesianJFA(input_noise=noise, fit_intercept=False)
    check_estimator(estimator)
    options = dict(projection_options or {})
    auto_prior = check_description_prior(description_prior, options, project)
    n_folds = blocks_needed(estimator, jackknife=jackknife, auto_prior=auto_prior)
    stats = stream_moments(
        model,
        logs,
        chunk_size=chunk_size,
        n_folds=n_folds,
        distributed=distributed,
        group=group,
        device=device,
        progress=progress,
        joint_weights=joint_weights,
        compiled=compiled,
    )
    folds = stats if n_folds is not None else None
    moments = sum(stats[1:], stats[0].copy()) if folds is not None else stats
    fit = estimate(
        estimator, moments, folds, input_noise=noise, jackknife=bool(jackknife), progress=progress
    )
    b = None if bias is None else bias(fit.theta_hat)
    if b is not None:
        fit = correct_bias(fit, b)
    projected = None
    if project:
        projected = project_estimate(
            model,
            fit,
            moments,
            folds,
            parametrization=parametrization,
            description_prior=description_prior,
            options=options,
        )
    _, world = rank_and_world_size(group) if distributed else (0, 1)
    return IdentificationResult(
        model=model,
        theta=fit.theta_hat if projected is None else projected.theta,
        theta_hat=fit.theta_hat,
        estimator=estimator,
        moments=moments,
        # the blocks of the prior's choice alone are not kept
        folds=folds if (jackknife or estimator.needs_folds) else None,
        projection=None if projected is None else projected.projection,
        input_noise=fit.metric_noise,
        world_size=world,
        theta_hat_std=fit.theta_hat_std,
        joint_weights=None
        if joint_weights is None
        else check_joint_weights(joint_weights, model.n_dof),
        theta_hat_jackknife=fit.theta_hat_jackknife,
        prior_weight=None if projected is None else projected.prior_weight,
        prior_choice=None if projected is None else projected.prior_choice,
        theta_hat_bias=fit.bias,
    )
