"""`RigidBodyModel.forward_kinematics` against MuJoCo (every shipped MJCF) and Pinocchio (URDF).

Tolerances: each pose is a product of at most a dozen 3x3 rotations and offsets, each entry a
sum of three float64 products, and MuJoCo and Pinocchio compose the same placements in another
order (MuJoCo through quaternions): the results differ by at most a few hundred units of
round-off (2.2e-16), about 1e-13 (measured: 3e-15). Rotations are compared to 1e-12 and
positions to 1e-12 of the robot's size (the sum of its fixed offsets, m). pytorch-kinematics'
own forward kinematics misses by 4 cm on branched_tree, 10 cm on `TEST_MJCF` and 0.65 m on
`NO_AXIS_URDF`.
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from dyn_robots import SMALL_URDF

import torchjfa
from torchjfa.dynamics import RigidBodyModel
from torchjfa.excitation import (
    FourierTrajectory,
    WorkspaceBox,
    check_limits,
    constraint_violations,
    limits_from_model,
)

_PACKAGE = Path(torchjfa.__file__).resolve().parent
#: every MJCF and URDF shipped in the package (robots/, sim/models/, ...)
SHIPPED_MJCF = sorted(str(p) for p in _PACKAGE.rglob("*.xml") if "<mujoco" in p.read_text())
SHIPPED_URDF = sorted(str(p) for p in _PACKAGE.rglob("*.urdf"))
ROTATION_TOL = 1e-12
RELATIVE_TOL = 1e-12

# slide joints with moving children, hinges placed away from the body origin, bodies and sites
# fixed to moving bodies, to lumped bodies and to the world, rotations in several notations
TEST_MJCF = """<mujoco model="kinematics">
  <compiler angle="radian"/>
  <worldbody>
    <site name="world_site" pos="0.3 0.1 0" euler="0.1 0.2 0.3"/>
    <body name="stand" pos="0 0 0.1" euler="0 0 0.5">
      <geom size="0.05"/>
      <body name="carriage" pos="0.1 0 0.3" euler="0.2 0 0.4">
        <joint name="rail" type="slide" axis="1 0.3 0" pos="0.05 0 0"/>
        <geom size="0.05"/>
        <body name="arm" pos="0.2 0 0.1" quat="0.9238795 0 0.3826834 0">
          <joint name="pivot" type="hinge" axis="0 0.6 0.8" pos="0.02 0.01 0"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
          <body name="bracket" pos="0.3 0 0" axisangle="0 0 1 0.7">
            <geom size="0.02"/>
            <site name="tool" pos="0.01 0.02 0.03" quat="0.7071068 0.7071068 0 0"/>
            <body name="tip" pos="0 0.1 0">
              <joint name="wrist" type="hinge" axis="1 0 0" pos="0 0 0.02"/>
              <geom size="0.02"/>
              <body name="slider" pos="0.05 0 0" euler="0.1 0.2 0.3">
                <joint name="extend" type="slide" axis="0 0 1"/>
                <geom size="0.01"/>
                <body name="finger" pos="0 0 0.04">
                  <joint name="flex" type="hinge" axis="0.3 -0.2 1" pos="0.01 -0.02 0.03"/>
                  <geom size="0.01"/>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

# a URDF joint without <axis> turns about (1, 0, 0), the URDF default
NO_AXIS_URDF = """<?xml version="1.0"?>
<robot name="no_axis">
  <link name="base"/>
  <link name="l1"><inertial><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <link name="flange"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.2" rpy="0.3 0.2 0.1"/>
    <limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0.3 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
  <joint name="to_flange" type="fixed"><parent link="l2"/><child link="flange"/>
    <origin xyz="0.25 0 0" rpy="0 1.5707963267948966 0"/></joint>
</robot>
"""


def _size(model: RigidBodyModel) -> float:
    """The sum of the fixed offsets of the tree, m: a bound on any frame's distance."""
    tree = model._tree
    return float(
        np.linalg.norm(tree.pos_fixed, axis=1).sum()
        + np.linalg.norm(tree.axis_point, axis=1).sum()
        + np.linalg.norm(tree.frame_pos, axis=1).sum()
    )


def _random_q(model: RigidBodyModel, n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return 2.0 * torch.randn(n, model.n_dof, generator=g, dtype=torch.float64)


def _assert_poses(T: np.ndarray, R_ref: np.ndarray, p_ref: np.ndarray, size: float) -> None:
    np.testing.assert_allclose(T[..., :3, :3], R_ref, rtol=0, atol=ROTATION_TOL)
    np.testing.assert_allclose(T[..., :3, 3], p_ref, rtol=0, atol=RELATIVE_TOL * size)
    np.testing.assert_array_equal(
        T[..., 3, :], np.broadcast_to([0.0, 0.0, 0.0, 1.0], T[..., 3, :].shape)
    )


# ----------------------------------------------------------------------------- MuJoCo
def _mujoco_poses(m: mujoco.MjModel, model: RigidBodyModel, q: np.ndarray):
    """MuJoCo's poses of `model.frame_names` (bodies and sites) at each row of q."""
    d = mujoco.MjData(m)
    adr = [int(m.jnt_qposadr[m.joint(j).id]) for j in model.joint_names]
    R = np.zeros((len(q), len(model.frame_names), 3, 3))
    p = np.zeros((len(q), len(model.frame_names), 3))
    for i, row in enumerate(q):
        d.qpos[adr] = row
        mujoco.mj_kinematics(m, d)
        for f, name in enumerate(model.frame_names):
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
            if body >= 0:
                R[i, f], p[i, f] = d.xmat[body].reshape(3, 3), d.xpos[body]
            else:
                site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
                R[i, f], p[i, f] = d.site_xmat[site].reshape(3, 3), d.site_xpos[site]
    return R, p


def test_every_shipped_mjcf_is_found():
    names = {Path(p).name for p in SHIPPED_MJCF}
    assert {"branched_tree.xml", "sarcos_head.xml", "sarcos_arm.xml"} <= names


@pytest.mark.parametrize(
    "source", [*SHIPPED_MJCF, TEST_MJCF], ids=[*(Path(p).stem for p in SHIPPED_MJCF), "test"]
)
def test_mjcf_frames_equal_mujoco(source):
    model = RigidBodyModel.from_mjcf(source)
    m = (
        mujoco.MjModel.from_xml_string(source)
        if source.lstrip().startswith("<")
        else mujoco.MjModel.from_xml_path(source)
    )
    # every body and every named site is a frame
    sites = [m.site(s).name for s in range(m.nsite) if m.site(s).name]
    assert set(model.frame_names) == {m.body(b).name for b in range(m.nbody)} | set(sites)
    q = _random_q(model, 12, seed=3)
    T = model.forward_kinematics(q, model.frame_names).numpy()
    R, p = _mujoco_poses(m, model, q.numpy())
    _assert_poses(T, R, p, _size(model))


def test_joint_pos_of_branched_tree_is_honoured():
    """The left arm's joints sit away from their body origins (MJCF joint ``pos``): turning the
    shoulder moves the upper arm's origin, as MuJoCo says (pytorch-kinematics' chain does not)."""
    model = RigidBodyModel.from_mjcf(torchjfa.robots.path("branched_tree"))
    q = torch.zeros(model.n_dof, dtype=torch.float64)
    q[model.joint_names.index("left_shoulder")] = 1.0
    moved = model.forward_kinematics(q, "left_upper")[:3, 3]
    rest = model.forward_kinematics(torch.zeros_like(q), "left_upper")[:3, 3]
    assert float((moved - rest).norm()) > 0.01


# ----------------------------------------------------------------------------- Pinocchio
def _pinocchio_poses(pin, pm, model: RigidBodyModel, q: np.ndarray, frames):
    pd = pm.createData()
    joints = [pm.joints[pm.getJointId(n)] for n in model.joint_names]
    ids = [pm.getFrameId(f, pin.FrameType.BODY) for f in frames]
    assert all(i < len(pm.frames) for i in ids), "Pinocchio lacks a frame"
    R = np.zeros((len(q), len(frames), 3, 3))
    p = np.zeros((len(q), len(frames), 3))
    for i, row in enumerate(q):
        qp = pin.neutral(pm)
        for k, j in enumerate(joints):
            if j.nq == 2:  # a continuous joint: (cos q, sin q)
                qp[j.idx_q : j.idx_q + 2] = np.cos(row[k]), np.sin(row[k])
            else:
                qp[j.idx_q] = row[k]
        pin.framesForwardKinematics(pm, pd, qp)
        for f, fid in enumerate(ids):
            R[i, f], p[i, f] = pd.oMf[fid].rotation, pd.oMf[fid].translation
    return R, p


def _check_against_pinocchio(path_or_text: str, locked: tuple[str, ...] = ()) -> None:
    pin = pytest.importorskip("pinocchio")
    if path_or_text.lstrip().startswith("<"):
        pm = pin.buildModelFromXML(path_or_text)
    else:
        pm = pin.buildModelFromUrdf(path_or_text)
    if locked:
        ids = [pm.getJointId(n) for n in locked]
        pm = pin.buildReducedModel(pm, ids, pin.neutral(pm))
    model = RigidBodyModel.from_urdf(path_or_text, fixed_joints=locked)
    q = _random_q(model, 8, seed=11)
    T = model.forward_kinematics(q, model.frame_names).numpy()
    R, p = _pinocchio_poses(pin, pm, model, q.numpy(), model.frame_names)
    _assert_poses(T, R, p, _size(model))


def test_every_shipped_urdf_is_found():
    assert {"panda.urdf", "panda_arm.urdf"} <= {Path(p).name for p in SHIPPED_URDF}


@pytest.mark.parametrize("path", SHIPPED_URDF, ids=[Path(p).stem for p in SHIPPED_URDF])
def test_shipped_urdf_frames_equal_pinocchio(path):
    _check_against_pinocchio(path)


@pytest.mark.parametrize("text", [SMALL_URDF, NO_AXIS_URDF], ids=["small", "no_axis"])
def test_urdf_frames_equal_pinocchio(text):
    """Prismatic and continuous joints, fixed joints chained, a joint without <axis>."""
    _check_against_pinocchio(text)


# (file, joints held fixed): the arms of the example-robot-data tests of the regressor
ERD_ROBOTS = {
    "panda": (
        "panda_description/urdf/panda.urdf",
        ("panda_finger_joint1", "panda_finger_joint2"),
    ),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", ()),
    "talos_left_arm": ("talos_data/robots/talos_left_arm.urdf", ()),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", ()),
    "so101": ("so_arm_description/urdf/so101.urdf", ()),
}


@pytest.mark.parametrize("name", list(ERD_ROBOTS))
def test_example_robot_data_frames_equal_pinocchio(name):
    relative, locked = ERD_ROBOTS[name]
    try:
        importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    try:
        path = torchjfa.robots.example_robot_data_path(relative)
    except FileNotFoundError:
        pytest.skip(f"this example-robot-data has no {relative}")
    _check_against_pinocchio(path, locked)


# ----------------------------------------------------------------------------- the API
def test_lumped_frames_keep_their_offset():
    """A URDF flange and tool frame fixed to the last link: lumped, and still placed."""
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda"))
    assert "panda_hand_tcp" in model.lumped_bodies["panda_joint7"]
    q = _random_q(model, 5, seed=2)
    link8, hand, tcp = model.forward_kinematics(
        q, ["panda_link8", "panda_hand", "panda_hand_tcp"]
    ).unbind(-3)
    # panda_hand is panda_link8 turned by -pi/4 about z; the tcp 0.1034 m along the hand's z
    torch.testing.assert_close(link8[..., :3, 3], hand[..., :3, 3], rtol=0, atol=1e-15)
    torch.testing.assert_close(
        tcp[..., :3, 3], hand[..., :3, 3] + 0.1034 * hand[..., :3, 2], rtol=0, atol=1e-15
    )
    # the root link never moves
    torch.testing.assert_close(
        model.forward_kinematics(q, "panda_link0"),
        torch.eye(4, dtype=torch.float64).expand(5, 4, 4),
        rtol=0,
        atol=0,
    )


def test_batch_shapes_dtype_and_default_frames():
    model = RigidBodyModel.from_mjcf(torchjfa.robots.path("branched_tree"))
    q = _random_q(model, 24, seed=4).reshape(2, 3, 4, model.n_dof)
    T = model.forward_kinematics(q)
    assert T.shape == (2, 3, 4, model.n_dof, 4, 4) and T.dtype == torch.float64
    flat = model.forward_kinematics(q.reshape(-1, model.n_dof), model.body_names)
    torch.testing.assert_close(T.reshape(flat.shape), flat, rtol=0, atol=0)
    one = model.forward_kinematics(q[1, 2, 3], ["right_tool", "world"])
    assert one.shape == (2, 4, 4)
    torch.testing.assert_close(one[0], model.forward_kinematics(q, "right_tool")[1, 2, 3])
    # a list of numbers is read as float64; float32 stays float32
    assert model.forward_kinematics(q[0, 0, 0].tolist(), "torso").dtype == torch.float64
    T32 = model.forward_kinematics(q.float())
    assert T32.dtype == torch.float32
    torch.testing.assert_close(T32.double(), T, rtol=0, atol=1e-5)


def test_bad_input_raises():
    model = RigidBodyModel.from_mjcf(torchjfa.robots.path("branched_tree"))
    with pytest.raises(ValueError, match=r"shape \(\*batch, 5\)"):
        model.forward_kinematics(torch.zeros(3, 4))
    with pytest.raises(ValueError, match="no frame named \\['hand'\\]"):
        model.forward_kinematics(torch.zeros(5), ["torso", "hand"])
    with pytest.raises(ValueError, match="NaN"):
        model.forward_kinematics(torch.full((5,), float("nan")))
    with pytest.raises(ValueError, match="empty"):
        model.forward_kinematics(torch.zeros(5), [])


def test_gradient_matches_finite_differences():
    model = RigidBodyModel.from_mjcf(TEST_MJCF)
    frames = ["tool", "finger", "slider"]
    q = _random_q(model, 3, seed=5).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: model.forward_kinematics(x, frames), (q,))
    urdf = RigidBodyModel.from_urdf(SMALL_URDF)
    q = _random_q(urdf, 2, seed=6).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: urdf.forward_kinematics(x, "a2_tcp"), (q,))


# ----------------------------------------------------------------------------- workspace
def test_workspace_limit_uses_mujocos_positions():
    """The workspace penalty of branched_tree's left arm (joints with ``pos``) is computed from
    the positions MuJoCo gives its bodies."""
    path = torchjfa.robots.path("branched_tree")
    model = RigidBodyModel.from_mjcf(path)
    boxes = [
        WorkspaceBox("left_lower", (-0.3, 0.0, 0.4), (0.3, 0.6, 1.2)),
        WorkspaceBox("right_tool", (-0.5, -0.6, 0.3), (0.5, 0.0, 1.0)),
    ]
    limits = limits_from_model(model, workspace=boxes)
    q = _random_q(model, 16, seed=7)
    zeros = torch.zeros_like(q)
    got = constraint_violations(model, limits, q, zeros, zeros, kinds=("workspace",))["workspace"]
    m = mujoco.MjModel.from_xml_path(path)
    _, p = _mujoco_poses(m, model, q.numpy())
    p = p[:, [model.frame_names.index(b.frame) for b in boxes]]
    low, high = np.array([b.low for b in boxes]), np.array([b.high for b in boxes])
    size = high - low
    # every box above its high corner (x, y, z), then below its low one
    expected = np.concatenate([(p - high) / size, (low - p) / size], 1).reshape(len(q), -1)
    np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=1e-12)
    assert (got > 0).any() and (got < 0).any()  # some samples outside a box, some inside
    with pytest.raises(ValueError, match="no frame 'hand'"):
        limits_from_model(model, workspace=[WorkspaceBox("hand", (0, 0, 0), (1, 1, 1))])


def test_check_limits_names_the_box_and_side_violated():
    """With two boxes, the first frame below its box on z is reported as such (not as the
    second frame above its box)."""
    model = RigidBodyModel.from_mjcf(torchjfa.robots.path("branched_tree"))
    q0 = np.zeros(model.n_dof)
    tool = model.forward_kinematics(torch.as_tensor(q0), "right_tool")[:3, 3].numpy()
    boxes = [
        WorkspaceBox("right_tool", tuple(tool - [1.0, 1.0, -0.1]), tuple(tool + 1.0)),
        WorkspaceBox("left_lower", (-2.0, -2.0, -2.0), (2.0, 2.0, 2.0)),
    ]
    limits = limits_from_model(model, workspace=boxes)
    zeros = np.zeros((model.n_dof, 2))
    rest = FourierTrajectory(0.5, q0, zeros, zeros, model.joint_names)  # at rest at q0
    with pytest.raises(ValueError, match="1 limit") as err:
        check_limits(model, rest, limits, rate=10.0)
    assert "right_tool: origin below its workspace box on axis z" in str(err.value)
