"""A log file's columns turned into a joint log's arrays: names, efforts and time units.

`table_columns` turns a pyarrow table into named arrays; `map_columns` applies a column
mapping (names and ``{joint}`` patterns) and finds the joints; `gather` collects time, positions,
velocities and torques (or motor currents times drive gains), reporting every missing column
in one error; `seconds` converts the time column to seconds, finding its unit when none is
given.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence

import numpy as np

from ._schema import COLUMN_KINDS, CURRENT, KINDS, TIME_COLUMN, LogError, joints_from_columns

__all__ = ["gather", "map_columns", "seconds", "table_columns"]

JOINT = "{joint}"
_WHAT = {"q": "position", "qd": "velocity", "qdd": "acceleration", "tau": "torque"}
_WHAT[CURRENT] = "motor current"
_EXAMPLE = "columns={'t': 'stamp', 'q_{joint}': 'pos_{joint}', 'tau_{joint}': 'effort_{joint}'}"

# time units: seconds unless the median step gives a rate below SECONDS_MIN_HZ; then the first
# of UNITS whose rate lies in UNIT_RATES_HZ (one 3-decade window, so at most one fits)
SECONDS_MIN_HZ = 2.0
UNIT_RATES_HZ = (10.0, 10_000.0)
UNITS = (("milliseconds", "ms", 1e-3), ("microseconds", "us", 1e-6), ("nanoseconds", "ns", 1e-9))
# a first time stamp farther from 0 than this many median steps (an absolute clock, e.g. epoch
# time) is subtracted, so that float64 keeps the steps exact; nearer ones are kept as recorded
ORIGIN_STEPS = 1e6


def _names(names, limit: int = 30) -> str:
    names = sorted(names)
    shown = ", ".join(repr(n) for n in names[:limit])
    return f"[{shown}" + (f", ... ({len(names)} in all)]" if len(names) > limit else "]")


def _quoted(names: Sequence[str]) -> str:
    return ", ".join(repr(n) for n in names)


def table_columns(table, *, decimal_comma: bool = False) -> dict[str, np.ndarray | None]:
    """A pyarrow table's columns as ``(n,)`` arrays: integers as int64 (exact, for time
    stamps in ns), floats as float64 (nulls NaN), text as None (kept to name it if asked for).

    Args:
        table: a ``pyarrow.Table``.
        decimal_comma: read text columns whose every value is a number written with a decimal
            comma (``1,25``) or point as float64.
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    cols: dict[str, np.ndarray | None] = {}
    for name, col in zip(table.column_names, table.columns, strict=True):
        if pa.types.is_integer(col.type) and col.null_count == 0:
            cols[name] = col.to_numpy().astype(np.int64)
        elif pa.types.is_integer(col.type) or pa.types.is_floating(col.type):
            cols[name] = col.to_numpy(zero_copy_only=False).astype(np.float64)
        elif pa.types.is_null(col.type):
            cols[name] = np.full(len(col), np.nan)
        elif decimal_comma and pa.types.is_string(col.type):
            text = pc.replace_substring(pc.utf8_trim_whitespace(col), ",", ".")
            try:
                cols[name] = text.cast(pa.float64()).to_numpy(zero_copy_only=False)
            except pa.ArrowInvalid:
                cols[name] = None
        else:
            cols[name] = None
    return cols


def _pattern(ours: str, theirs: str, where) -> re.Pattern:
    kinds = [f"{k}_{JOINT}" for k in COLUMN_KINDS]
    if ours not in kinds or theirs.count(JOINT) != 1:
        raise LogError(
            f"{where}: the column mapping {ours!r}: {theirs!r} is not a pattern: a pattern maps "
            f"one of {kinds} to a name with '{{joint}}' once (e.g. 'q_{{joint}}': "
            "'pos_{joint}')"
        )
    before, after = theirs.split(JOINT)
    return re.compile(re.escape(before) + "(.+)" + re.escape(after))


def map_columns(
    columns: Mapping[str, str] | None, raw: Mapping, where
) -> tuple[dict[str, str], list[str]]:
    """The column mapping (the library's names -> the file's) with its patterns expanded.

    A key and value with ``{joint}`` (``{"q_{joint}": "pos_{joint}"}``) map the columns of
    the file that match the value, each joint being the part that ``{joint}`` stands for; a
    plain entry overrides a pattern's for the same name.

    Returns:
        The mapping, and one line per entry that names no column of the file.

    Raises:
        LogError: on a pattern that is not ``<kind>_{joint}`` mapped to a name with
            ``{joint}`` once.
    """
    mapping: dict[str, str] = {}
    patterns = []
    for ours, theirs in (columns or {}).items():
        ours, theirs = str(ours), str(theirs)
        if JOINT in ours or JOINT in theirs:
            patterns.append((ours, theirs, _pattern(ours, theirs, where)))
        else:
            mapping[ours] = theirs
    unknown = [
        f"{theirs!r} (for {ours!r})" for ours, theirs in mapping.items() if theirs not in raw
    ]
    for ours, theirs, rx in patterns:
        hits = [(m.group(1), name) for name in raw if (m := rx.fullmatch(name))]
        if not hits:
            unknown.append(f"the pattern {theirs!r} (for {ours!r})")
        for joint, name in hits:
            mapping.setdefault(ours.replace(JOINT, joint), name)
    problems = []
    if unknown:
        plural = "no such columns" if len(unknown) > 1 else "no such column"
        problems.append(f"the column mapping names {', '.join(unknown)} but the file has {plural}")
    return mapping, problems


def _gains(drive_gains, joints: Sequence[str], where) -> tuple[dict[str, float], list[str]]:
    if not isinstance(drive_gains, Mapping):
        raise LogError(
            f"{where}: drive_gains must map joint names to N m/A (e.g. {{'{joints[0]}': 0.5}}), "
            f"got a {type(drive_gains).__name__}"
        )
    gains = {str(k): float(v) for k, v in drive_gains.items()}
    bad = [j for j in joints if j in gains and not (math.isfinite(gains[j]) and gains[j] != 0)]
    if bad:
        raise LogError(
            f"{where}: the drive gains of joint(s) {bad} are {[gains[j] for j in bad]}; a "
            "drive gain (N m/A) must be a finite number other than 0"
        )
    missing = [j for j in joints if j not in gains]
    problems = [f"no drive gain (N m/A) for joint(s) {missing}"] if missing else []
    return {j: gains[j] for j in joints if j in gains}, problems


def _effort(has, joints, drive_gains, where) -> tuple[str, list[str]]:
    """The effort kind to read (``"tau"`` or ``"i"``), and the problems found on the way."""
    tau = [j for j in joints if has(f"tau_{j}")]
    current = [j for j in joints if has(f"{CURRENT}_{j}")]
    if tau and current and drive_gains is not None:
        raise LogError(
            f"{where}: the log has both torques (tau_<joint>, N m) and motor currents "
            "(i_<joint>, A) and drive gains were given, so it is ambiguous which to use: leave "
            "out the drive gains to use the torques, or remove (or rename) the tau_<joint> "
            "columns to use the currents"
        )
    if tau or not current:
        return "tau", []
    if drive_gains is None:
        return CURRENT, [
            "the log has motor currents i_<joint> (A) and no torques; give the drive gains "
            "(N m/A) per joint (drive_gains=, --drive-gains G1,G2,... or joint=G,...)"
        ]
    return CURRENT, []


def _missing(joints, effort: str, mapping, raw) -> list[str]:
    """The library's names of the columns needed and absent (a mapped name that is absent is
    reported with the mapping, not here)."""
    names = [TIME_COLUMN] + [f"{k}_{j}" for k in ("q", effort) for j in joints]
    return [n for n in names if n not in mapping and n not in raw]


def _missing_line(missing: Sequence[str]) -> str:
    described = [
        f"{n!r} ({'time, s' if n == TIME_COLUMN else _WHAT[n.split('_', 1)[0]]})" for n in missing
    ]
    word = "columns" if len(missing) > 1 else "column"
    return f"missing {word} {', '.join(described)}"


def gather(
    raw: Mapping[str, np.ndarray | None],
    columns: Mapping[str, str] | None,
    joints: Sequence[str] | None,
    drive_gains: Mapping[str, float] | None,
    where,
) -> tuple[np.ndarray, list[str], dict[str, np.ndarray], dict]:
    """Time, joints and signals from a file's columns.

    Args:
        raw: the file's columns by its own names (None for text).
        columns, joints, drive_gains: as `torchjfa.data.read_log`.
        where: the file, for messages.

    Returns:
        ``(t, joints, signals, info)``: the time column as stored (int64 or float64, not yet in
        seconds), the joint names, ``(n, n_dof)`` float64 arrays by kind of `KINDS` (``tau``
        computed from motor currents when the log has those instead), and ``info`` entries
        ``effort`` (``"torque"`` or ``"current"``) and, for currents, ``drive_gains``.

    Raises:
        LogError: one for everything missing at once (mapped names the file lacks, the time
            column, each joint's position and torque or current, drive gains), or on text
            columns, velocity columns for some joints only, or ambiguous efforts.
    """
    mapping, problems = map_columns(columns, raw, where)
    renamed_from = {theirs: ours for ours, theirs in mapping.items()}
    names = [renamed_from.get(n, n) for n in raw]
    inferred = joints is None
    if inferred:
        joints = joints_from_columns(names)
        if not joints:
            problems.append(
                "no joint columns found; expected columns named q_<joint> and tau_<joint> (or "
                f"i_<joint>), or a mapping such as {_EXAMPLE}"
            )
            raise LogError(f"{where}: {'; '.join(problems)}; the file has {_names(raw)}")
    joints = [str(j) for j in joints]

    def has(name: str) -> bool:
        return mapping.get(name, name) in raw

    effort, found = _effort(has, joints, drive_gains, where)
    problems += found
    gains = None
    if effort == CURRENT and drive_gains is not None:
        gains, found = _gains(drive_gains, joints, where)
        problems += found
    missing = _missing(joints, effort, mapping, raw)
    if missing:
        problems.append(f"{_missing_line(missing)}; map the file's own names with {_EXAMPLE}")
    if problems:
        raise LogError(f"{where}: {'; '.join(problems)}; the file has {_names(raw)}")
    sources = {TIME_COLUMN: [TIME_COLUMN]}  # kind -> the library's names of its columns
    for kind in KINDS:
        source = effort if kind == "tau" else kind
        present = [j for j in joints if has(f"{source}_{j}")]
        if kind in ("qd", "qdd") and present and len(present) != len(joints):
            absent = [f"{kind}_{j}" for j in joints if j not in present]
            others = [j for j in joints if j not in present]
            maybe = (
                f" (if {others} are not joints of the robot, remove their columns or read the "
                "robot's joints only with joints=)"
                if inferred
                else ""
            )
            raise LogError(
                f"{where}: {kind} columns for some joints but not for {absent}; give every "
                f"joint's or none{maybe}"
            )
        if kind in ("q", "tau") or present:
            sources[kind] = [f"{source}_{j}" for j in joints]
    text = [mapping.get(n, n) for ns in sources.values() for n in ns]
    text = [c for c in text if raw[c] is None]
    if text:
        are = "columns {} are not numeric" if len(text) > 1 else "column {} is not numeric"
        raise LogError(f"{where}: {are.format(_quoted(text))}")
    t = raw[mapping.get(TIME_COLUMN, TIME_COLUMN)]
    other = {c: len(raw[c]) for c in dict.fromkeys(mapping.get(n, n) for ns in sources.values()
                                                     for n in ns) if len(raw[c]) != len(t)}  # fmt: skip
    if other:
        raise LogError(
            f"{where}: the columns have different lengths: the time has {len(t)} rows, but "
            + ", ".join(f"{c!r} {n}" for c, n in list(other.items())[:4])
            + (f" and {len(other) - 4} more" if len(other) > 4 else "")
            + "; give every column one value per sample"
        )
    signals = {
        kind: np.stack([raw[mapping.get(n, n)].astype(np.float64) for n in ns], axis=1)
        for kind, ns in sources.items()
        if kind != TIME_COLUMN
    }
    info: dict = {"effort": "torque", "read_notes": []}
    if effort == CURRENT:
        signals["tau"] = signals["tau"] * np.array([gains[j] for j in joints])
        info.update(effort="current", drive_gains=gains)
    elif drive_gains is not None:
        info["read_notes"].append("the drive gains are not used: the log has torques (tau_<joint>)")
    return t, joints, signals, info


#: an isolated spike stands out from both its neighbours by more than this many robust steps
#: of its channel (1.4826 x the median absolute sample-to-sample change, at least its smallest
#: nonzero change: the quantum of a channel that mostly stands still) ...
SPIKE_STEPS = 20.0
#: ... and by more than this many times the channel's range (of its three-sample running
#: median, which no isolated spike reaches):
#: out of the signal's whole envelope and back within one sample, which no joint moves or
#: pushes like; smaller one-sample spikes (a current's peak) are left to the fit
SPIKE_RANGE = 5.0


def spike_rows(x: np.ndarray) -> np.ndarray:
    """Where ``(n, c)`` samples hold isolated spikes, channel by channel: one sample
    above (or below) both its neighbours by more than `SPIKE_STEPS` robust steps and
    `SPIKE_RANGE` times the channel's range (a glitch, a byte error, 1e30 for a missing value).
    Steps (a friction's sign change) and bursts of several samples are motion, not spikes.

    Returns:
        ``(n, c)`` bool (``(n, 1)`` for ``(n,)`` samples): where the spikes are.
    """
    x = np.asarray(x, dtype=np.float64).reshape(len(x), -1)
    found = np.zeros(x.shape, dtype=bool)
    if len(x) < 5:
        return found
    up, down = x[1:-1] - x[:-2], x[1:-1] - x[2:]
    jump = np.where(up * down > 0, np.minimum(np.abs(up), np.abs(down)), 0.0)
    change = np.abs(np.diff(x, axis=0))
    quantum = np.where(change > 0, change, np.inf).min(axis=0)
    step = np.maximum(1.4826 * np.median(change, axis=0), np.where(np.isinf(quantum), 0, quantum))
    smooth = np.median(np.stack([x[:-2], x[1:-1], x[2:]]), axis=0)  # no isolated spike left
    span = smooth.max(axis=0) - smooth.min(axis=0)
    found[1:-1] = (jump > SPIKE_STEPS * step) & (jump > SPIKE_RANGE * span)
    return found


def _unit(h: float, where) -> tuple[float, list[str]]:
    """Seconds per unit of a time column whose median step is ``h`` units, and the note."""
    if not h > 0 or 1.0 / h >= SECONDS_MIN_HZ:
        return 1.0, []
    lo, hi = UNIT_RATES_HZ
    for name, symbol, scale in UNITS:
        rate = 1.0 / (h * scale)
        if lo <= rate < hi:
            return scale, [
                f"time read as {name} (median step {h:.4g} {symbol} -> {rate:.4g} Hz); "
                "pass time_scale=1 (--time-scale 1) if it is in seconds, or the seconds per "
                "unit of the time column"
            ]
    raise LogError(
        f"{where}: cannot tell the time column's unit: its median step {h:.4g} gives "
        f"{1.0 / h:.3g} Hz in seconds (below {SECONDS_MIN_HZ:g} Hz) and no rate within "
        f"{lo:g} Hz-{hi / 1000:g} kHz in ms, us or ns; pass time_scale= (--time-scale) with the "
        "seconds per unit of the time column (e.g. 1e-9 for ns)"
    )


def seconds(t: np.ndarray, time_scale: float | None, where) -> tuple[np.ndarray, dict]:
    """The time column in seconds.

    Args:
        t: ``(n,)`` finite time stamps as stored (int64 or float64), ``n >= 2``.
        time_scale: seconds per unit; None finds the unit from the median step (see
            `SECONDS_MIN_HZ`, `UNITS`, `UNIT_RATES_HZ`).
        where: the file, for messages.

    Returns:
        ``(n,)`` float64 seconds, and ``info`` entries ``time_scale`` (seconds per unit used),
        ``read_notes`` (a line, without the file's name, when the unit was found not to be
        seconds) and, for a clock far
        from 0 (`ORIGIN_STEPS`), ``time_origin_s`` (the first stamp in seconds, subtracted).

    Raises:
        LogError: on a ``time_scale`` that is not a positive number, or a unit not found.
    """
    steps = np.asarray(t - t[0], dtype=np.float64)  # exact for int64 stamps (ns since 1970)
    h = float(np.median(np.diff(steps)))
    notes: list[str] = []
    if time_scale is None:
        scale, notes = _unit(h, where)
    else:
        scale = float(time_scale)
        if not (math.isfinite(scale) and scale > 0):
            raise LogError(
                f"{where}: time_scale must be the seconds per unit of the time column (a "
                f"positive number, e.g. 1e-9 for ns), got {time_scale!r}"
            )
    info: dict = {"time_scale": scale, "read_notes": notes}
    start = float(t[0]) * scale
    if h > 0 and abs(start) > ORIGIN_STEPS * h * scale:
        info["time_origin_s"] = start
        return steps * scale, info
    return np.asarray(t, dtype=np.float64) * scale, info
