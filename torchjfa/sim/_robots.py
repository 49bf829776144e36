"""The simulated Sarcos-like robots shipped with torchjfa, with switchable unmodeled effects.

Two MJCF models live in ``torchjfa/sim/models/``:

* ``"head"`` (``sarcos_head.xml``): a 7-DoF oculomotor head, neck pan/tilt/roll then a pan/tilt
  pair per eye on its own branch (77 rigid-body parameters with viscous friction), as the paper's
  Sarcos vision head.
* ``"arm"`` (``sarcos_arm.xml``): a 10-DoF anthropomorphic arm, 3 shoulder, 1 elbow, 3 wrist
  and 3 finger joints (the fingers branch off the hand; 110 parameters), as the paper's Sarcos arm.

Both are fixed-base trees of hinge joints with one motor per joint (``ctrl`` is the joint
torque in N m). Their masses and inertias are made up but plausible; they are not the real
robots' values. Besides the rigid-body dynamics, every joint has four effects whose TRUE values
are written in the files (and returned by `robot_effects`):

==============  ======================  =============================  ===========
effect          MuJoCo field            model                          rigid-body
==============  ======================  =============================  ===========
``damping``     ``dof_damping``         ``-b qd`` (viscous), N m s/rad  modelled (fv)
``armature``    ``dof_armature``        ``+a qdd`` rotor inertia, kg m^2 unmodeled
``frictionloss`` ``dof_frictionloss``   ``-f sign(qd)`` (dry), N m      unmodeled
``stiffness``   ``jnt_stiffness``       ``-k q`` (cable, springref 0)   unmodeled
==============  ======================  =============================  ===========

True values as damping/armature/frictionloss/stiffness (N m s/rad, kg m^2, N m, N m/rad),
joint by joint in file order. They are set from the joint-space inertia ``M_jj`` and the RMS
rigid-body torque of the default excitation: damping ~ 3 M_jj (1/s, mechanical time constants
of about 0.3 s), armature ~ 0.2 M_jj, frictionloss ~ 5 % and stiffness x 0.5 rad ~ 5 % of the
RMS torque.

* head: neck_pan 0.15/0.01/0.02/0.04, neck_tilt 0.55/0.035/0.15/0.3,
  neck_roll 0.16/0.011/0.04/0.08, left_eye_pan 0.0012/8e-5/0.0009/0.0017,
  left_eye_tilt 0.0005/3.5e-5/0.0017/0.0035, right_eye_pan 0.0014/9e-5/0.0009/0.0018,
  right_eye_tilt 0.0006/4e-5/0.0019/0.0038.
* arm: shoulder_fe 3.5/0.23/0.7/1.5, shoulder_aa 3/0.2/0.65/1.3, humeral_rot 0.6/0.04/0.25/0.5,
  elbow 0.7/0.05/0.35/0.7, wrist_ps 0.004/2.8e-4/0.015/0.03, wrist_fe 0.03/0.002/0.04/0.085,
  wrist_aa 0.02/0.0013/0.03/0.065, thumb 1.2e-4/8e-6/6e-4/0.0012,
  index 2.6e-4/1.8e-5/0.0012/0.0024, fingers 3.8e-4/2.5e-5/0.002/0.004.

Viscous damping is part of the rigid-body parameter set (the paper's 11th parameter per joint),
so it stays on by default; armature, frictionloss and stiffness are what the identified model
cannot represent. In MuJoCo's inverse dynamics the torque of a joint moving at a speed that
saturates the dry-friction constraint is ``Y theta + a qdd + k q + f sign(qd)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import mujoco
import numpy as np
import torch

from ..robots import SIMULATED, simulated_path

__all__ = [
    "ROBOTS",
    "EFFECTS",
    "UNMODELED",
    "model_path",
    "load_robot",
    "set_effects",
    "robot_effects",
    "true_parameters",
]

ROBOTS = SIMULATED
EFFECTS = ("damping", "armature", "frictionloss", "stiffness")
UNMODELED = ("armature", "frictionloss", "stiffness")


def model_path(robot: str) -> Path:
    """The absolute path of a shipped MJCF model.

    Args:
        robot: ``"head"`` or ``"arm"``.

    Raises:
        ValueError: on an unknown robot name.
    """
    if robot not in ROBOTS:
        raise ValueError(f"unknown robot {robot!r}; choose from {tuple(ROBOTS)}")
    return Path(simulated_path(robot))


def _fields(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Views of the per-joint arrays of each effect (hinge joints: dof index = joint index)."""
    return {
        "damping": model.dof_damping,
        "armature": model.dof_armature,
        "frictionloss": model.dof_frictionloss,
        "stiffness": model.jnt_stiffness,
    }


def robot_effects(robot: str) -> dict[str, np.ndarray]:
    """The true per-joint values of the four joint effects written in the model file.

    Returns:
        ``{"damping", "armature", "frictionloss", "stiffness"}`` -> ``(n_dof,)`` float64 arrays
        in MuJoCo joint order (units in the module docstring).
    """
    model = mujoco.MjModel.from_xml_path(str(model_path(robot)))
    return {k: np.array(v, dtype=np.float64) for k, v in _fields(model).items()}


def load_robot(robot: str, *, unmodeled: bool | Mapping[str, object] = True) -> mujoco.MjModel:
    """Compile a shipped robot with the chosen joint effects.

    Args:
        robot: ``"head"`` or ``"arm"``.
        unmodeled: True keeps every effect at its true value; False turns armature,
            frictionloss and stiffness off (viscous damping stays: it is in the rigid-body
            parameter set); a mapping sets effects one by one, keys from ``EFFECTS``, values
            True (the true value), False (off), a float (every joint) or an ``(n_dof,)``
            sequence. Unmodeled effects missing from the mapping are off, missing
            ``damping`` keeps its true value. ``{"damping": 0}`` with False-like others gives
            the pure rigid-body robot.

    Returns:
        A ``mujoco.MjModel`` (contacts disabled, one torque motor per joint).

    Raises:
        ValueError: on an unknown robot, effect name, wrong length or negative value.
        TypeError: if ``unmodeled`` is neither a bool nor a mapping.
    """
    model = mujoco.MjModel.from_xml_path(str(model_path(robot)))
    fields = _fields(model)
    if isinstance(unmodeled, bool):
        if not unmodeled:
            for k in UNMODELED:
                fields[k][:] = 0.0
        return model
    if not isinstance(unmodeled, Mapping):
        raise TypeError(
            f"unmodeled must be True, False or a mapping of effects, got {type(unmodeled)}"
        )
    unknown = [k for k in unmodeled if k not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effects {unknown}; choose from {EFFECTS}")
    settings: dict[str, object] = {}
    for k in EFFECTS:
        value = unmodeled.get(k, k == "damping")
        if isinstance(value, (bool, np.bool_)):
            if not value:
                settings[k] = 0.0
            continue
        settings[k] = value
    set_effects(model, settings)
    return model


def set_effects(model: mujoco.MjModel, effects: Mapping[str, object]) -> None:
    """Set joint effects of a compiled model in place (the other effects stay as they are).

    Args:
        model: a robot whose joints are all hinges or slides (dof index = joint index).
        effects: name from ``EFFECTS`` -> a float (every joint) or an ``(n_dof,)`` sequence in
            MuJoCo joint order; units N m s/rad (damping), kg m^2 (armature), N m
            (frictionloss), N m/rad (stiffness), with N and m in place of N m and rad for a
            slide joint.

    Raises:
        ValueError: on an unknown effect, a wrong length, a negative or non-finite value.
    """
    unknown = [k for k in effects if k not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effects {unknown}; choose from {EFFECTS}")
    n = model.njnt
    values = {}
    for k, value in effects.items():  # every value checked before any is set
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim == 0:
            arr = np.full(n, float(arr))
        if arr.shape != (n,):
            raise ValueError(f"{k} must be a float or have shape ({n},), got shape {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ValueError(f"{k} must be finite and non-negative, got {arr.tolist()}")
        values[k] = arr
    fields = _fields(model)
    for k, arr in values.items():
        fields[k][:] = arr


def joint_ranges(model: mujoco.MjModel) -> np.ndarray:
    """``(n_dof, 2)`` joint ranges, rad (unlimited joints get ``(-pi, pi)``)."""
    rng = np.array(model.jnt_range, dtype=np.float64)
    unlimited = ~np.asarray(model.jnt_limited, dtype=bool)
    rng[unlimited] = (-np.pi, np.pi)
    return rng


def joint_names(model: mujoco.MjModel) -> tuple[str, ...]:
    """The joints' names in MuJoCo order."""
    return tuple(model.joint(i).name for i in range(model.njnt))


def check_hinge_robot(model: mujoco.MjModel) -> None:
    """Raise ``ValueError`` unless every joint is a hinge or a slide (a fixed-base robot whose
    dof index is its joint index) and every joint has a gear-1 motor."""
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"expected a mujoco.MjModel, got {type(model)}")
    one_dof = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    if model.njnt == 0 or not np.all(np.isin(model.jnt_type, one_dof)):
        raise ValueError("the simulation needs a fixed-base robot with hinge and slide joints only")
    if model.nu != model.njnt or not np.array_equal(
        np.asarray(model.actuator_trnid[:, 0]), np.arange(model.njnt)
    ):
        raise ValueError("the simulation needs one motor per joint, in joint order")
    if np.any(model.actuator_gear[:, 0] != 1.0) or np.any(model.actuator_ctrllimited):
        raise ValueError("the motors must have gear 1 and no ctrlrange (ctrl = joint torque)")


def true_parameters(robot: str, model, *, armature: bool = False) -> torch.Tensor:
    """The true parameters of a shipped robot with ``unmodeled=False`` (rigid body and viscous
    damping: what `generate_log(..., unmodeled=False)` simulates), in ``model``'s layout.

    Args:
        robot: ``"head"`` or ``"arm"``.
        model: a `torchjfa.dynamics.RigidBodyModel` of that robot's file (e.g.
            ``RigidBodyModel.from_mjcf(model_path(robot), friction=("viscous",))``): its
            ``nominal_theta`` holds the file's inertials; the damping goes to its ``fv`` terms.
        armature: also the file's armature in the model's ``ia`` terms (where it has them):
            the truth of a robot simulated with its armature on (MuJoCo adds ``armature qdd``
            to each joint's torque exactly as the ``ia`` term does).

    Returns:
        ``(n_params,)`` float64: the file's inertials, the damping as viscous friction (and the
        armature), 0 for any other joint term.

    Raises:
        ValueError: when ``model`` has other joints than the robot or no viscous friction term.
    """
    if "viscous" not in tuple(model.friction):
        raise ValueError("the model has no viscous friction term for the robot's damping")
    names = joint_names(load_robot(robot, unmodeled=False))
    if sorted(names) != sorted(model.joint_names):
        raise ValueError(f"the model's joints {model.joint_names} are not {robot}'s {names}")
    theta = model.nominal_theta.clone()
    effects = robot_effects(robot)
    terms = {"fv": effects["damping"]}
    if armature and "armature" in tuple(model.friction):
        terms["ia"] = effects["armature"]
    for short, values in terms.items():
        for name, value in zip(names, values, strict=True):
            theta[model.layout.index(name, short)] = float(value)
    return theta
