"""Log sources: logs read ``[a, b)`` sample ranges at a time, for streaming identification.

A source is made from an ``.npz`` path (read lazily through `NpzLog`, either layout, so the
memory stays that of a few ranges whatever the file's length), a `JointLog` (a
`torchjfa.sim.SimulatedLog` included), a mapping of arrays, or any object with ``q``, ``qd``,
``qdd`` and ``tau`` ``(n_samples, n_dof)`` arrays (memory-mapped ``.npy`` arrays stay on disk:
only the ranges read are copied). `log_sources` opens one or several and matches their columns
to a model's joints by name; `torchjfa.identification.stream_moments` reads them.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence

import numpy as np
import torch

from ._joints import permutation
from ._npz import NpzLog

__all__ = ["log_length", "log_sources"]

_KEYS = ("q", "qd", "qdd", "tau")
_NEEDS = (
    "a log needs q, qd, qdd and tau (n_samples, n_dof) (differentiate q or qd first, e.g. "
    "with torchjfa.data.prepare or torchjfa.data.differentiate)"
)


class _ArraySource:
    """A log held in memory (or memory-mapped): arrays sliced on demand."""

    def __init__(self, obj, name: str) -> None:
        get = obj.__getitem__ if isinstance(obj, Mapping) else lambda k: getattr(obj, k)
        self.name = name
        self.arrays = {}
        for k in _KEYS:
            try:
                v = get(k)
            except (KeyError, AttributeError):
                v = None
            if v is None:
                raise ValueError(f"{name} has no {k!r}; {_NEEDS}")
            if not isinstance(v, torch.Tensor | np.ndarray):
                v = np.asarray(v, dtype=np.float64)
            self.arrays[k] = v
        shape = tuple(self.arrays["q"].shape)
        for k, v in self.arrays.items():
            if tuple(v.shape) != shape or len(shape) != 2:
                raise ValueError(
                    f"{name}: q, qd, qdd and tau must all have shape (n_samples, n_dof); "
                    f"got {k} {tuple(v.shape)} and q {shape}"
                )
        self.shape = shape
        names = None
        try:
            names = get("joint_names")
        except (KeyError, AttributeError):
            pass
        self.joint_names = None if names is None else tuple(str(s) for s in np.asarray(names))

    def read(self, segments) -> Iterator[tuple]:
        """``((a, b, fold), [q, qd, qdd, tau])`` float64 tensors per ``(a, b, fold)`` segment."""
        for a, b, fold in segments:
            out = []
            for k in _KEYS:
                v = self.arrays[k][a:b]
                if isinstance(v, torch.Tensor):
                    out.append(v.to(torch.float64))
                else:  # copy: memory maps and read-only arrays become ordinary tensors
                    out.append(torch.from_numpy(np.array(v, dtype=np.float64, copy=True)))
            yield (a, b, fold), out


class _NpzSource:
    """An ``.npz`` log read lazily, ``[a, b)`` row ranges straight from the zip members."""

    def __init__(self, path) -> None:
        self.log = NpzLog(path)
        self.name = self.log.name
        missing = [k for k in _KEYS if k not in self.log.members]
        if missing:
            raise ValueError(f"{self.name!r} has no array(s) {missing}; {_NEEDS}")
        self.joint_names = self.log.joint_names
        shapes = {k: self.log.shape(k) for k in _KEYS}
        shape = shapes["q"]
        if len(shape) != 2 or any(s != shape for s in shapes.values()):
            raise ValueError(
                f"{self.name!r}: q, qd, qdd and tau must all have shape (n_samples, n_dof); "
                f"got {shapes}"
            )
        for k in _KEYS:
            dtype = self.log.dtype(k)
            if dtype.kind not in "fiu":
                raise ValueError(f"{self.name!r}: {k} has dtype {dtype}, expected floats")
        self.shape = shape

    def read(self, segments) -> Iterator[tuple]:
        """As `_ArraySource.read`, reading only the rows of each segment."""
        with self.log.open() as rows:
            for a, b, fold in segments:
                yield (a, b, fold), [torch.from_numpy(rows(k, a, b)) for k in _KEYS]


def _open(log, index: int):
    if isinstance(log, str | os.PathLike):
        return _NpzSource(log)
    if isinstance(log, Mapping) or all(hasattr(log, k) for k in _KEYS):
        return _ArraySource(log, f"log {index} ({type(log).__name__})")
    raise TypeError(
        f"log {index} is a {type(log).__name__}; expected an .npz path, a JointLog (or "
        "SimulatedLog), a mapping or an object with q, qd, qdd and tau arrays (n_samples, n_dof)"
    )


def log_sources(logs, joint_names: Sequence[str]) -> list:
    """Open one log or a list of logs as sources whose columns follow ``joint_names``.

    Args:
        logs: an ``.npz`` path, a `JointLog`, a mapping or an object with ``q, qd, qdd, tau``
            ``(n_samples, n_dof)`` arrays, or a list of those.
        joint_names: ``(n_dof,)`` the model's joints; a log with ``joint_names`` has its
            columns matched to them by name, one without must have ``n_dof`` columns.

    Returns:
        Sources with ``name``, ``shape`` ``(n_samples, n_dof)``, ``joint_names``, ``perm``
        (the log's columns in model order, None when already so) and ``read(segments)``,
        which yields ``((a, b, fold), [q, qd, qdd, tau])`` float64 CPU tensors for each
        ``(a, b, fold)`` sample range.

    Raises:
        TypeError: on something that is not a log or a list of logs.
        ValueError: on no logs, a log without one of the four signals, signals of different
            shapes, or joints other than the model's.
        FileNotFoundError: for a path that does not exist.
    """
    items = [logs] if isinstance(logs, str | os.PathLike | Mapping) or hasattr(logs, "q") else logs
    if not isinstance(items, Sequence) or isinstance(items, str):
        raise TypeError(f"logs must be a log or a list of logs, got {type(logs).__name__}")
    if len(items) == 0:
        raise ValueError("no logs given")
    sources = [_open(log, i) for i, log in enumerate(items)]
    for src in sources:
        src.perm = _permutation(tuple(joint_names), src)
    return sources


def _permutation(joint_names: tuple[str, ...], src) -> list[int] | None:
    """Column order that puts the log's joints in the model's order (None: already so)."""
    n_dof = src.shape[1]
    if src.joint_names is None:
        if n_dof != len(joint_names):
            raise ValueError(
                f"{src.name} has {n_dof} joint columns, the model has {len(joint_names)} joints "
                f"{joint_names}"
            )
        return None
    if len(src.joint_names) != n_dof:
        raise ValueError(
            f"{src.name} names {len(src.joint_names)} joints {src.joint_names} for {n_dof} "
            "joint columns"
        )
    perm = permutation(src.joint_names, joint_names, where=src.name, want_name="the model")
    return None if perm == list(range(n_dof)) else perm


def log_length(log) -> int:
    """Number of samples of a log (an ``.npz`` path is not loaded: only its header is read)."""
    return _open(log, 0).shape[0]
