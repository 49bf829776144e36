"""Robots and MuJoCo oracles shared by the dynamics tests."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import torch

import torchjfa.robots

# A small URDF written for the tests: a branch at the base, continuous, revolute and prismatic
# joints, rotated joint origins, inertial frames with rpy and full inertias, a fixed joint with a
# massive child (lumped), and a massless tool frame.
SMALL_URDF = """<?xml version="1.0"?>
<robot name="small_tree">
  <link name="base">
    <inertial><origin xyz="0 0 0.05"/><mass value="2.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>
    </inertial>
  </link>
  <link name="a1">
    <inertial><origin xyz="0.1 0.02 -0.01" rpy="0.3 -0.2 0.5"/><mass value="1.5"/>
      <inertia ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.025" iyz="0.0015" izz="0.012"/>
    </inertial>
  </link>
  <link name="a2">
    <inertial><origin xyz="0.05 0 0.02" rpy="-0.4 0.1 0.9"/><mass value="0.8"/>
      <inertia ixx="0.004" ixy="-0.0005" ixz="0.0003" iyy="0.005" iyz="0.0002" izz="0.003"/>
    </inertial>
  </link>
  <link name="a2_tool">
    <inertial><origin xyz="0.02 0.01 0.03" rpy="0.2 0.3 -0.1"/><mass value="0.4"/>
      <inertia ixx="0.001" ixy="0.0001" ixz="0" iyy="0.0012" iyz="-0.0001" izz="0.0008"/>
    </inertial>
  </link>
  <link name="a2_tcp"/>
  <link name="b1">
    <inertial><origin xyz="0 0.08 0.01" rpy="0 0.6 0"/><mass value="1.1"/>
      <inertia ixx="0.009" ixy="0.0004" ixz="0.0001" iyy="0.006" iyz="-0.0003" izz="0.008"/>
    </inertial>
  </link>
  <link name="b2">
    <inertial><origin xyz="0.03 -0.01 0.06" rpy="0.7 0 -0.3"/><mass value="0.5"/>
      <inertia ixx="0.002" ixy="0.0001" ixz="0.0002" iyy="0.0018" iyz="0.0001" izz="0.001"/>
    </inertial>
  </link>
  <joint name="j_a1" type="continuous">
    <parent link="base"/><child link="a1"/>
    <origin xyz="0.1 0 0.2" rpy="0.1 0.2 0.3"/><axis xyz="0 0 1"/>
  </joint>
  <joint name="j_a2" type="prismatic">
    <parent link="a1"/><child link="a2"/>
    <origin xyz="0.3 0 0" rpy="0 1.5707963267948966 0"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-0.5" upper="0.5" effort="100" velocity="1"/>
  </joint>
  <joint name="j_a2_tool" type="fixed">
    <parent link="a2"/><child link="a2_tool"/>
    <origin xyz="0.1 0.05 0" rpy="0.5 0 0.2"/>
  </joint>
  <joint name="j_a2_tcp" type="fixed">
    <parent link="a2_tool"/><child link="a2_tcp"/>
    <origin xyz="0 0 0.1"/>
  </joint>
  <joint name="j_b1" type="revolute">
    <parent link="base"/><child link="b1"/>
    <origin xyz="-0.1 0 0.2" rpy="-0.3 0 0"/><axis xyz="1 1 0"/>
    <limit lower="-2" upper="2" effort="100" velocity="1"/>
    <dynamics damping="0.5" friction="0.2"/>
  </joint>
  <joint name="j_b2" type="revolute">
    <parent link="b1"/><child link="b2"/>
    <origin xyz="0 0.25 0" rpy="0 0 -0.7"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="100" velocity="1"/>
  </joint>
</robot>
"""

_MJ_URDF_OPTIONS = '<mujoco><compiler discardvisual="true" fusestatic="false"/></mujoco>'


def urdf_for_mujoco(text: str) -> str:
    """The URDF with MuJoCo's compiler options: keep every link as its own body."""
    start = text.index("<robot")
    end = text.index(">", start) + 1
    return text[:end] + _MJ_URDF_OPTIONS + text[end:]


def mujoco_model(kind: str, source: str, gravity=None) -> mujoco.MjModel:
    """A MuJoCo model with armature, damping, friction loss, springs and constraints off."""
    if kind == "urdf":
        text = source if source.lstrip().startswith("<") else Path(source).read_text()
        m = mujoco.MjModel.from_xml_string(urdf_for_mujoco(text))
    else:
        m = mujoco.MjModel.from_xml_path(source)
    m.dof_damping[:] = 0.0
    m.dof_armature[:] = 0.0
    m.dof_frictionloss[:] = 0.0
    m.jnt_stiffness[:] = 0.0
    off = mujoco.mjtDisableBit
    m.opt.disableflags |= int(
        off.mjDSBL_CONSTRAINT | off.mjDSBL_SPRING | off.mjDSBL_DAMPER | off.mjDSBL_FRICTIONLOSS
    )
    if gravity is not None:
        m.opt.gravity[:] = gravity
    return m


def mujoco_inverse(m: mujoco.MjModel, q, qd, qdd) -> np.ndarray:
    """``mj_inverse`` sample by sample; inputs ``(N, nv)`` float64 arrays."""
    d = mujoco.MjData(m)
    out = np.zeros_like(q)
    for i in range(q.shape[0]):
        d.qpos[:] = q[i]
        d.qvel[:] = qd[i]
        d.qacc[:] = qdd[i]
        mujoco.mj_inverse(m, d)
        out[i] = d.qfrc_inverse
    return out


def mujoco_mass_matrix(m: mujoco.MjModel, q) -> np.ndarray:
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    return M


ROBOTS = {
    "panda": ("urdf", torchjfa.robots.path("panda")),
    "branched_tree": ("mjcf", torchjfa.robots.path("branched_tree")),
    "small_urdf": ("urdf", SMALL_URDF),
}


def random_state(n: int, batch: tuple[int, ...], seed: int, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return tuple(torch.randn(*batch, n, generator=g, dtype=dtype) for _ in range(3))
