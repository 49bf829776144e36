"""The names every log reader and writer shares: the column prefixes and the log's error."""

from __future__ import annotations

__all__ = ["KINDS", "TIME_COLUMN", "LogError"]

TIME_COLUMN = "t"
KINDS = ("q", "qd", "qdd", "tau")  # column prefixes, each followed by "_<joint>"


class LogError(ValueError):
    """A log that cannot be used as it is; the message says what is wrong and where."""


def joints_from_columns(names) -> list[str]:
    """The joints named by ``<kind>_<joint>`` columns, in order of first appearance."""
    joints = []
    for name in names:
        for kind in KINDS:
            if name.startswith(kind + "_") and len(name) > len(kind) + 1:
                j = name[len(kind) + 1 :]
                if j not in joints:
                    joints.append(j)
    return joints
