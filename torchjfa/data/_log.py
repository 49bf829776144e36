"""Joint logs from files: CSV, NPZ, Parquet and ROS bags, columns matched to joints by name.

A log is a table with one row per sample: a time column and, per joint, the measured position,
optionally the velocity (and acceleration), and the measured torque or motor current. The
library's column names are

    t                    time, s (other units: see below)
    q_<joint>            position, rad (m for a prismatic joint)
    qd_<joint>           velocity, rad/s (optional: differentiated from q when absent)
    qdd_<joint>          acceleration, rad/s^2 (optional, rarely measured)
    tau_<joint>          measured joint torque, N m (N)
    i_<joint>            motor current, A (instead of tau_: torque = drive gain (N m/A) x i)

and ``columns=`` maps them to a file's own names, one by one (``{"t": "stamp", "q_shoulder":
"pos[0]"}``) or by pattern (``{"q_{joint}": "pos_{joint}"}``: every column matching the value
is a joint's, the joint being the part ``{joint}`` stands for). Joints may come in any order;
`JointLog.reorder` matches them to a model by name.

Formats, from the suffix (or ``format=``):

- ``.csv``, ``.tsv``, ``.txt``: delimited text, read with pyarrow; the delimiter (tab,
  semicolon, comma or runs of spaces) is found from the first lines, whatever the suffix, and
  decimal commas (``1,25``) are read when the delimiter is not the comma.
- ``.npz``: one array per column under the names above, or matrices ``t`` ``(n,)``, ``q``,
  ``tau`` (and ``qd``, ``qdd``) ``(n, n_dof)`` with ``joint_names`` ``(n_dof,)`` (the layout
  `torchjfa.sim.SimulatedLog.save` writes).
- ``.parquet``, ``.pq``: a table, read with pyarrow.
- ``.bag`` (ROS 1), ``.mcap``, ``.db3`` or a ROS 2 bag folder (holding ``metadata.yaml``):
  the joint states of one topic (``topic=``), time from the header stamps, efforts as torques
  or motor currents (``effort=``).

Time: ``time_scale`` (seconds per unit) converts the time column as given. Without it the
column is taken to be in seconds unless its median step gives a rate below 2 Hz; then it is
read in the first of ms, us and ns giving a rate in [10 Hz, 10 kHz), and the log's
``info["read_notes"]`` says so (else `LogError` asks for ``time_scale``). A clock far from 0
(epoch time) is shifted to start at 0 (``info["time_origin_s"]``), keeping the steps exact.

Every check here raises `LogError` (a ``ValueError``) with a message meant for the person who
recorded the log: every missing column at once, NaN rows (reported with their row numbers;
dropped only on request), time that is not strictly increasing.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .._util import atomic_file
from ._columns import gather, seconds, spike_rows, table_columns
from ._joints import permutation
from ._npz import NpzArchive, npz_columns
from ._schema import KINDS, TIME_COLUMN, LogError

__all__ = ["JointLog", "LogError", "read_log", "write_log", "KINDS", "TIME_COLUMN"]

_FORMATS = ("csv", "npz", "parquet", "ros")
_SUFFIXES = {"pq": "parquet", "txt": "csv", "tsv": "csv", "bag": "ros", "mcap": "ros", "db3": "ros"}
_EFFORTS = ("torque", "current")


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
        info: what `read_log` found (``effort``: ``"torque"`` or ``"current"``,
            ``drive_gains``, ``time_scale``, ``read_notes``: lines on what it converted by
            itself, e.g. the time unit), or, after `torchjfa.data.prepare`, what that did
            (rates, period, samples dropped).
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
        if path.is_dir() and (path / "metadata.yaml").is_file():
            return "ros"  # a ROS 2 bag folder
        fmt = path.suffix.lower().lstrip(".")
        fmt = _SUFFIXES.get(fmt, fmt)
    if fmt not in _FORMATS:
        raise LogError(
            f"{path}: cannot tell the log's format from its name; pass format= one of "
            f"{_FORMATS} (ros: a .bag, .mcap or .db3 file, or a ROS 2 bag folder)"
        )
    return fmt


def _npz_columns(path: Path) -> dict[str, np.ndarray | None]:
    """`npz_columns`, with one-dimensional integer members kept as int64 (time stamps in ns
    lose their last digits as float64)."""
    cols = npz_columns(path)
    archive = NpzArchive(path)
    headers = archive.headers(k for k in archive.members if k in cols)
    ints = [k for k, h in headers.items() if h.dtype.kind in "iu" and len(h.shape) == 1]
    for k, v in archive.arrays(ints).items():
        cols[k] = v.astype(np.int64)
    return cols


def _read_columns(
    path: Path,
    fmt: str,
    *,
    topic: str | None = None,
    effort: str = "torque",
    drop_cut_line: bool = False,
) -> tuple[dict[str, np.ndarray | None], dict]:
    """The file's columns by its own names (None for text columns), and ``info`` entries
    (``format``; ``delimiter`` for text; ``read_notes``)."""
    info: dict = {"format": fmt, "read_notes": []}
    if fmt == "ros":
        from ._ros import ros_columns

        return dict(ros_columns(path, topic=topic, effort=effort)), info
    if fmt == "npz":
        return _npz_columns(path), info
    if fmt == "csv":
        from ._text import read_table

        table, delimiter = read_table(path, drop_cut_line=drop_cut_line, notes=info["read_notes"])
        info["delimiter"] = delimiter
        return table_columns(table, decimal_comma=delimiter != ","), info
    import pyarrow as pa
    from pyarrow import parquet

    try:
        table = parquet.read_table(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise LogError(f"{path}: cannot read it as {fmt}: {exc}") from None
    return table_columns(table), info


def _options(path: Path, fmt: str, topic: str | None, effort: str) -> None:
    if effort not in _EFFORTS:
        raise LogError(f"{path}: effort must be one of {_EFFORTS}, got {effort!r}")
    if fmt != "ros" and (topic is not None or effort != "torque"):
        given = "topic" if topic is not None else "effort"
        raise LogError(
            f"{path}: {given} applies to ROS bags only; in a {fmt} log the columns say what "
            "they hold (tau_<joint> torques, i_<joint> motor currents)"
        )
    if path.is_dir() and fmt != "ros":
        raise LogError(
            f"{path} is a folder, not a log file (a ROS 2 bag folder holds metadata.yaml)"
        )


def read_log(
    path: str | os.PathLike,
    *,
    columns: Mapping[str, str] | None = None,
    joints: Sequence[str] | None = None,
    time_scale: float | None = None,
    drop_nan: bool = False,
    drop_outliers: bool = False,
    drop_cut_line: bool = False,
    format: str | None = None,
    drive_gains: Mapping[str, float] | None = None,
    topic: str | None = None,
    effort: str = "torque",
) -> JointLog:
    """Read a joint log from a CSV, NPZ or Parquet file or a ROS bag (see the module's text).

    Args:
        path: the file (``.csv``/``.tsv``/``.txt``, ``.npz``, ``.parquet``/``.pq``, ``.bag``,
            ``.mcap``, ``.db3``) or a ROS 2 bag folder.
        columns: the library's column names mapped to the file's, by name (``{"t": "time",
            "q_j1": "pos1"}``) or by pattern (``{"q_{joint}": "pos_{joint}",
            "tau_{joint}": "effort_{joint}"}``); names not mapped are looked up as they are.
        joints: the joints to read (default: every joint that has a ``q_``, ``qd_``,
            ``qdd_``, ``tau_`` or ``i_`` column, after the mapping), in this order.
        time_scale: seconds per unit of the time column (1e-9 for nanoseconds), used as given;
            None: seconds, or ms / us / ns when the median step says so (noted in
            ``info["read_notes"]``).
        drop_nan: drop rows where any signal read is NaN or infinite (they are reported, and
            `LogError` is raised, when False).
        drop_outliers: drop rows where a signal holds an isolated spike (`spike_rows`: a
            sample far from both its neighbours and the signal's range); they are reported,
            and `LogError` is raised, when False.
        drop_cut_line: leave out a text log's last line when its number of fields differs
            from the header's (a log cut while it was written; noted in ``info["read_notes"]``);
            a `LogError` names that line otherwise.
        format: ``"csv"``, ``"npz"``, ``"parquet"`` or ``"ros"`` (default from the suffix).
        drive_gains: N m/A per joint name, for a log with motor currents ``i_<joint>`` (A)
            and no torques: ``tau = gain * i``. Every joint read needs one.
        topic: the ``sensor_msgs/JointState`` topic of a ROS bag (default: its only one).
        effort: what a ROS bag's efforts are: ``"torque"`` (N m) or ``"current"`` (A, read
            with ``drive_gains``).

    Returns:
        A `JointLog` with ``q`` and ``tau``, and ``qd``/``qdd`` when the file has them for
        every joint; its ``info`` holds ``format``, ``effort`` (``"torque"`` or
        ``"current"``), ``drive_gains`` (currents only), ``time_scale`` (seconds per unit
        used), ``read_notes`` (one line per thing done without being asked, e.g. the time
        unit, without the file's name), ``delimiter`` (text) and ``time_origin_s`` (s, the
        first stamp subtracted from a clock far from 0).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        LogError: on an unreadable file (naming the delimiter tried), every missing column at
            once (time, a joint's position, torque or current, a mapped name), missing drive
            gains, torques and currents both present with drive gains, a column that is not
            numeric, a velocity column for some joints only, NaN rows (unless ``drop_nan``),
            a time unit not found, time that is not strictly increasing, fewer than two
            samples, or ``topic``/``effort`` for a format that is not a ROS bag.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no log file {str(path)!r}")
    fmt = _format(path, format)
    _options(path, fmt, topic, effort)
    raw, info = _read_columns(path, fmt, topic=topic, effort=effort, drop_cut_line=drop_cut_line)
    t, joints, signals, found = gather(raw, columns, joints, drive_gains, path)
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
    spikes = {f"{k}_{j}": s for k, v in signals.items()
              for j, s in zip(joints, spike_rows(v).T, strict=True) if s.any()}  # fmt: skip
    if spikes:
        spiked = np.flatnonzero(np.any(list(spikes.values()), axis=0))
        where = ", ".join(f"{c} row(s) {_rows(np.flatnonzero(s), 4)}" for c, s in spikes.items())
        if not drop_outliers:
            raise LogError(
                f"{path}: isolated spikes, one sample far from its neighbours and from the "
                f"signal's range ({where}, counting the first usable row as 0): drop those rows "
                "with drop_outliers=True (--drop-outliers), the log is then resampled across "
                "the gaps"
            )
        keep = np.ones(t.size, dtype=bool)
        keep[spiked] = False
        t, signals = t[keep], {k: v[keep] for k, v in signals.items()}
        found["read_notes"] = [*found["read_notes"], f"dropped {spiked.size} rows holding "
                               f"isolated spikes ({where})"]  # fmt: skip
    if t.size < 2:
        raise LogError(f"{path}: the log has {t.size} usable samples; at least 2 are needed")
    t, timing = seconds(t, time_scale, path)
    notes = info.pop("read_notes") + found["read_notes"] + timing["read_notes"]
    info.update(found)
    info.update(timing, read_notes=notes)
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0])
        raise LogError(
            f"{path}: time must increase strictly, but at row {i + 1} it goes from {t[i]:.9g} s "
            f"to {t[i + 1]:.9g} s ({back.size} such steps; sort the log or drop repeated rows)"
        )
    return JointLog(t=t, joint_names=tuple(joints), source=str(path), info=info, **signals)


def write_log(log: JointLog, path: str | os.PathLike, *, format: str | None = None) -> None:
    """Write a `JointLog` as a CSV, NPZ (one array per column) or Parquet file.

    The columns are named as `read_log` reads them (``t``, ``q_<joint>``, ...). The file is
    written whole or not at all (`torchjfa.io.atomic_file`).
    """
    path = Path(path)
    fmt = _format(path, format)
    if fmt == "ros":
        raise LogError(f"{path}: write_log writes csv, npz or parquet files, not ROS bags")
    cols = log.to_columns()
    with atomic_file(path) as tmp:
        if fmt == "npz":
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **cols)
            return
        import pyarrow as pa

        table = pa.table(cols)
        if fmt == "csv":
            from pyarrow import csv

            csv.write_csv(table, tmp)
        else:
            from pyarrow import parquet

            parquet.write_table(table, tmp)
