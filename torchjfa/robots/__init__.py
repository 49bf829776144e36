"""Robot descriptions shipped with torchjfa (see ``README.md`` here for sources and licences).

Example:
    >>> from torchjfa.dynamics import RigidBodyModel
    >>> model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda"))  # doctest: +SKIP
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["path", "available"]

_HERE = Path(__file__).resolve().parent
_FILES = {
    "panda": "panda.urdf",
    "panda_arm": "panda_arm.urdf",
    "branched_tree": "branched_tree.xml",
}


def available() -> tuple[str, ...]:
    """Names accepted by `path`."""
    return tuple(sorted(_FILES))


def path(name: str) -> str:
    """Absolute path of a shipped robot description.

    Args:
        name: one of `available()`: ``"panda"`` (Franka Panda URDF, 7 revolute + 2 prismatic
            finger joints, fixed joints to the hand), ``"panda_arm"`` (the same with the fingers
            fixed: a 7-DoF arm) or ``"branched_tree"`` (MJCF: a torso with
            two 2-link arms, hinge and slide joints, rotated full inertias).

    Raises:
        ValueError: for an unknown name.
    """
    if name not in _FILES:
        raise ValueError(f"unknown robot {name!r}; available: {available()}")
    return str(_HERE / _FILES[name])
