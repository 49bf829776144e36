"""`IdentificationResult`: what the fit stages of `torchjfa.identification` hand on to each other
and to the report (`torchjfa.identification.fit` makes it; `correct_bias` and `make_consistent`
return updated copies; `torchjfa.report.make_report` reads it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ..dynamics import InverseDynamics, RigidBodyModel
from ..estimators import LinearEstimator
from ..physical import ProjectionResult
from ..stats import Moments

__all__ = ["IdentificationResult", "PRIOR_TOLERANCE"]

#: the description prior's weights whose held-out errors lie within this fraction of the best
#: one's tie (`torchjfa.identification.pick_prior_weight` takes the largest of them)
PRIOR_TOLERANCE = 0.01


@dataclass
class IdentificationResult:
    """The fit of a robot's parameters, as the stages `fit` -> `correct_bias` ->
    `make_consistent` of `torchjfa.identification` pass it on (each returns an updated copy).

    Attributes:
        model: the `RigidBodyModel`.
        theta: ``(n_params,)`` float64, the identified parameters: projected (physically
            consistent) once `make_consistent` ran, else ``theta_hat``.
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
            (`torchjfa.estimators.jackknife`) with ``Options(jackknife=K)``, else None.
        joint_weights: ``(n_dof,)`` the weights of each joint's equations, or None (all 1);
            the moments, and so `rmse`, are of the weighted equations.
        theta_hat_jackknife: ``(K, n_params)`` the leave-one-block-out coefficients behind
            ``theta_hat_std`` (for the spread of combinations, e.g. base parameters), or None.
        prior_weight: the weight of the description prior in the projection
            (``Options.description_prior``), or None when there was none.
        prior_choice: with ``description_prior="auto"``: weight -> cross-validated RMS torque
            error over the blocks of the training data (N m, weighted equations), else None.
        theta_hat_bias: ``(n_params,)`` the bias estimate subtracted from the estimator's
            ``coef_`` (and from the jackknife's refits) to give ``theta_hat``
            (`torchjfa.identification.correct_bias`), or None when none was.
        theta_hat_redrawn: ``(B, n_params)`` the refits on re-drawn noise behind that bias
            correction (`torchjfa.identification.simex_bias`; their spread is a parametric
            bootstrap's), or None.
        warnings: what the stages found that the user should know (`torchjfa.identify` adds
            them to the report's).
        given_noise: ``(n_params,)`` the input noise given to the estimator (None where it
            learns its own or takes none); ``input_noise`` is the projection's metric.
        blocks: the contiguous blocks of the training moments the description prior's weight
            is cross-validated over (``description_prior="auto"``), or None.
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
    given_noise: torch.Tensor | None = field(default=None, repr=False)
    blocks: list[Moments] | None = field(default=None, repr=False)

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

    def inverse_dynamics(self, *, projected: bool = True, trainable: bool | str = False):
        """The identified model as an `InverseDynamics` ``nn.Module``.

        Args:
            projected: use `theta` (default) or the unconstrained ``theta_hat``.
            trainable: False (frozen), True (trained through the consistent parametrisation)
                or ``"unconstrained"`` (see `torchjfa.dynamics.InverseDynamics`).
        """
        theta = self.theta if projected else self.theta_hat
        return InverseDynamics(self.model, theta.detach().cpu(), trainable=trainable)
