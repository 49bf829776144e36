"""The input checks and output buffers of `RigidBodyModel`'s regressor, moments and chunks.

Pure functions on tensors: joint states checked against the model's joints, the ``out=`` tensor
and ``chunk_size`` validated, and large CPU outputs allocated through numpy (huge pages).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from .._validation import as_tensor, check_finite

__all__ = ["check_state", "check_out", "check_chunk", "new_output"]

_NUMPY_ALLOC_MIN = 1 << 20  # elements
_NP_DTYPES = {torch.float64: np.float64, torch.float32: np.float32}
_STATE_NAMES = ("q", "qd", "qdd", "tau")


def check_state(
    *values, joint_names: Sequence[str], names: Sequence[str] = _STATE_NAMES
) -> list[torch.Tensor]:
    """Check joint states against a model's joints and bring them to one dtype.

    While `torch.compile` or `torch.export` traces (``torch.compiler.is_compiling()``), the
    NaN/inf check is skipped: it reads the data, which a traced graph cannot branch on. Shapes
    and devices are still checked (they are known while tracing).

    Args:
        values: ``(*batch, n_dof)`` arrays, by default ``q, qd, qdd`` and optionally ``tau``
            (joint positions, velocities, accelerations and torques; tensors or array-likes,
            non-tensors become float64); a trailing None is dropped.
        joint_names: the model's ``n_dof`` joints, for the error message.
        names: the names of ``values``, for the error messages; the first is the reference
            whose shape and device the others must have.

    Returns:
        The values as tensors of their promoted dtype, in order.

    Raises:
        ValueError: on a wrong last dimension, mismatched shapes or devices, NaN or inf.
    """
    values = list(values)
    while values and values[-1] is None:
        values.pop()
    if not values or len(values) > len(names):
        raise TypeError(f"check_state takes 1 to {len(names)} arrays, got {len(values)}")
    n_dof = len(joint_names)
    vals = [as_tensor(v, name=n) for v, n in zip(values, names, strict=False)]
    shape = vals[0].shape
    if len(shape) == 0 or shape[-1] != n_dof:
        raise ValueError(
            f"{names[0]} must have shape (*batch, {n_dof}) (one column per joint of "
            f"{tuple(joint_names)}), got {tuple(shape)}"
        )
    for v, n in zip(vals[1:], names[1:], strict=False):
        if v.shape != shape:
            raise ValueError(
                f"{n} must have the same shape as {names[0]} {tuple(shape)}, got {tuple(v.shape)}"
            )
        if v.device != vals[0].device:
            raise ValueError(
                f"{n} is on {v.device}, {names[0]} on {vals[0].device}; use one device"
            )
    dtype = vals[0].dtype
    for v in vals[1:]:
        dtype = torch.promote_types(dtype, v.dtype)
    vals = [v.to(dtype) for v in vals]
    if not torch.compiler.is_compiling():
        for v, n in zip(vals, names, strict=False):
            if not v.requires_grad:
                check_finite(v, n)
            elif not bool(torch.isfinite(v.detach()).all()):
                check_finite(v.detach(), n)
    return vals


def new_output(like: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """An uninitialised tensor for a regressor; large CPU ones are allocated by numpy.

    numpy asks the kernel for transparent huge pages on large arrays (``madvise``); first
    touching a 4 kB-paged output of hundreds of MB costs more than computing it.
    """
    numel = int(np.prod(shape))
    if like.device.type == "cpu" and like.dtype in _NP_DTYPES and numel >= _NUMPY_ALLOC_MIN:
        return torch.from_numpy(np.empty(shape, dtype=_NP_DTYPES[like.dtype]))
    return like.new_empty(shape)


def check_out(out, shape, like: torch.Tensor, grad: bool) -> None:
    """Check an ``out=`` tensor: ``shape``, ``like``'s dtype and device, contiguous, no grad."""
    if not isinstance(out, torch.Tensor):
        raise TypeError(f"out must be a torch.Tensor, got {type(out).__name__}")
    if grad or out.requires_grad:
        raise ValueError("out= cannot be used when an input or out requires grad")
    if tuple(out.shape) != tuple(shape) or out.dtype != like.dtype or out.device != like.device:
        raise ValueError(
            f"out must have shape {tuple(shape)}, dtype {like.dtype} and device {like.device}, "
            f"got {tuple(out.shape)}, {out.dtype}, {out.device}"
        )
    if not out.is_contiguous():
        raise ValueError("out must be contiguous")


def check_chunk(chunk_size) -> int:
    """``chunk_size`` (samples per chunk) if it is a positive int; ValueError otherwise."""
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive int, got {chunk_size!r}")
    return chunk_size
