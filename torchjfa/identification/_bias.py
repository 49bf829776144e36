"""The `correct_bias` stage: the errors-in-variables bias of the unconstrained estimate, from
refits on the raw log with re-drawn sensor noise (`simex_bias`), subtracted before the
projection; `signal_bootstrap`: those refits, the parametric bootstrap of the estimate through
the sensor noise."""

from __future__ import annotations

from dataclasses import replace

import torch

from .._util import progress_bar
from ..data import LogError, SignalNoise, redrawn_logs
from ..dynamics import RigidBodyModel
from ..estimators import bootstrap
from ..report._result import IdentificationResult
from ._fit import make_estimator
from ._noise import NoiseChoice
from ._options import IdentificationError, Options
from ._prepare import PreparedData
from ._stream import stream_moments

__all__ = ["correct_bias", "signal_bootstrap", "simex_bias"]


def signal_bootstrap(
    model: RigidBodyModel,
    data: PreparedData,
    noise: NoiseChoice,
    options: Options | None = None,
    *,
    n_draws: int = 20,
    seed: int = 0,
    signal: SignalNoise | None = None,
    progress: bool = False,
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
        data: the `PreparedData` (with ``parts``, the raw logs it was prepared from).
        noise: the `NoiseChoice` of the fit (joint weights and input noise).
        options: the `Options` of the fit (the estimator and its options).
        n_draws: refits, at least 2.
        seed: seeds the draws.
        signal: the raw signals' white noise (default: estimated from the raw log).
        progress: a progress bar over the refits.

    Returns:
        ``(coefs, std)``: ``(n_draws, n_params)`` the refits' unconstrained estimates and
        ``(n_params,)`` their standard deviation, float64.

    Raises:
        IdentificationError: without the raw log, or on ``n_draws < 2``.
        torchjfa.data.LogError: when the raw log's noise cannot be read from its spectrum.
    """
    options = Options() if options is None else options
    parts = data.training_parts
    if not parts:
        raise IdentificationError("the bootstrap needs the raw logs (PreparedData.parts)")
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 2:
        raise IdentificationError(f"the bootstrap needs at least 2 draws, got {n_draws!r}")
    if signal is not None and len(parts) > 1:
        raise IdentificationError("signal= gives one log's sensor noise; the data hold several")
    model = data.model_for(model)  # the Coulomb term as the preparation chose it, as in `fit`
    estimator = make_estimator(options, noise.input_noise)
    folds = max(int(options.jackknife), 2) if estimator.needs_folds else None
    streams = [
        redrawn_logs(
            part.raw,
            data.preparation,
            noise=signal,
            n_draws=n_draws,
            seed=seed + 7919 * i,
            lazy=True,
        )  # fmt: skip
        for i, part in enumerate(parts)
    ]  # one noisy copy of each log in memory at a time
    with progress_bar(total=n_draws, desc="re-drawn noise", enabled=progress, unit="refit") as bar:

        def draws():
            for logs in zip(*streams, strict=True):
                train = [
                    log.select(slice(0, part.train.n_samples))
                    for log, part in zip(logs, parts, strict=True)
                ]
                yield stream_moments(
                    model,
                    train[0] if len(train) == 1 else train,
                    n_folds=folds,
                    joint_weights=noise.joint_weights,
                    chunk_size=options.compute.chunk_size,
                    compiled=options.compute.compiled,
                )
                bar.update(1)

        return bootstrap(estimator, draws())


def simex_bias(
    model: RigidBodyModel,
    data: PreparedData,
    noise: NoiseChoice,
    theta_hat: torch.Tensor,
    options: Options | None = None,
    *,
    n_draws: int = 20,
    seed: int = 0,
    signal: SignalNoise | None = None,
    progress: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The bias the sensor noise gives the unconstrained estimate, by simulation-extrapolation.

    Noisy regressor columns (above all the differentiated accelerations) bias least squares
    toward zero along the directions they carry (errors in variables), and no spread covers a
    bias. The refits of `signal_bootstrap` see the log's noise plus one more draw of it, twice
    its variance, so their mean moves from ``theta_hat`` by ``b(2 s^2) - b(s^2)``, which to
    first order in the noise variance ``s^2`` is the bias ``b(s^2)`` itself: ``theta_hat``
    less it is the linear extrapolation to no noise (SIMEX, Cook and Stefanski 1994, with
    noise multiples 1 and 2). An estimator given the input noise (Bayesian JFA, JFA) is given
    twice it for the refits, so that it corrects what it can there as it does on the log.

    In simulation (`scripts/spread_coverage.py`, docs/report.md) the corrected estimate lies
    closer to the truth, and the jackknife spread covers it at about the nominal rate, where it
    covers the uncorrected estimate less often than nominal on the head.

    Args:
        model: as for `signal_bootstrap`.
        data: as for `signal_bootstrap`.
        noise: as for `signal_bootstrap`.
        options: as for `signal_bootstrap`.
        n_draws: as for `signal_bootstrap`.
        seed: as for `signal_bootstrap`.
        signal: as for `signal_bootstrap`.
        progress: as for `signal_bootstrap`.
        theta_hat: ``(n_params,)`` the estimate of the log itself (the same estimator, noise
            and joint weights).

    Returns:
        ``(bias, coefs)``: ``(n_params,)`` the bias to subtract from ``theta_hat`` and
        ``(n_draws, n_params)`` the refits (their spread is the bootstrap's).

    Raises:
        IdentificationError: as for `signal_bootstrap`.
        torchjfa.data.LogError: as for `signal_bootstrap`.
    """
    doubled = noise
    if noise.input_noise is not None:
        doubled = replace(noise, input_noise=2.0 * noise.input_noise)
    coefs, _ = signal_bootstrap(
        model, data, doubled, options, n_draws=n_draws, seed=seed, signal=signal,
        progress=progress,
    )  # fmt: skip
    theta_hat = torch.as_tensor(theta_hat, dtype=coefs.dtype, device=coefs.device)
    return coefs.mean(0) - theta_hat, coefs


def correct_bias(
    result: IdentificationResult,
    data: PreparedData | None = None,
    noise: NoiseChoice | None = None,
    options: Options | None = None,
    *,
    bias: torch.Tensor | None = None,
) -> IdentificationResult:
    """Subtract the sensor noise's bias from the unconstrained estimate: the stage after `fit`.

    With ``options.bias_refits(result.estimator)`` refits (``bias_correction="auto"``: 20 for
    OLS, none for the other estimators, whose shrinkage and pruning change with the noise
    level) the bias is `simex_bias`'s, subtracted from ``theta_hat`` and from each of the
    jackknife's refits (so the jackknife spread, now about the corrected estimate, stays).
    Where the raw log's noise cannot be read (its spectrum), the estimate stays as it is and
    the result's ``warnings`` say so.

    Args:
        result: the `IdentificationResult` of `fit` on ``data`` with ``noise`` and ``options``.
        data: the `PreparedData` (with ``raw``, the raw log it was prepared from).
        noise: the `NoiseChoice` of the fit.
        options: the `Options` of the fit.
        bias: ``(n_params,)`` a bias to subtract instead (``data``, ``noise`` and the refits
            are then not needed).

    Returns:
        ``result`` itself when no refits are asked for, else a corrected copy
        (``theta_hat_bias`` and, from the refits, ``theta_hat_redrawn`` set).

    Raises:
        IdentificationError: after `make_consistent`, or on a ``bias`` of the wrong shape or
            not finite.
    """
    if result.projection is not None:
        raise IdentificationError("correct_bias comes before make_consistent, not after it")
    coefs = None
    if bias is None:
        options = Options() if options is None else options
        n_refits = options.bias_refits(result.estimator)
        if not n_refits:
            return result
        if not isinstance(data, PreparedData) or noise is None:
            raise IdentificationError(
                "the bias correction refits on the raw log: pass the PreparedData and the "
                "NoiseChoice of the fit (or bias_correction=0)"
            )
        try:
            bias, coefs = simex_bias(
                result.model, data, noise, result.theta_hat, options, n_draws=n_refits,
                progress=options.compute.progress,
            )  # fmt: skip
        except (LogError, IdentificationError) as err:
            note = (
                f"the estimate is not corrected for the sensor noise's bias ({err}); "
                "bias_correction=0 (--bias-correction 0) turns the correction off"
            )
            return replace(result, warnings=[*result.warnings, note])
    bias = torch.as_tensor(bias, dtype=result.theta_hat.dtype, device=result.theta_hat.device)
    if bias.shape != result.theta_hat.shape or not bool(torch.isfinite(bias).all()):
        raise IdentificationError(
            f"the bias must be {tuple(result.theta_hat.shape)} finite values, got shape "
            f"{tuple(bias.shape)}"
        )
    jack = result.theta_hat_jackknife
    theta_hat = result.theta_hat - bias
    return replace(
        result,
        theta=theta_hat,
        theta_hat=theta_hat,
        theta_hat_jackknife=None if jack is None else jack - bias,
        theta_hat_bias=bias if result.theta_hat_bias is None else result.theta_hat_bias + bias,
        theta_hat_redrawn=coefs,
    )
