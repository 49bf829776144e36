"""Input checks shared by the whole library.

Every public entry point that takes user tensors calls these, so that bad input raises a
``ValueError`` (or ``TypeError``) that says what was wrong and what was expected, instead of a
shape error deep inside a matrix product.
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = [
    "as_tensor",
    "check_coulomb_velocity",
    "check_finite",
    "check_Xy",
    "check_X",
    "check_joint_weights",
]


def as_tensor(value, *, name: str, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
    """Convert array-likes to a floating tensor, keeping tensors' dtype and device.

    Args:
        value: a tensor, numpy array, or nested sequence of numbers.
        name: the argument's name, used in error messages.
        dtype: dtype to cast to; by default a floating tensor keeps its dtype, anything else
            becomes float64.
        device: device to move to; by default a tensor stays where it is.

    Returns:
        A floating-point tensor.

    Raises:
        TypeError: if ``value`` cannot be read as numbers.
    """
    if isinstance(value, torch.Tensor):
        t = value
    else:
        try:
            t = torch.as_tensor(np.asarray(value, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise TypeError(
                f"{name} must be a tensor or array of numbers, got {type(value)}"
            ) from exc
    if dtype is not None:
        t = t.to(dtype)
    elif not t.is_floating_point():
        t = t.to(torch.float64)
    if device is not None:
        t = t.to(device)
    return t


def check_finite(t: torch.Tensor, name: str) -> None:
    """Raise ``ValueError`` if ``t`` has NaN or infinite entries, saying how many and where."""
    bad = ~torch.isfinite(t)
    if bool(bad.any()):
        n_nan = int(torch.isnan(t).sum())
        n_inf = int(bad.sum()) - n_nan
        first = tuple(int(i) for i in torch.nonzero(bad)[0])
        raise ValueError(
            f"{name} has {n_nan} NaN and {n_inf} infinite entries (first at index {first}); "
            "remove or impute them before fitting"
        )


def check_X(
    X, *, name: str = "X", n_features: int | None = None, finite: bool = True
) -> torch.Tensor:
    """Check a design matrix of shape ``(n, d)`` and return it as a floating tensor.

    ``finite=False`` skips the pass over every entry, for callers that detect NaN and inf more
    cheaply themselves (e.g. from the diagonal of ``X^T X``) and then call `check_finite`.
    """
    X = as_tensor(X, name=name)
    if X.ndim != 2:
        raise ValueError(
            f"{name} must be 2-D with shape (n_samples, n_features), got shape {tuple(X.shape)}"
        )
    if X.shape[0] < 1:
        raise ValueError(f"{name} has no rows; at least one sample is needed")
    if X.shape[1] < 1:
        raise ValueError(f"{name} has no columns; at least one feature is needed")
    if n_features is not None and X.shape[1] != n_features:
        raise ValueError(f"{name} has {X.shape[1]} features, expected {n_features}")
    if finite:
        check_finite(X, name)
    return X


def check_Xy(
    X, y, weights=None, *, finite: bool = True
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Check a regression data set.

    Args:
        X: inputs, shape ``(n, d)``.
        y: outputs, shape ``(n,)`` (a trailing singleton dimension ``(n, 1)`` is accepted).
        weights: optional non-negative per-row weights, shape ``(n,)``.
        finite: check ``X`` and ``y`` for NaN and inf (see `check_X`); weights always are.

    Returns:
        ``(X, y, weights)`` as tensors; ``y`` and ``weights`` on ``X``'s device and dtype.

    Raises:
        ValueError: on NaN or inf, mismatched lengths, wrong number of dimensions, no rows or
            negative weights.
    """
    X = check_X(X, finite=finite)
    y = as_tensor(y, name="y", device=X.device)
    if y.ndim == 2 and y.shape[1] == 1:
        y = y[:, 0]
    if y.ndim != 1:
        raise ValueError(f"y must be 1-D with shape (n_samples,), got shape {tuple(y.shape)}")
    if y.shape[0] != X.shape[0]:
        raise ValueError(
            f"X and y have different numbers of samples: {X.shape[0]} and {y.shape[0]}"
        )
    if finite:
        check_finite(y, "y")
    y = y.to(X.dtype)
    if weights is not None:
        weights = as_tensor(weights, name="weights", device=X.device).to(X.dtype)
        if weights.ndim != 1 or weights.shape[0] != X.shape[0]:
            raise ValueError(f"weights must have shape ({X.shape[0]},), got {tuple(weights.shape)}")
        check_finite(weights, "weights")
        if bool((weights < 0).any()):
            raise ValueError("weights must be non-negative")
    return X, y, weights


def check_joint_weights(
    weights, n_dof: int, *, positive: bool = False, dtype=torch.float64, device=None
) -> torch.Tensor | None:
    """Check per-joint weights of the torque equations (weighted least squares).

    Args:
        weights: ``(n_dof,)`` weight of each joint's rows, in the model's joint order, or None
            (no weighting).
        n_dof: the robot's number of joints.
        positive: require every weight ``> 0``; by default a joint may have weight 0 (its rows
            are left out), but not all of them.
        dtype, device: of the returned tensor (default float64, the input's device).

    Returns:
        The weights as a ``(n_dof,)`` tensor, or None when ``weights`` is None.

    Raises:
        TypeError: if ``weights`` cannot be read as numbers.
        ValueError: on another shape, NaN or inf, a negative weight, all weights 0, or a zero
            weight when ``positive``.
    """
    if weights is None:
        return None
    w = as_tensor(weights, name="joint_weights", dtype=dtype, device=device)
    if tuple(w.shape) != (n_dof,):
        raise ValueError(f"joint_weights must have shape ({n_dof},), got {tuple(w.shape)}")
    check_finite(w, "joint_weights")
    if positive and not bool((w > 0).all()):
        raise ValueError(f"joint_weights must be positive, got {w.tolist()}")
    if bool((w < 0).any()) or not bool((w > 0).any()):
        raise ValueError("joint_weights must be non-negative and not all zero")
    return w


def check_coulomb_velocity(value) -> float:
    """A Coulomb smoothing velocity as a float >= 0 (rad/s), or a ValueError naming it."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not (math.isfinite(v) and v >= 0.0):
        raise ValueError(
            f"coulomb_velocity must be a finite number >= 0 (rad/s; 0 for sign(qd)), got {value!r}"
        )
    return v
