"""Robot descriptions shipped with torchjfa (see ``README.md`` here for sources and licences),
and the way to the many more of the ``example-robot-data`` package.

Example:
    >>> from torchjfa.dynamics import RigidBodyModel
    >>> model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda"))  # doctest: +SKIP
    >>> arm = RigidBodyModel.from_urdf(  # doctest: +SKIP
    ...     torchjfa.robots.example_robot_data_path("panda_description/urdf/panda.urdf"),
    ...     fixed_joints=("panda_finger_joint1", "panda_finger_joint2"),
    ... )  # the 7-DoF arm, fingers held closed
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

__all__ = ["path", "available", "example_robot_data_path", "SIMULATED", "simulated_path"]

_ERD = "example-robot-data"
_ERD_ROBOTS = "share/example-robot-data/robots/"

_HERE = Path(__file__).resolve().parent
_FILES = {
    "panda": "panda.urdf",
    "panda_arm": "panda_arm.urdf",
    "branched_tree": "branched_tree.xml",
}

#: the simulated Sarcos-like robots of `torchjfa.sim` (MJCF, MuJoCo simulates them): name -> file
SIMULATED = {"head": "sarcos_head.xml", "arm": "sarcos_arm.xml"}
_SIMULATED_DIR = _HERE.parent / "sim" / "models"


def available() -> tuple[str, ...]:
    """Names accepted by `path`."""
    return tuple(sorted(_FILES))


def path(name: str) -> str:
    """Absolute path of a shipped robot description.

    Args:
        name: one of `available()`: ``"panda"`` (Franka Panda URDF, 7 revolute + 2 prismatic
            finger joints, independent: the upstream ``<mimic>`` is removed; fixed joints to
            the hand), ``"panda_arm"`` (the same with the fingers
            fixed: a 7-DoF arm) or ``"branched_tree"`` (MJCF: a torso with
            two 2-link arms, hinge and slide joints, rotated full inertias).

    Raises:
        ValueError: for an unknown name.
    """
    if name not in _FILES:
        raise ValueError(f"unknown robot {name!r}; available: {available()}")
    return str(_HERE / _FILES[name])


def simulated_path(name: str) -> str:
    """Absolute path of a simulated robot's MJCF file (``"head"`` or ``"arm"``, `SIMULATED`);
    reading the path needs no MuJoCo, simulating the robot does (`torchjfa.sim`).

    Raises:
        ValueError: for an unknown name.
    """
    if name not in SIMULATED:
        raise ValueError(f"unknown simulated robot {name!r}; choose from {tuple(SIMULATED)}")
    return str(_SIMULATED_DIR / SIMULATED[name])


def example_robot_data_path(relative: str) -> str:
    """Absolute path of a robot file of the installed ``example-robot-data`` package.

    ``example-robot-data`` (``pip install example-robot-data``, in torchjfa's ``dev`` extra)
    ships URDFs of about 60 robots (Panda, xArm7, Kinova, UR, SO-100/101, Talos, ...); its
    files lie under ``site-packages/cmeel.prefix/share/example-robot-data/robots/``. torchjfa
    reads them without their meshes. 7-DoF arms among them: ``xarm_description/urdf/xarm7.urdf``,
    ``panda_description/urdf/panda.urdf`` (with ``fixed_joints=("panda_finger_joint1",
    "panda_finger_joint2")``: its fingers are a mimic pair) and
    ``talos_data/robots/talos_left_arm.urdf``.

    Args:
        relative: the file's path below ``robots/``, e.g. ``"panda_description/urdf/panda.urdf"``.

    Returns:
        The absolute path, as a string.

    Raises:
        ModuleNotFoundError: if ``example-robot-data`` is not installed.
        FileNotFoundError: if the package has no such file (the message lists its robots).
    """
    try:
        dist = importlib.metadata.distribution(_ERD)
    except importlib.metadata.PackageNotFoundError:
        raise ModuleNotFoundError(
            f"{_ERD} is not installed; `pip install {_ERD}` (or torchjfa's dev extra) to use "
            f"its robot descriptions (asked for {relative!r})"
        ) from None
    want = _ERD_ROBOTS + str(relative).lstrip("/")
    folders = set()
    for f in dist.files or ():
        name = str(f).replace("\\", "/")
        if name.endswith(want) and (name == want or name[: -len(want)].endswith("/")):
            return str(Path(dist.locate_file(f)).resolve())
        if _ERD_ROBOTS in name:
            folders.add(name.split(_ERD_ROBOTS, 1)[1].split("/", 1)[0])
    raise FileNotFoundError(
        f"{_ERD} {dist.version} has no file robots/{relative}; its robot folders: {sorted(folders)}"
    )
