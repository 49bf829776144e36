"""The names every log reader and writer shares: the column prefixes and the log's error."""

from __future__ import annotations

__all__ = ["CURRENT", "KINDS", "COLUMN_KINDS", "TIME_COLUMN", "LogError", "joints_from_columns"]

TIME_COLUMN = "t"
KINDS = ("q", "qd", "qdd", "tau")  # a JointLog's signals; column prefixes, each + "_<joint>"
CURRENT = "i"  # motor current, A: read as torque with drive gains (N m/A), not kept as is
COLUMN_KINDS = (*KINDS, CURRENT)  # every prefix a log file's joint columns may have


class LogError(ValueError):
    """A log that cannot be used as it is; the message says what is wrong and where."""


def joints_from_columns(names) -> list[str]:
    """The joints named by ``<kind>_<joint>`` columns (``q_``, ``qd_``, ``qdd_``, ``tau_``,
    ``i_``), in order of first appearance."""
    joints = []
    for name in names:
        for kind in COLUMN_KINDS:
            if name.startswith(kind + "_") and len(name) > len(kind) + 1:
                j = name[len(kind) + 1 :]
                if j not in joints:
                    joints.append(j)
    return joints
