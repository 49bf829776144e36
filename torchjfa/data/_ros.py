"""Joint logs from ROS bags: ``sensor_msgs/JointState`` messages as the library's columns.

Reads ROS 1 ``.bag`` files and ROS 2 bags in SQLite3 and MCAP storage (a bag folder holding
``metadata.yaml``, or one of its ``.db3`` / ``.mcap`` files) with the pure-Python package
``rosbags`` (the optional extra ``torchjfa[ros]``); ROS itself is not needed.

The rules, for a bag recorded from a robot driver:

* Topic: the bag's only ``sensor_msgs/JointState`` topic, or the one named by ``topic``.
* Joints: matched by ``name`` in each message, so drivers that list joints in varying order
  read correctly (every message is reordered to the first kept message's order). A topic can
  carry messages naming different sets of joints (two drivers publishing on one topic, a
  gripper next to an arm): the set named by the most messages is kept (on a tie, the larger
  set, then the one seen first) and the other messages are dropped, with a note saying which.
  Every joint read thus has a value at every time read, and a joint the model needs that was
  dropped is then reported missing by the log's reader.
* Time: ``header.stamp`` of each message, relative to the first kept message's stamp (the
  difference is taken in integer nanoseconds, so a stamp since 1970 keeps its nanoseconds).
  When every stamp is zero (drivers that leave the header empty), the bag's receive times are
  used instead, with a note. Stamps are not sorted or checked here: messages stay in the
  bag's order, and a stamp that repeats or steps back is reported by the log's reader.
* Efforts: the ``effort`` field is the joint torque (``tau_<joint>``) or, for drivers that
  publish the motor current there, the current (``i_<joint>``).
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import numpy as np

from .._util import note
from ._schema import TIME_COLUMN, LogError

__all__ = ["EFFORTS", "JOINT_STATE", "ros_columns"]

#: ``effort=`` values and the column prefix each gives the JointState ``effort`` field.
EFFORTS = {"torque": "tau", "current": "i"}
#: The JointState type as ROS 2 (and rosbags, for ROS 1 bags too) and ROS 1 spell it.
JOINT_STATE = ("sensor_msgs/msg/JointState", "sensor_msgs/JointState")
_STORAGE_SUFFIXES = (".db3", ".mcap")
_EXPECTED = "ROS 2 bag folder with metadata.yaml, its .db3/.mcap file, or a ROS 1 .bag file"


def ros_columns(
    path: str | os.PathLike, *, topic: str | None = None, effort: str = "torque"
) -> dict[str, np.ndarray]:
    """A bag's ``sensor_msgs/JointState`` topic as named float64 columns.

    Args:
        path: a ROS 1 ``.bag`` file, a ROS 2 bag folder (with ``metadata.yaml``), or a ROS 2
            ``.db3`` / ``.mcap`` storage file. A storage file that its folder's
            ``metadata.yaml`` lists is read through that folder (so a split bag is read
            whole); one without it is read alone.
        topic: the JointState topic to read (the leading ``/`` may be left out); default the
            bag's only JointState topic.
        effort: what the messages' ``effort`` field holds: ``"torque"`` (joint torque, N m,
            or force, N, read as ``tau_<joint>``) or ``"current"`` (motor current, A, read as
            ``i_<joint>``).

    Returns:
        Columns of equal length ``(n,)``, float64, in this order: ``t`` (s, 0 at the first
        message), ``q_<joint>`` (position, rad or m) per joint, ``qd_<joint>`` (velocity,
        rad/s or m/s) per joint only when every message read has a full velocity array, then
        ``tau_<joint>`` or ``i_<joint>`` per joint. Joints are in the first message's order.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        LogError: when ``rosbags`` is not installed, ``effort`` is not one of `EFFORTS`, the
            file is not a readable bag, the topic cannot be chosen (none, several, or a
            ``topic`` that is missing or not JointState), the topic has no messages, a
            message repeats a joint or has position/effort arrays that do not match its
            names, or the messages carry no efforts.
    """
    path = Path(path)
    if effort not in EFFORTS:
        raise LogError(
            f"{path}: effort={effort!r} is not known; pass 'torque' when the JointState effort "
            "field holds joint torques, 'current' when it holds motor currents"
        )
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise LogError(
            f"{path}: reading ROS bags needs the rosbags package; install it with "
            'pip install "torchjfa[ros]" (or pip install rosbags)'
        ) from None

    target = _bag_target(path)
    store = Stores.ROS1_NOETIC if target.suffix == ".bag" else Stores.ROS2_HUMBLE
    try:
        # Bags without message definitions (ROS 2 Humble and older) use the default store.
        with AnyReader([target], default_typestore=get_typestore(store)) as reader:
            types = {name: info.msgtype for name, info in reader.topics.items()}
            chosen = _choose_topic(path, types, topic)
            raw = _read_topic(reader, chosen)
    except LogError:
        raise
    except Exception as err:  # rosbags' many reader errors (bad magic, truncated file, ...)
        raise LogError(
            f"{path}: cannot read it as a ROS bag: {type(err).__name__}: {err}; if the "
            "recording was cut short, repair it first (ROS 2: ros2 bag reindex, or mcap "
            "recover for an .mcap file; ROS 1: rosbag reindex)"
        ) from err
    return _columns(path, chosen, raw, EFFORTS[effort])


def _bag_target(path: Path) -> Path:
    """The path to hand to the reader: the bag folder for a storage file it lists."""
    if not path.exists():
        raise FileNotFoundError(f"no ROS bag {str(path)!r}")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise LogError(
                f"{path}: a folder without metadata.yaml is not a ROS 2 bag; pass the bag "
                "folder that holds metadata.yaml, or one of its .db3/.mcap files"
            )
        return path
    if path.suffix == ".bag":
        return path
    if path.suffix not in _STORAGE_SUFFIXES:
        raise LogError(f"{path}: not a ROS bag; expected a {_EXPECTED}")
    meta = path.parent / "metadata.yaml"
    try:
        listed = meta.is_file() and path.name in meta.read_text(errors="replace")
    except OSError:
        listed = False
    return path.parent if listed else path


def _choose_topic(path: Path, types: dict[str, str | None], topic: str | None) -> str:
    """The JointState topic to read: ``topic``, or the bag's only one."""
    joint_states = sorted(name for name, typ in types.items() if typ in JOINT_STATE)
    everything = ", ".join(f"{n} ({t or 'mixed types'})" for n, t in sorted(types.items()))
    found = (
        f"its JointState topics are {', '.join(joint_states)}"
        if joint_states
        else f"it has no JointState topic (its topics: {everything or 'none'})"
    )
    if topic is not None:
        name = topic if topic in types or topic.startswith("/") else "/" + topic
        if name not in types:
            raise LogError(
                f"{path}: the bag has no topic {topic!r}; {found}; pass one of them with "
                "--topic / topic="
            )
        if types[name] not in JOINT_STATE:
            raise LogError(
                f"{path}: topic {name!r} holds {types[name] or 'mixed types'}, not "
                f"sensor_msgs/JointState; {found}; pass one of them with --topic / topic="
            )
        return name
    if len(joint_states) == 1:
        return joint_states[0]
    if not joint_states:
        raise LogError(
            f"{path}: no sensor_msgs/JointState topic in the bag (its topics: "
            f"{everything or 'none'}); record the joints' JointState messages (e.g. "
            "/joint_states) and name the topic with --topic / topic= if there are several"
        )
    raise LogError(
        f"{path}: {len(joint_states)} sensor_msgs/JointState topics "
        f"({', '.join(joint_states)}); pass the one to read with --topic / topic="
    )


def _read_topic(reader, topic: str) -> dict[str, list]:
    """Every message of ``topic``, field by field, in the bag's order."""
    raw: dict[str, list] = {k: [] for k in ("stamp", "received", "name", "q", "qd", "effort")}
    connections = reader.topics[topic].connections
    for connection, received, data in reader.messages(connections=connections):
        msg = reader.deserialize(data, connection.msgtype)
        stamp = msg.header.stamp
        raw["stamp"].append(int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec))
        raw["received"].append(int(received))
        raw["name"].append(tuple(str(n) for n in msg.name))
        raw["q"].append(np.asarray(msg.position, dtype=np.float64))
        raw["qd"].append(np.asarray(msg.velocity, dtype=np.float64))
        raw["effort"].append(np.asarray(msg.effort, dtype=np.float64))
    return raw


def _columns(path: Path, topic: str, raw: dict[str, list], effort_prefix: str) -> dict:
    """The messages of one topic as columns, by the rules of the module's docstring."""
    where = f"{path}: topic {topic}"
    n_msgs = len(raw["name"])
    if n_msgs == 0:
        raise LogError(f"{where} has no messages; record the robot's joint states into it")
    for k, names in enumerate(raw["name"]):
        if len(set(names)) != len(names):
            repeated = sorted({n for n in names if names.count(n) > 1})
            raise LogError(
                f"{where}: message {k} (counting the topic's messages from 0) names joints "
                f"{repeated} more than once; their values cannot be told apart"
            )

    # the joint set named by the most messages; a tie goes to the larger set, then the first
    first_seen: dict[frozenset, int] = {}
    for k, names in enumerate(raw["name"]):
        first_seen.setdefault(frozenset(names), k)
    counts = Counter(frozenset(names) for names in raw["name"])
    named = [s for s in counts if s]  # messages naming no joint hold nothing to read
    if not named:
        raise LogError(
            f"{where}: the messages name no joints (their name arrays are empty), so their "
            "values cannot be matched to the robot's joints"
        )
    joint_set = max(named, key=lambda s: (counts[s], len(s), -first_seen[s]))
    keep = [k for k, names in enumerate(raw["name"]) if frozenset(names) == joint_set]
    joints = raw["name"][keep[0]]
    if len(keep) < n_msgs:
        others = "; ".join(
            f"{counts[s]} naming {sorted(s)}"
            for s in sorted(counts, key=lambda s: -counts[s])
            if s != joint_set
        )
        note(
            f"{where}: read the {len(keep)} messages naming joints {list(joints)} and dropped "
            f"the other {n_msgs - len(keep)} ({others}), which name other joints"
        )

    perms: dict[tuple[str, ...], np.ndarray] = {}
    n_dof = len(joints)

    def gather(field: str, label: str, required: bool) -> np.ndarray | None:
        """``(len(keep), n_dof)`` values of ``field``, reordered to ``joints``; None when
        some message has no full array and the field is not required."""
        rows = np.empty((len(keep), n_dof))
        for i, k in enumerate(keep):
            values, names = raw[field][k], raw["name"][k]
            if values.shape != (n_dof,):
                if not required:
                    return None
                raise LogError(
                    f"{where}: message {k} (counting the topic's messages from 0) has "
                    f"{values.size} {label} values for its {n_dof} joint names; every message "
                    f"needs one {label} per joint"
                )
            perm = perms.get(names)
            if perm is None:
                perm = perms[names] = np.array([names.index(j) for j in joints])
            rows[i] = values[perm]
        return rows

    if all(raw["effort"][k].size == 0 for k in keep):
        raise LogError(
            f"{where}: the messages have no efforts (their effort arrays are empty), so the "
            "log has no joint torques; record a driver that publishes efforts"
        )
    q = gather("q", "position", required=True)
    qd = gather("qd", "velocity", required=False)
    eff = gather("effort", "effort", required=True)

    stamps = np.array([raw["stamp"][k] for k in keep], dtype=np.int64)
    if not stamps.any():
        stamps = np.array([raw["received"][k] for k in keep], dtype=np.int64)
        note(f"{where}: every header stamp is zero; the time is the bag's receive time")
    cols = {TIME_COLUMN: (stamps - stamps[0]).astype(np.float64) / 1e9}
    for prefix, values in (("q", q), ("qd", qd), (effort_prefix, eff)):
        if values is not None:
            for i, joint in enumerate(joints):
                cols[f"{prefix}_{joint}"] = np.ascontiguousarray(values[:, i])
    return cols
