"""`signal_bootstrap`: the parametric bootstrap of the flow's estimate through the signal noise."""

from __future__ import annotations

import torch

from ..data import SignalNoise, redrawn_logs
from ..dynamics import RigidBodyModel
from ..estimators import bootstrap
from ..pipeline import stream_moments
from ._options import IdentificationError, Options
from ._stages import NoiseChoice, PreparedData, make_estimator

__all__ = ["signal_bootstrap"]


def signal_bootstrap(
    model: RigidBodyModel,
    data: PreparedData,
    noise: NoiseChoice,
    options: Options | None = None,
    *,
    n_draws: int = 20,
    seed: int = 0,
    signal: SignalNoise | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The spread of the unconstrained estimate by a parametric bootstrap through the sensors.

    Each of ``n_draws`` draws adds white noise of the raw log's estimated sensor noise
    (`torchjfa.data.signal_noise`, from its spectrum; or ``signal``) to its q, qd and tau, runs
    the same preparation (the zero-phase filter, the derivatives; `torchjfa.data.redrawn_logs`),
    forms the training part's moments with the same joint weights and refits the same estimator
    (the same input noise). So the draws carry what the flow does to the noise: filtered,
    correlated torque noise and noisy regressor columns, which a re-draw of white residuals
    (`torchjfa.estimators.redraw_moments`, the least-squares std) misses. The noise is added to
    the log's own, so the refits scatter about the estimate of a log with twice the noise
    variance; their spread is, to first order in the noise, the estimate's.

    Args:
        model: the robot (`load_model`).
        data: the `PreparedData` (with ``raw``, the raw log it was prepared from).
        noise: the `NoiseChoice` of the fit (joint weights and input noise).
        options: the `Options` of the fit (the estimator and its options).
        n_draws: refits, at least 2.
        seed: seeds the draws.
        signal: the raw signals' white noise (default: estimated from the raw log).

    Returns:
        ``(coefs, std)``: ``(n_draws, n_params)`` the refits' unconstrained estimates and
        ``(n_params,)`` their standard deviation, float64.

    Raises:
        IdentificationError: without the raw log, or on ``n_draws < 2``.
    """
    options = Options() if options is None else options
    if data.raw is None:
        raise IdentificationError("the bootstrap needs the raw log (PreparedData.raw)")
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 2:
        raise IdentificationError(f"the bootstrap needs at least 2 draws, got {n_draws!r}")
    model = data.model_for(model)  # the Coulomb term as the preparation chose it, as in `fit`
    estimator = make_estimator(options, noise.input_noise)
    n_train = data.train.n_samples
    folds = max(int(options.jackknife), 2) if estimator.needs_folds else None
    logs = redrawn_logs(data.raw, data.preparation, noise=signal, n_draws=n_draws, seed=seed)
    draws = (
        stream_moments(
            model,
            log.select(slice(0, n_train)),
            n_folds=folds,
            joint_weights=noise.joint_weights,
            chunk_size=options.compute.chunk_size,
            compiled=options.compute.compiled,
        )
        for log in logs
    )
    return bootstrap(estimator, draws)
