"""The joint terms a description states beside its inertials: a URDF's ``<dynamics damping
friction>``, an MJCF joint's ``damping``, ``frictionloss`` and ``armature`` (its defaults
classes applied, as MuJoCo compiles them). `RigidBodyModel.description_theta` puts them into
the model's joint terms, so that the description is judged with everything it states."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

__all__ = ["described_terms"]

#: a model's joint term -> the description's quantity (per joint; N m s/rad, N m, kg m^2)
TERMS = {"viscous": "damping", "coulomb": "friction", "armature": "armature"}


def _urdf(text: str, joints) -> dict[str, np.ndarray]:
    root = ET.fromstring(text)
    out = {k: np.zeros(len(joints)) for k in ("damping", "friction", "armature")}
    index = {name: k for k, name in enumerate(joints)}
    for joint in root.iter("joint"):
        k = index.get(joint.get("name"))
        dyn = joint.find("dynamics")
        if k is None or dyn is None:
            continue
        for key in ("damping", "friction"):
            try:
                out[key][k] = float(dyn.get(key, 0.0))
            except ValueError:
                out[key][k] = 0.0
    return out


def _mjcf(text: str, path: str | None, joints) -> dict[str, np.ndarray]:
    import mujoco

    try:
        mj = mujoco.MjModel.from_xml_path(path) if path else mujoco.MjModel.from_xml_string(text)
    except ValueError:  # the joints' text alone (a floating base's): compile it
        mj = mujoco.MjModel.from_xml_string(text)
    dof = [int(mj.jnt_dofadr[mj.joint(name).id]) for name in joints]
    return {
        "damping": np.array(mj.dof_damping[dof], dtype=np.float64),
        "friction": np.array(mj.dof_frictionloss[dof], dtype=np.float64),
        "armature": np.array(mj.dof_armature[dof], dtype=np.float64),
    }


def described_terms(model) -> dict[str, np.ndarray]:
    """The description's damping, dry friction and armature per joint, ``(n_dof,)`` each in
    the model's joint order (0 where none is stated; a URDF states no armature).

    Args:
        model: a `RigidBodyModel`.
    """
    joints = model.joint_names
    if model.source_format == "urdf":
        return _urdf(model.source_xml, joints)
    path = model.source_path
    same = False
    if path:
        try:
            with open(path, encoding="utf-8") as fh:
                same = fh.read() == model.source_xml
        except OSError:
            same = False
    return _mjcf(model.source_xml, path if same else None, joints)
