"""The one ``.npz`` reader: archives read member by member, logs read row range by row range.

`NpzArchive` opens a ``numpy.savez``/``savez_compressed`` file without loading it: the member
names, each member's ``.npy`` header (shape, dtype, where its data starts), a member whole, or
``[a, b)`` row ranges of a member straight from the zip stream (a compressed member is
decompressed as it is read; a forward seek decompresses and skips), so that a reader of row
ranges holds a few of them in memory whatever the member's length. Nothing is unpickled.

`NpzLog` is a joint log in an archive, in either of the library's two layouts:

- matrices ``q``, ``tau`` (and ``qd``, ``qdd``) ``(n, n_dof)`` with an optional ``joint_names``
  ``(n_dof,)`` (what `torchjfa.sim.SimulatedLog.save` writes, and the pipeline's input);
- one ``(n,)`` array per column, ``q_<joint>``, ``tau_<joint>``, ... (what
  `torchjfa.data.write_log` writes).

`torchjfa.data.read_log`, `torchjfa.sim.SimulatedLog.load` and the pipeline's streaming log
sources (`torchjfa.data.log_sources`) all read through this module.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

from ._schema import KINDS, LogError, joints_from_columns

__all__ = ["NpyHeader", "NpzArchive", "NpzLog", "npz_columns", "read_header"]


class NpyHeader(NamedTuple):
    """An ``.npy`` member's header.

    Attributes:
        shape: the array's shape.
        dtype: its dtype.
        fortran_order: True when the array is stored column-major (rows not contiguous).
        offset: the byte where the data starts in the member's stream, or None when the
            header's version is not one this reader knows (the member is then loaded whole).
    """

    shape: tuple[int, ...]
    dtype: np.dtype
    fortran_order: bool
    offset: int | None


def read_header(fh) -> NpyHeader:
    """The `NpyHeader` of an ``.npy`` stream positioned at its start (left after the header)."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
    else:
        return NpyHeader((), np.dtype(np.float64), True, None)
    return NpyHeader(tuple(shape), np.dtype(dtype), bool(fortran), fh.tell())


class NpzArchive:
    """An ``.npz`` file, read one member at a time.

    Args:
        path: the file.

    Attributes:
        path: the file's path, as a string.
        members: the array names (member names without ``.npy``), in the archive's order.

    Raises:
        FileNotFoundError: if ``path`` is not a file.
        LogError: if it is not a zip archive (``numpy.savez``/``savez_compressed``).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = os.fspath(path)
        if not os.path.isfile(self.path):
            raise FileNotFoundError(f"no such log file: {self.path!r}")
        if not zipfile.is_zipfile(self.path):
            raise LogError(f"{self.path!r} is not an .npz file (numpy.savez/savez_compressed)")
        with zipfile.ZipFile(self.path) as zf:
            names = zf.namelist()
        self.members = tuple(n[: -len(".npy")] for n in names if n.endswith(".npy"))
        self._headers: dict[str, NpyHeader] = {}

    def __contains__(self, key: str) -> bool:
        return key in self.members

    def headers(self, keys: Iterable[str]) -> dict[str, NpyHeader]:
        """The headers of the members ``keys`` (read once, then remembered)."""
        keys = list(keys)
        todo = [k for k in keys if k not in self._headers]
        if todo:
            with zipfile.ZipFile(self.path) as zf:
                for k in todo:
                    with zf.open(f"{k}.npy") as fh:
                        self._headers[k] = read_header(fh)
        return {k: self._headers[k] for k in keys}

    def arrays(self, keys: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """The members ``keys`` (default all), each loaded whole."""
        keys = self.members if keys is None else list(keys)
        with zipfile.ZipFile(self.path) as zf:
            return {k: _load(zf, k) for k in keys}

    @contextmanager
    def rows(self) -> Iterator[_Rows]:
        """A reader of row ranges, open while the context lasts: ``reader(key, a, b)`` is rows
        ``[a, b)`` of member ``key`` as float64, best read in increasing ``a``."""
        with zipfile.ZipFile(self.path) as zf:
            reader = _Rows(self, zf)
            try:
                yield reader
            finally:
                reader.close()


def _load(zf: zipfile.ZipFile, key: str) -> np.ndarray:
    with zf.open(f"{key}.npy") as fh:
        try:
            return np.lib.format.read_array(fh, allow_pickle=False)
        except ValueError as exc:  # an object array: pickled Python objects, never unpickled
            raise LogError(
                f"{zf.filename}: member {key!r} holds Python objects, which are not read (they "
                "would be unpickled): save it as a numeric array, np.asarray(x, dtype=float)"
            ) from exc


class _Rows:
    """Row ranges of an archive's members; one open stream per member."""

    def __init__(self, archive: NpzArchive, zf: zipfile.ZipFile) -> None:
        self.archive, self.zf = archive, zf
        self.handles: dict = {}
        self.whole: dict[str, np.ndarray] = {}

    def __call__(self, key: str, a: int, b: int) -> np.ndarray:
        if key in self.whole:
            return np.array(self.whole[key][a:b], dtype=np.float64)
        header = self.archive.headers([key])[key]
        if header.fortran_order or header.offset is None:  # rows not contiguous: load it
            self.whole[key] = _load(self.zf, key)
            return self(key, a, b)
        fh = self.handles.get(key)
        if fh is None:
            fh = self.handles[key] = self.zf.open(f"{key}.npy")
        shape, dtype = header.shape, header.dtype
        width = int(np.prod(shape[1:], dtype=np.int64))
        row = width * dtype.itemsize
        start = header.offset + a * row
        if fh.tell() != start:
            fh.seek(start)  # forward seeks in a compressed member decompress and skip
        data = fh.read((b - a) * row)
        if len(data) != (b - a) * row:
            raise LogError(
                f"{self.archive.path!r}: {key} ends before row {b}; the file is truncated"
            )
        return np.frombuffer(data, dtype=dtype).reshape(b - a, *shape[1:]).astype(np.float64)

    def close(self) -> None:
        for fh in self.handles.values():
            fh.close()


class NpzLog:
    """A joint log in an ``.npz`` archive, in the matrix or the per-column layout.

    Nothing but headers is read at construction; `open` reads ``(b - a, n_dof)`` float64 row
    ranges of a signal in either layout.

    Args:
        path: the file.

    Attributes:
        archive: the `NpzArchive`.
        joint_names: ``(n_dof,)`` the joints (None for matrices without ``joint_names``).
        members: per signal kind present (``"q"``, ``"qd"``, ``"qdd"``, ``"tau"``), the member
            names holding it: ``[kind]`` for a matrix, ``[f"{kind}_{joint}", ...]`` for columns
            (a kind counts as present only when every joint has its column).
        headers: the member headers, by member name.

    Raises:
        FileNotFoundError, LogError: as `NpzArchive`.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.archive = NpzArchive(path)
        members = self.archive.members
        if "q" in members:  # the matrix layout
            self.members = {k: [k] for k in KINDS if k in members}
            self.joint_names = None
            if "joint_names" in members:
                names = self.archive.arrays(["joint_names"])["joint_names"]
                self.joint_names = tuple(str(s) for s in names.reshape(-1))
        else:
            self.joint_names = tuple(joints_from_columns(members))
            self.members = {
                k: [f"{k}_{j}" for j in self.joint_names]
                for k in KINDS
                if self.joint_names and all(f"{k}_{j}" in members for j in self.joint_names)
            }
        self.headers = self.archive.headers(m for ms in self.members.values() for m in ms)

    @property
    def name(self) -> str:
        return self.archive.path

    def shape(self, kind: str) -> tuple[int, ...]:
        """The ``(n, n_dof)`` shape of signal ``kind`` (a matrix's own shape, which may be
        another; for columns of unequal lengths, the lengths)."""
        ms = self.members[kind]
        if len(ms) == 1 and ms[0] == kind:
            return self.headers[kind].shape
        shapes = {self.headers[m].shape for m in ms}
        if len(shapes) != 1 or len(next(iter(shapes))) != 1:
            return tuple(self.headers[m].shape for m in ms)
        return (next(iter(shapes))[0], len(ms))

    def dtype(self, kind: str) -> np.dtype:
        """The dtype of signal ``kind`` (its first non-float member's, if any is not float)."""
        dtypes = [self.headers[m].dtype for m in self.members[kind]]
        return next((d for d in dtypes if d.kind not in "fiu"), dtypes[0])

    @contextmanager
    def open(self) -> Iterator:
        """A reader ``read(kind, a, b) -> (b - a, n_dof)`` float64 rows, open in the context."""
        with self.archive.rows() as rows:

            def read(kind: str, a: int, b: int) -> np.ndarray:
                ms = self.members[kind]
                if len(ms) == 1 and ms[0] == kind:
                    return rows(kind, a, b)
                return np.stack([rows(m, a, b) for m in ms], axis=1)

            yield read


def npz_columns(path: str | os.PathLike) -> dict[str, np.ndarray | None]:
    """An ``.npz`` log as named ``(n,)`` float64 columns (``t``, ``q_<joint>``, ...).

    The matrix layout (with ``joint_names``) is split into ``<kind>_<joint>`` columns; every
    other one-dimensional numeric member is a column as it is; members that are not are None
    (kept so that a message can name them).
    """
    data = NpzArchive(path).arrays()
    if "joint_names" in data and "q" in data:  # matrix layout
        names = [str(s) for s in np.atleast_1d(data["joint_names"])]
        cols: dict[str, np.ndarray | None] = {}
        for k, v in data.items():
            if k in KINDS and v.ndim == 2 and v.shape[1] == len(names):
                for i, j in enumerate(names):
                    cols[f"{k}_{j}"] = v[:, i].astype(np.float64)
            elif v.ndim == 1 and v.dtype.kind in "fiu":
                cols[k] = v.astype(np.float64)
        return cols
    return {
        k: v.astype(np.float64) if v.ndim == 1 and v.dtype.kind in "fiu" else None
        for k, v in data.items()
    }
