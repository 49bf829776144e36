"""The joint terms a description states beside its inertials: a URDF's ``<dynamics damping
friction>``, an MJCF joint's ``damping``, ``frictionloss`` and ``armature`` (its defaults
classes applied, as MuJoCo compiles them). `RigidBodyModel.description_theta` puts them into
the model's joint terms, so that the description is judged with everything it states."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import torch

from ._mjcf import mjcf_joint_terms

__all__ = ["described_terms", "description_theta"]

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
    return mjcf_joint_terms(model.source_xml, path if same else None, joints)


def description_theta(model) -> torch.Tensor:
    """``(n_params,)`` float64: the description with everything it states: its inertials and,
    in the model's joint terms, its damping (``viscous``), dry friction (``coulomb``) and
    armature (``armature``). With a transmission the joint terms act per motor and stay 0."""
    inertial = torch.as_tensor(model._tree.inertial, dtype=torch.float64)
    if model.transmission is not None or not model.friction:
        return model.layout.join(inertial)
    stated = described_terms(model)
    terms = torch.zeros(model.n_dof, len(model.friction), dtype=torch.float64)
    for k, kind in enumerate(model.friction):
        if kind in TERMS:
            terms[:, k] = torch.as_tensor(stated[TERMS[kind]], dtype=torch.float64)
    return model.layout.join(inertial, terms)
