"""Error measures of predicted joint torques (or any predicted columns): `nmse` and `rms`.

The one definition of the normalised mean squared error that the whole library reports (the
identification report, the experiments, the residual-dynamics training, the demo). It sits at
the bottom of the package (it imports only torch), so any module may use it.

For each column ``j`` (joint) of ``n`` samples,

    nMSE_j = mean_i (pred_ij - target_ij)^2 / var_j,
    var_j  = mean_i (target_ij - mean_k target_kj)^2,

the variance of the target about its own mean, per column, with the population divisor ``n``
(not ``n - 1``). So ``nMSE_j = 1 - R^2_j`` (`sklearn.metrics.r2_score` per output), 0 is a
perfect prediction and 1 is as good as predicting the target's mean. Each joint is normalised
by its own variance, so a wrist joint counts as much as a shoulder joint whose torques are
100x larger; the mean over joints weights them equally.
"""

from __future__ import annotations

import torch

__all__ = ["nmse", "rms"]


def _errors(prediction, target) -> tuple[torch.Tensor, torch.Tensor]:
    """``(squared errors, target)``, both ``(n, n_cols)`` in the target's dtype (and device)."""
    for name, t in (("prediction", prediction), ("target", target)):
        if not isinstance(t, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    if prediction.shape != target.shape or target.ndim not in (1, 2) or target.shape[0] < 2:
        raise ValueError(
            "prediction and target must have the same shape, (n,) or (n, n_dof) with n >= 2, "
            f"got {tuple(prediction.shape)} and {tuple(target.shape)}"
        )
    if not target.is_floating_point():
        raise TypeError(f"target must be a floating-point tensor, got {target.dtype}")
    return (prediction.to(target) - target) ** 2, target


def nmse(
    prediction: torch.Tensor,
    target: torch.Tensor,
    *,
    per_joint: bool = False,
    allow_constant: bool = False,
):
    """Normalised mean squared error: per joint ``mean((pred - target)^2) / var(target)``.

    ``var`` is the target's variance about its mean, per joint, population (divisor ``n``);
    see the module docstring. Computed in the target's dtype and on its device.

    Args:
        prediction: ``(n, n_dof)`` (or ``(n,)``) predicted values, e.g. torques in N m.
        target: the same shape, the measured values, floating point.
        per_joint: return the ``(n_dof,)`` values instead of their mean.
        allow_constant: give a constant target column ``inf`` instead of raising.

    Returns:
        A 0-d tensor (the mean over joints; for a 1-D target, its one value), or ``(n_dof,)``
        (dimensionless).

    Raises:
        TypeError: if an input is not a tensor, or the target is not floating point.
        ValueError: on mismatched shapes, fewer than 2 samples, or a constant target column
            (its normalised error is undefined) unless ``allow_constant``.

    With ``allow_constant`` a constant target column (a joint whose logged torque never
    changes) gives ``inf`` for any error (NaN for an exact prediction), so that a report can
    still show it rather than fail.
    """
    err2, target = _errors(prediction, target)
    var = target.var(0, unbiased=False)
    if not allow_constant and not bool((var > 0).all()):
        raise ValueError("a target column is constant; its normalised error is undefined")
    per = err2.mean(0) / var
    return per if per_joint else per.mean()


def rms(prediction: torch.Tensor, target: torch.Tensor, *, per_joint: bool = False):
    """Root mean squared error, in the target's units (N m for revolute joints' torques).

    Args:
        prediction: as for `nmse`.
        target: as for `nmse`.
        per_joint: return ``(n_dof,)`` values ``sqrt(mean_i (pred_ij - target_ij)^2)``
            instead of the RMS over every entry (the root of the mean over joints of their
            mean squared errors).

    Returns:
        A 0-d tensor, or ``(n_dof,)``.

    Raises:
        TypeError, ValueError: as for `nmse`.
    """
    mse = _errors(prediction, target)[0].mean(0)
    return mse.sqrt() if per_joint else mse.mean().sqrt()
