"""Error measures of predicted joint torques."""

from __future__ import annotations

import torch

__all__ = ["nmse"]


def nmse(prediction: torch.Tensor, target: torch.Tensor, *, per_joint: bool = False):
    """Normalised mean squared error: per joint ``mean((pred - target)^2) / var(target)``.

    Args:
        prediction, target: ``(n, n_dof)`` torques.
        per_joint: return the ``(n_dof,)`` values instead of their mean.

    Returns:
        A 0-d tensor (mean over joints), or ``(n_dof,)``.

    Raises:
        ValueError: on mismatched shapes, fewer than 2 samples, or a constant target column.
    """
    if prediction.shape != target.shape or target.ndim != 2 or target.shape[0] < 2:
        raise ValueError(
            "prediction and target must have the same shape (n >= 2, n_dof), got "
            f"{tuple(prediction.shape)} and {tuple(target.shape)}"
        )
    var = target.var(0, unbiased=False)
    if not bool((var > 0).all()):
        raise ValueError("a target column is constant; its normalised error is undefined")
    per = ((prediction.to(target.dtype) - target) ** 2).mean(0) / var
    return per if per_joint else per.mean()
