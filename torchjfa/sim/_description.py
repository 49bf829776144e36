"""Any robot description in MuJoCo: a URDF or MJCF file compiled for `generate_log`.

`load_description` compiles a description with MuJoCo's own parsers into the robot that
`generate_log` and `computed_torque` simulate, keeping what the rigid-body dynamics need and
replacing what would get in the way of tracking a trajectory with torques:

* kept: the kinematic tree, the inertials (a URDF's ``<inertial>``, an MJCF's bodies as
  MuJoCo compiles them, meshes included where the files are found), the gravity (a URDF's is
  ``(0, 0, -9.81)`` m/s^2 in the root frame, an MJCF's its ``<option gravity>``) and the joint
  ranges (they bound the random excitation and the check of a given trajectory);
* URDF: every ``<visual>`` and ``<collision>`` is dropped before MuJoCo reads the file, so no
  mesh needs to be found (contacts are off anyway); links joined by fixed joints are fused
  into their parent (``fusestatic``), as torchjfa's `RigidBodyModel` lumps them;
* replaced: the description's actuators, sensors and keyframes by one motor per joint in joint
  order (gear 1, no control range: ``ctrl`` is the joint torque in N m, or N for a slide
  joint); contacts off; the RK4 integrator; a joint's ``actuatorfrcrange`` (a URDF's
  ``<limit effort>``) is recorded in `Description.effort_limit` and not enforced, so the
  torques a trajectory needs are applied and logged as they are; gravity compensation
  (``gravcomp``) off;
* joint effects (damping, armature, frictionloss, stiffness; see `torchjfa.sim.EFFECTS`): off
  by default, so the simulated robot is the description's rigid body; ``own_effects=True``
  keeps the ones the description writes (a URDF's ``<dynamics damping friction>``, an MJCF's
  joint attributes), and ``effects`` sets any of them (unmodelled effects for the identified
  model to meet).

A description MuJoCo cannot compile, a joint that is neither a hinge nor a slide (a floating
base, a ball joint), an unnamed joint, an equality constraint (a ``<mimic>`` joint) or a moving
link without mass raise `DescriptionError`, whose message says which.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field

import mujoco
import numpy as np

from .. import robots
from ..dynamics._mjcf import strip_urdf_for_mujoco
from ..dynamics._urdf import check_urdf_elements
from ._robots import EFFECTS, _fields, check_hinge_robot, joint_names, set_effects

__all__ = ["Description", "DescriptionError", "load_description", "description_path"]

_ONE_DOF = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)


class DescriptionError(ValueError):
    """A description that cannot be simulated (the message names the file and the reason)."""


@dataclass(frozen=True)
class Description:
    """A robot description compiled for simulation (see the module).

    Attributes:
        model: the ``mujoco.MjModel``: ``n_dof`` hinge or slide joints, one gear-1 motor per
            joint in joint order, contacts off, RK4, the chosen joint effects.
        name: the robot as it was given (a shipped robot's name or the path).
        path: the description file's absolute path.
        format: ``"urdf"`` or ``"mjcf"``.
        joint_names: ``(n_dof,)`` the joints in MuJoCo order (a URDF's in file order).
        effort_limit: ``(n_dof,)`` N m (N for a slide joint): a URDF's ``<limit effort>``, an
            MJCF joint's ``actuatorfrcrange`` (the larger magnitude); ``inf`` where none.
        velocity_limit: ``(n_dof,)`` rad/s (m/s): a URDF's ``<limit velocity>`` (MJCF has
            none); ``inf`` where none.
        own_effects: the joint effects the description writes, name -> ``(n_dof,)`` (units as
            `torchjfa.sim.set_effects`), whether or not they are simulated.
    """

    model: mujoco.MjModel
    name: str
    path: str
    format: str
    joint_names: tuple[str, ...]
    effort_limit: np.ndarray
    velocity_limit: np.ndarray
    own_effects: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    @property
    def effects(self) -> dict[str, np.ndarray]:
        """The joint effects simulated, name -> ``(n_dof,)`` (copies)."""
        return {k: np.array(v, dtype=np.float64) for k, v in _fields(self.model).items()}


def description_path(robot: str | os.PathLike) -> tuple[str, str]:
    """The file and format of a robot: a shipped description's name (`torchjfa.robots`), a
    simulated robot's name (``"head"``, ``"arm"``) or a path.

    Returns:
        ``(absolute path, "urdf" | "mjcf")``: ``.urdf`` files, and files whose root element is
        ``<robot>``, are URDF; the rest MJCF.

    Raises:
        DescriptionError: if there is no such file.
    """
    robot = os.fspath(robot)
    if robot in robots.available():
        path = robots.path(robot)
    elif robot in robots.SIMULATED:
        path = robots.simulated_path(robot)
    else:
        path = robot
        if not os.path.isfile(path):
            raise DescriptionError(
                f"no robot file {path!r} (give a .urdf or MJCF .xml path, or one of "
                f"{sorted(set(robots.available()) | set(robots.SIMULATED))})"
            )
    path = os.path.abspath(path)
    if path.lower().endswith(".urdf"):
        return path, "urdf"
    tag = None
    try:
        for _, element in ET.iterparse(path, events=("start",)):
            tag = element.tag
            break
    except ET.ParseError:
        pass  # MuJoCo's parser says what is wrong
    return path, "urdf" if tag == "robot" else "mjcf"


def _urdf_spec(path: str) -> tuple[mujoco.MjSpec, dict[str, float]]:
    """The URDF without its visual and collision geometry, parsed by MuJoCo; and each joint's
    ``<limit velocity>`` (rad/s or m/s) by name."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DescriptionError(f"{path!r} is not well-formed XML: {exc}") from None
    if root.tag != "robot":
        raise DescriptionError(f"{path!r} is not a URDF (its root element is <{root.tag}>)")
    try:  # names and links first: MuJoCo's importer drops a repeated joint's name
        check_urdf_elements(root, f"{path!r}")
    except ValueError as exc:
        raise DescriptionError(str(exc)) from None
    strip_urdf_for_mujoco(root, fusestatic="true")
    velocity = {}
    for joint in root.findall("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("velocity") not in (None, ""):
            try:
                velocity[joint.get("name", "")] = abs(float(limit.get("velocity")))
            except ValueError:
                raise DescriptionError(
                    f"{path!r}: joint {joint.get('name')!r} has a velocity limit that is not a "
                    f"number: {limit.get('velocity')!r}"
                ) from None
    spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    spec.modelfiledir = os.path.dirname(path)
    return spec, velocity


def _check_spec(spec: mujoco.MjSpec, path: str) -> None:
    """Refuse what the simulation cannot run: no joint, other than hinge and slide joints,
    unnamed joints, active equality constraints."""
    joints = list(spec.joints)
    if not joints:
        raise DescriptionError(f"{path!r} has no moving joint")
    other = [j.name or "(unnamed)" for j in joints if j.type not in _ONE_DOF]
    if other:
        raise DescriptionError(
            f"{path!r}: the simulation needs a fixed-base robot with hinge and slide joints "
            f"only; {other} are free or ball joints"
        )
    if any(not j.name for j in joints):
        raise DescriptionError(f"{path!r} has unnamed joints; name every joint")
    if any(e.active for e in spec.equalities):
        raise DescriptionError(
            f"{path!r} has equality constraints (a <mimic> joint, a coupling): the simulation "
            "needs independent joints (fix or remove the coupled ones)"
        )


def _with_motors(spec: mujoco.MjSpec) -> None:
    """Replace the actuators (and the sensors and keyframes, which may refer to them) by one
    gear-1 motor per joint without a control range, in joint order."""
    for kind in (spec.sensors, spec.actuators, spec.keys):
        for e in list(kind):
            spec.delete(e)
    for joint in spec.joints:
        motor = spec.add_actuator()
        motor.name = f"torchjfa_motor_{joint.name}"
        motor.target = joint.name
        motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
        motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE


def _compile(spec: mujoco.MjSpec, path: str) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as exc:  # MuJoCo raises ValueError for every compile error
        msg = " ".join(str(exc).split())
        hint = ""
        if "mass and inertia of moving bodies" in msg:
            hint = " (give every moving link an <inertial> with a positive mass and inertia)"
        raise DescriptionError(f"MuJoCo cannot compile {path!r}: {msg}{hint}") from None


def load_description(
    robot: str | os.PathLike,
    *,
    effects: Mapping[str, object] | None = None,
    own_effects: bool = False,
    name: str | None = None,
) -> Description:
    """Compile a robot description for simulation (what is kept and replaced: the module).

    Args:
        robot: a URDF or MJCF path, a shipped description's name (`torchjfa.robots.available`)
            or a simulated robot's name (its file, compiled as any other description).
        effects: joint effects to simulate, name from `torchjfa.sim.EFFECTS` -> a float (every
            joint) or an ``(n_dof,)`` sequence in `Description.joint_names` order (units as
            `torchjfa.sim.set_effects`); they replace the description's own or the default 0.
        own_effects: keep the joint effects the description writes (default: none, the pure
            rigid body; ``effects`` still override them).
        name: the robot's name in logs and messages (default: ``robot`` as given).

    Returns:
        A `Description`.

    Raises:
        DescriptionError: on a missing file, one MuJoCo cannot read or compile, or a robot
            the simulation cannot run (see the module); on bad ``effects``.
    """
    path, fmt = description_path(robot)
    velocity: dict[str, float] = {}
    try:
        if fmt == "urdf":
            spec, velocity = _urdf_spec(path)
        else:
            spec = mujoco.MjSpec.from_file(path)
    except DescriptionError:
        raise
    except Exception as exc:  # MuJoCo's parser: ValueError with its own message
        raise DescriptionError(
            f"MuJoCo cannot read {path!r} as {fmt.upper()}: {' '.join(str(exc).split())}"
        ) from None
    _check_spec(spec, path)
    _with_motors(spec)
    model = _compile(spec, path)
    check_hinge_robot(model)
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    model.body_gravcomp[:] = 0.0
    names = joint_names(model)
    frc = np.abs(np.asarray(model.jnt_actfrcrange, dtype=np.float64)).max(axis=1)
    effort = np.where(np.asarray(model.jnt_actfrclimited, dtype=bool) & (frc > 0), frc, np.inf)
    model.jnt_actfrclimited[:] = 0
    own = {k: np.array(v, dtype=np.float64) for k, v in _fields(model).items()}
    if not own_effects:
        set_effects(model, dict.fromkeys(EFFECTS, 0.0))
    if effects:
        try:
            set_effects(model, effects)
        except ValueError as exc:
            raise DescriptionError(f"{path!r}: {exc}") from None
    return Description(
        model=model,
        name=os.fspath(robot) if name is None else str(name),
        path=path,
        format=fmt,
        joint_names=names,
        effort_limit=effort,
        velocity_limit=np.array([velocity.get(n, np.inf) for n in names], dtype=np.float64),
        own_effects=own,
    )
