"""Joint logs from files: CSV, NPZ and Parquet, columns matched to a robot's joints by name.

A log is a table with one row per sample: a time column and, per joint, the measured position,
optionally the velocity (and acceleration), and the measured torque. The library's column names
are

    t                    time, s (``time_scale`` converts other units, e.g. 1e-9 for ns)
    q_<joint>            position, rad (m for a prismatic joint)
    qd_<joint>           velocity, rad/s (optional: differentiated from q when absent)
    qdd_<joint>          acceleration, rad/s^2 (optional, rarely measured)
    tau_<joint>          measured joint torque, N m (N)

and ``columns=`` maps them to a file's own names, e.g. ``{"t": "stamp", "q_shoulder":
"pos[0]"}``. Joints may come in any order; `JointLog.reorder` matches them to a model by name.

NPZ files hold either one array per column under the names above, or matrices ``t`` ``(n,)``,
``q``, ``tau`` (and ``qd``, ``qdd``) ``(n, n_dof)`` with ``joint_names`` ``(n_dof,)`` (the
layout `torchjfa.sim.SimulatedLog.save` writes). CSV and Parquet are read with pyarrow.

Every check here raises `LogError` (a ``ValueError``) with a message meant for the person who
recorded the log: a missing column, NaN rows (reported with their row numbers; dropped only on
request), time that is not strictly increasing.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .._joints import permutation
from ._npz import npz_columns
from ._schema import KINDS, TIME_COLUMN, LogError, joints_from_columns

__all__ = ["JointLog", "LogError", "read_log", "write_log", "KINDS", "TIME_COLUMN"]

_FORMATS = ("csv", "npz", "parquet")


def _rows(idx: np.ndarray, limit: int = 8) -> str:
    shown = ", ".join(str(int(i)) for i in idx[:limit])
    return shown + (f", ... ({len(idx)} in all)" if len(idx) > limit else "")


@dataclass(eq=False)
class JointLog:
    """A joint log: time, per-joint positions, torques and optional velocities/accelerations.

    All arrays are float64 tensors on the CPU with time along the first dimension and joints
    in `joint_names` order.

    Attributes:
        t: ``(n,)`` sample times, s.
        q: ``(n, n_dof)`` positions, rad (m).
        tau: ``(n, n_dof)`` measured torques, N m (N).
        joint_names: ``(n_dof,)`` joint names.
        qd: ``(n, n_dof)`` velocities, rad/s, or None.
        qdd: ``(n, n_dof)`` accelerations, rad/s^2, or None.
        period_samples: samples per excitation period when the excitation is periodic and the
            log is sampled so that a period is a whole number of samples (see
            `torchjfa.data.prepare`), else None.
        source: where the log came from (a path), for messages.
        info: what `torchjfa.data.prepare` did (rates, period, samples dropped).
    """

    t: torch.Tensor
    q: torch.Tensor
    tau: torch.Tensor
    joint_names: tuple[str, ...]
    qd: torch.Tensor | None = None
    qdd: torch.Tensor | None = None
    period_samples: int | None = None
    source: str = "log"
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.joint_names = tuple(str(j) for j in self.joint_names)
        if len(set(self.joint_names)) != len(self.joint_names):
            raise LogError(f"{self.source}: joint names repeat: {self.joint_names}")
        self.t = torch.as_tensor(self.t, dtype=torch.float64).cpu()
        if self.t.ndim != 1:
            raise LogError(
                f"{self.source}: t must have shape (n_samples,), got {tuple(self.t.shape)}"
            )
        shape = (self.t.shape[0], len(self.joint_names))
        for kind in KINDS:
            v = getattr(self, kind)
            if v is None:
                continue
            v = torch.as_tensor(v, dtype=torch.float64).cpu()
            if v.ndim == 1 and shape[1] == 1:
                v = v[:, None]
            if tuple(v.shape) != shape:
                raise LogError(
                    f"{self.source}: {kind} must have shape {shape} (n_samples, n_dof), got "
                    f"{tuple(v.shape)}"
                )
            setattr(self, kind, v)

    @property
    def n_samples(self) -> int:
        return self.t.shape[0]

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample."""
        return float(self.t[-1] - self.t[0]) if self.n_samples > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        """Sampling rate from the median step, Hz."""
        if self.n_samples < 2:
            raise LogError(f"{self.source}: a log needs at least 2 samples for a rate")
        return 1.0 / float(torch.median(torch.diff(self.t)))

    @property
    def n_periods(self) -> int:
        """Whole excitation periods in the log.

        Raises:
            LogError: if the log has no ``period_samples``.
        """
        if self.period_samples is None:
            raise LogError(
                f"{self.source}: the log has no period_samples (a periodic excitation resampled "
                "to whole-sample periods, see torchjfa.data.prepare)"
            )
        return self.n_samples // self.period_samples

    def signals(self) -> dict[str, torch.Tensor]:
        """The ``(n, n_dof)`` signals the log has, by kind (``q``, ``qd``, ``qdd``, ``tau``)."""
        return {k: getattr(self, k) for k in KINDS if getattr(self, k) is not None}

    def _sample_arrays(self) -> dict[str, torch.Tensor]:
        """Every ``(n, n_dof)`` array of the log by attribute name: what `select` slices and
        `reorder` permutes (a subclass with more per-sample arrays adds them here)."""
        return self.signals()

    def _joint_fields(self, perm: list[int]) -> dict:
        """The fields that follow the joints, with their joints in ``perm`` order."""
        return {k: v[:, perm] for k, v in self._sample_arrays().items()}

    def select(self, index) -> JointLog:
        """The samples ``index`` (a slice, a boolean mask or integer indices) as a new log
        (of the same type: a subclass's per-sample arrays are selected too).

        ``period_samples`` is kept only for a slice with step 1 (the phase moves, periods stay
        whole-sample): the noise estimate stacks whole periods from the first sample.
        """
        keep_period = isinstance(index, slice) and index.step in (None, 1)
        return replace(
            self,
            t=self.t[index],
            **{k: v[index] for k, v in self._sample_arrays().items()},
            period_samples=self.period_samples if keep_period else None,
        )

    def reorder(self, joint_names: Sequence[str]) -> JointLog:
        """The log with its columns in ``joint_names`` order (e.g. a model's); a subclass's
        per-joint fields follow.

        Raises:
            LogError: if the log has a joint that is not in ``joint_names`` or lacks one.
        """
        want = tuple(joint_names)
        perm = permutation(self.joint_names, want, where=self.source, error=LogError)
        return replace(self, joint_names=want, **self._joint_fields(perm))

    def split(self, fraction: float, *, gap: int = 0) -> tuple[JointLog, JointLog]:
        """Split into a training head and a held-out tail of about ``fraction`` of the samples.

        Args:
            fraction: the share of samples in the tail, in (0, 1).
            gap: samples dropped between the two parts (so that a filter's reach does not let
                the tail see the head's samples).
        """
        if not 0.0 < fraction < 1.0:
            raise LogError(f"the validation fraction must lie in (0, 1), got {fraction}")
        n = self.n_samples
        n_tail = int(round(fraction * n))
        n_head = n - n_tail - gap
        if n_tail < 1 or n_head < 1:
            raise LogError(
                f"{self.source}: {n} samples cannot be split into a head and a tail of "
                f"{fraction:.0%} with a gap of {gap}"
            )
        return self.select(slice(0, n_head)), self.select(slice(n - n_tail, n))

    def to_columns(self) -> dict[str, np.ndarray]:
        """The log as named float64 columns (``t``, ``q_<joint>``, ...)."""
        cols = {TIME_COLUMN: self.t.numpy()}
        for kind, v in self.signals().items():
            for i, j in enumerate(self.joint_names):
                cols[f"{kind}_{j}"] = v[:, i].numpy()
        return cols


# ------------------------------------------------------------------------------------ reading
def _format(path: Path, fmt: str | None) -> str:
    if fmt is None:
        fmt = path.suffix.lower().lstrip(".")
        fmt = {"pq": "parquet", "txt": "csv", "tsv": "csv"}.get(fmt, fmt)
    if fmt not in _FORMATS:
        raise LogError(
            f"{path}: cannot tell the log's format from its name; pass format= one of {_FORMATS}"
        )
    return fmt


def _table_columns(table, path: Path) -> dict[str, np.ndarray]:
    import pyarrow as pa

    cols = {}
    for name, col in zip(table.column_names, table.columns, strict=True):
        if pa.types.is_integer(col.type) or pa.types.is_floating(col.type):
            cols[name] = col.to_numpy(zero_copy_only=False).astype(np.float64)
        elif pa.types.is_null(col.type):
            cols[name] = np.full(len(col), np.nan)
        else:
            cols[name] = None  # text, kept to name it if it is asked for
    return cols


def _read_columns(path: Path, fmt: str) -> dict[str, np.ndarray | None]:
    if fmt == "npz":
        return npz_columns(path)
    import pyarrow as pa

    try:
        if fmt == "csv":
            from pyarrow import csv

            delimiter = "\t" if path.suffix.lower() == ".tsv" else ","
            table = csv.read_csv(path, parse_options=csv.ParseOptions(delimiter=delimiter))
        else:
            from pyarrow import parquet

            table = parquet.read_table(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise LogError(f"{path}: cannot read it as {fmt}: {exc}") from None
    return _table_columns(table, path)


def read_log(
    path: str | os.PathLike,
    *,
    columns: Mapping[str, str] | None = None,
    joints: Sequence[str] | None = None,
    time_scale: float = 1.0,
    drop_nan: bool = False,
    format: str | None = None,
) -> JointLog:
    """Read a joint log from a CSV, NPZ or Parquet file.

    Args:
        path: the file (``.csv``/``.tsv``, ``.npz`` or ``.parquet``/``.pq``).
        columns: the library's column names mapped to the file's (``{"t": "time", "q_j1":
            "pos1", "tau_j1": "effort1"}``); names not mapped are looked up as they are.
        joints: the joints to read (default: every joint that has a ``q_`` or ``tau_``
            column, after the mapping), in this order.
        time_scale: seconds per unit of the time column (1e-9 for nanoseconds).
        drop_nan: drop rows where any signal read is NaN or infinite (they are reported, and
            `LogError` is raised, when False).
        format: ``"csv"``, ``"npz"`` or ``"parquet"`` (default from the file's suffix).

    Returns:
        A `JointLog` with ``q`` and ``tau``, and ``qd``/``qdd`` when the file has them for
        every joint.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        LogError: on an unreadable file, a missing column (time, or a joint's position or
            torque), a column that is not numeric, a velocity column for some joints only,
            NaN rows (unless ``drop_nan``), time that is not strictly increasing, or fewer
            than two samples.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no log file {str(path)!r}")
    fmt = _format(path, format)
    raw = _read_columns(path, fmt)
    mapping = {str(k): str(v) for k, v in (columns or {}).items()}  # ours -> the file's
    for ours, theirs in mapping.items():
        if theirs not in raw:
            raise LogError(
                f"{path}: the column mapping names {theirs!r} (for {ours!r}) but the file has no "
                f"such column; it has {sorted(raw)}"
            )
    renamed_from = {v: k for k, v in mapping.items()}
    names = [renamed_from.get(n, n) for n in raw]
    if joints is None:
        joints = joints_from_columns(names)
        if not joints:
            raise LogError(
                f"{path}: no joint columns found; expected columns named q_<joint> and "
                f"tau_<joint> (or a column mapping), the file has {sorted(raw)}"
            )
    joints = [str(j) for j in joints]

    def column(name: str) -> np.ndarray:
        source = mapping.get(name, name)
        if source not in raw:
            if name == TIME_COLUMN:
                hint = "a time column 't' in seconds (or map yours: columns={'t': ...})"
            else:
                hint = f"a column {name!r} (or map yours: columns={{{name!r}: ...}})"
            raise LogError(f"{path}: missing column {source!r}; the log needs {hint}")
        v = raw[source]
        if v is None:
            raise LogError(f"{path}: column {source!r} is not numeric")
        return v

    t = column(TIME_COLUMN) * float(time_scale)
    signals: dict[str, np.ndarray] = {}
    for kind in KINDS:
        present = [j for j in joints if mapping.get(f"{kind}_{j}", f"{kind}_{j}") in raw]
        if kind in ("q", "tau") or present:
            if kind in ("qd", "qdd") and len(present) != len(joints):
                missing = [f"{kind}_{j}" for j in joints if j not in present]
                raise LogError(
                    f"{path}: {kind} columns for some joints but not for {missing}; give every "
                    "joint's or none"
                )
            signals[kind] = np.stack([column(f"{kind}_{j}") for j in joints], axis=1)
    bad = ~np.isfinite(t)
    for v in signals.values():
        bad |= ~np.isfinite(v).all(axis=1)
    idx = np.flatnonzero(bad)
    if idx.size:
        if not drop_nan:
            raise LogError(
                f"{path}: {idx.size} of {t.size} rows hold NaN or inf (rows {_rows(idx)}, "
                "counting the first data row as 0); drop them with drop_nan=True "
                "(--drop-nan), the log is then resampled across the gaps"
            )
        keep = ~bad
        t = t[keep]
        signals = {k: v[keep] for k, v in signals.items()}
    if t.size < 2:
        raise LogError(f"{path}: the log has {t.size} usable samples; at least 2 are needed")
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0])
        raise LogError(
            f"{path}: time must increase strictly, but at row {i + 1} it goes from {t[i]:.9g} s "
            f"to {t[i + 1]:.9g} s ({back.size} such steps; sort the log or drop repeated rows)"
        )
    return JointLog(t=t, joint_names=tuple(joints), source=str(path), **signals)


def write_log(log: JointLog, path: str | os.PathLike, *, format: str | None = None) -> None:
    """Write a `JointLog` as a CSV, NPZ (one array per column) or Parquet file.

    The columns are named as `read_log` reads them (``t``, ``q_<joint>``, ...).
    """
    path = Path(path)
    fmt = _format(path, format)
    cols = log.to_columns()
    if fmt == "npz":
        with open(path, "wb") as fh:
            np.savez_compressed(fh, **cols)
        return
    import pyarrow as pa

    table = pa.table(cols)
    if fmt == "csv":
        from pyarrow import csv

        csv.write_csv(table, path)
    else:
        from pyarrow import parquet

        parquet.write_table(table, path)
