"""Robot descriptions that load, or fail with a message naming what is wrong.

URDFs as public repositories write them (an encoding declaration first, ``<transmission>`` and
``<ros2_control>`` tags, mimic grippers) and the malformed ones users meet (two trees, loops,
fixed joints only, undefined links); the standard arms of ``example-robot-data`` against
Pinocchio's RNEA.
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np
import pytest
import torch
from _robots import erd_path
from dyn_robots import SMALL_URDF, random_state

import torchjfa.robots
from torchjfa import cli
from torchjfa.dynamics import RigidBodyModel

DECLARATION = '<?xml version="1.0" encoding="utf-8"?>\n'
BODY = SMALL_URDF[SMALL_URDF.index("<robot") :]  # SMALL_URDF without its XML declaration


def _link(name: str) -> str:
    return (
        f'<link name="{name}"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>'
        '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.3"/></inertial></link>'
    )


def _joint(name: str, parent: str, child: str, kind: str = "revolute", extra: str = "") -> str:
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="0 0 0.2" rpy="0.1 0 0"/><axis xyz="0 1 0"/>{extra}</joint>'
    )


def _urdf(links: str, joints: list[str]) -> str:
    return '<robot name="r">' + "".join(_link(n) for n in links) + "".join(joints) + "</robot>"


def _same_model(a: RigidBodyModel, b: RigidBodyModel) -> None:
    assert a.joint_names == b.joint_names and a.parents == b.parents
    torch.testing.assert_close(a.nominal_theta, b.nominal_theta, rtol=0, atol=0)
    q, qd, qdd = random_state(a.n_dof, (4,), seed=3)
    torch.testing.assert_close(a.regressor(q, qd, qdd), b.regressor(q, qd, qdd), rtol=0, atol=0)


# ----------------------------------------------------------------------------- XML declaration
def test_encoding_declaration_loads_from_a_file_a_string_and_bytes(tmp_path):
    reference = RigidBodyModel.from_urdf(BODY)
    text = DECLARATION + BODY
    path = tmp_path / "declared.urdf"
    path.write_text(text, encoding="utf-8")
    for source in (text, text.encode("utf-8"), str(path), path, str(path).encode()):
        _same_model(RigidBodyModel.from_urdf(source), reference)
    # the command line loads it too
    _same_model(cli.load_model(str(path), ("viscous",)), reference)
    # a byte-order mark in front of the declaration
    bom = tmp_path / "bom.urdf"
    bom.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    _same_model(RigidBodyModel.from_urdf(str(bom)), reference)


def test_bytes_are_decoded_as_their_declaration_says(tmp_path):
    # a joint name that is not ASCII, in a Latin-1 file: read as UTF-8 it would not decode
    text = '<?xml version="1.0" encoding="ISO-8859-1"?>\n' + BODY.replace("j_b2", "j_épaule")
    path = tmp_path / "latin1.urdf"
    path.write_bytes(text.encode("latin-1"))
    for source in (str(path), text.encode("latin-1"), text):
        model = RigidBodyModel.from_urdf(source)
        assert "j_épaule" in model.joint_names
    with pytest.raises(ValueError, match="not valid utf-8"):
        RigidBodyModel.from_urdf(BODY.replace("j_b2", "j_épaule").encode("latin-1"))
    with pytest.raises(ValueError, match="unknown encoding 'klingon'"):
        RigidBodyModel.from_urdf(b'<?xml version="1.0" encoding="klingon"?>' + BODY.encode())


def test_mjcf_from_bytes_and_with_a_declaration():
    tree = torchjfa.robots.path("branched_tree")
    reference = RigidBodyModel.from_mjcf(tree)
    data = Path(tree).read_bytes()
    text = DECLARATION + data.decode("utf-8")
    for source in (data, text, text.encode("utf-8")):
        _same_model(RigidBodyModel.from_mjcf(source), reference)


# ----------------------------------------------------------------------------- structure
def test_two_root_trees_are_refused_with_both_roots_named(tmp_path):
    text = _urdf("abcd", [_joint("j1", "a", "b"), _joint("j2", "c", "d")])
    with pytest.raises(ValueError, match=r"2 root links .*'a' \('j1'\); 'c' \('j2'\)"):
        RigidBodyModel.from_urdf(text)
    path = tmp_path / "forest.urdf"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"URDF file '{path}'"):
        RigidBodyModel.from_urdf(path)
    with pytest.raises(cli.UsageError, match="2 root links"):
        cli.load_model(str(path), ("viscous",))


def test_kinematic_loops_are_refused():
    # link b closes a loop: the child of j0 and of j2
    closed = _urdf("abc", [_joint("j0", "a", "b"), _joint("j1", "b", "c"), _joint("j2", "c", "b")])
    with pytest.raises(ValueError, match="'b' is the child of two joints, 'j0' and 'j2'.*loop"):
        RigidBodyModel.from_urdf(closed)
    # a cycle hanging nowhere: c -> d -> c beside the tree a -> b
    cycle = _urdf("abcd", [_joint("j0", "a", "b"), _joint("j1", "c", "d"), _joint("j2", "d", "c")])
    with pytest.raises(ValueError, match="kinematic loop: links 'c' <- 'd' <- 'c'"):
        RigidBodyModel.from_urdf(cycle)
    self_loop = _urdf("ab", [_joint("j0", "a", "b"), _joint("j1", "b", "b")])
    with pytest.raises(ValueError, match="'j1' connects link 'b' to itself"):
        RigidBodyModel.from_urdf(self_loop)


def test_only_fixed_joints_are_refused():
    text = _urdf("abc", [_joint("f1", "a", "b", "fixed"), _joint("f2", "b", "c", "fixed")])
    with pytest.raises(ValueError, match=r"every joint is fixed \('f1', 'f2'\)"):
        RigidBodyModel.from_urdf(text)
    with pytest.raises(ValueError, match="every joint is fixed"):
        RigidBodyModel.from_urdf(SMALL_URDF, fixed_joints=("j_a1", "j_a2", "j_b1", "j_b2"))


def test_undefined_links_and_missing_names_are_refused():
    ghost = _urdf("ab", [_joint("j", "a", "b"), _joint("j2", "b", "ghost")])
    with pytest.raises(ValueError, match=r"'j2' names child link 'ghost', which is not defined"):
        RigidBodyModel.from_urdf(ghost)
    ghost_parent = _urdf("ab", [_joint("j", "a", "b"), _joint("j2", "ghost", "b")])
    with pytest.raises(ValueError, match="names parent link 'ghost'"):
        RigidBodyModel.from_urdf(ghost_parent)
    orphan = _urdf("ab", ['<joint name="j" type="revolute"><parent link="a"/></joint>'])
    with pytest.raises(ValueError, match="'j' has no <child"):
        RigidBodyModel.from_urdf(orphan)
    twice = _urdf("abb", [_joint("j", "a", "b")])
    with pytest.raises(ValueError, match="link 'b' is defined twice"):
        RigidBodyModel.from_urdf(twice)
    bad_mass = BODY.replace('<mass value="0.8"/>', '<mass value="heavy"/>')
    with pytest.raises(ValueError, match="link 'a2' inertial.*'heavy'"):
        RigidBodyModel.from_urdf(bad_mass)


# ----------------------------------------------------------------------------- mimic joints
MIMIC = _urdf(
    "abcd",
    [
        _joint("j1", "a", "b"),
        _joint("f1", "b", "c", "prismatic"),
        _joint("f2", "b", "d", "prismatic", '<mimic joint="f1" multiplier="-1"/>'),
    ],
)


def test_a_mimic_joint_is_refused_and_the_message_says_what_to_do(tmp_path):
    with pytest.raises(ValueError, match=r"'f2' mimics 'f1'.*fixed_joints=\('f2', 'f1'\)"):
        RigidBodyModel.from_urdf(MIMIC)
    path = tmp_path / "gripper.urdf"
    path.write_text(MIMIC)
    with pytest.raises(cli.UsageError, match="mimics") as info:
        cli.load_model(str(path), ("viscous",))
    assert "\n" not in str(info.value)  # one line on the command line
    assert "--fixed-joints f2,f1" in str(info.value)
    from torchjfa.identification import load_model

    held = load_model(str(path), ("viscous",), fixed_joints=("f2", "f1"))
    assert held.joint_names == ("j1",)
    # a <mimic> on a fixed joint couples nothing: accepted (talos' grippers have such joints)
    fixed_mimic = MIMIC.replace('name="f2" type="prismatic"', 'name="f2" type="fixed"')
    assert RigidBodyModel.from_urdf(fixed_mimic).joint_names == ("j1", "f1")
    # where the leaders are all that would move, the advice fixes the followers only
    gripper = MIMIC.replace('name="j1" type="revolute"', 'name="j1" type="fixed"')
    with pytest.raises(ValueError, match=r"fixed_joints=\('f2',\).*followers at q = 0") as info:
        RigidBodyModel.from_urdf(gripper)
    path.write_text(gripper)
    assert load_model(str(path), ("viscous",), fixed_joints=("f2",)).joint_names == ("f1",)
    assert "--fixed-joints f2)" in str(info.value)


def test_mjcf_equality_constraints_are_refused_unless_inactive():
    body = (
        '<mujoco><worldbody><body name="a"><joint name="j1"/><geom size=".1"/>'
        '<body name="b" pos="0 0 .2"><joint name="j2"/><geom size=".1"/></body></body>'
        "</worldbody><equality>{}</equality></mujoco>"
    )
    coupled = '<joint name="couple" joint1="j2" joint2="j1" polycoef="0 2 0 0 0"/>'
    with pytest.raises(ValueError, match="1 active equality constraint.*joint 'couple'"):
        RigidBodyModel.from_mjcf(body.format(coupled))
    with pytest.raises(ValueError, match="connect #0.*closed loops"):
        RigidBodyModel.from_mjcf(body.format('<connect body1="b" anchor="0 0 0"/>'))
    inactive = body.format('<weld body1="b" active="false"/>')
    assert RigidBodyModel.from_mjcf(inactive).joint_names == ("j1", "j2")


def test_mjcf_entities_are_refused_before_mujoco_reads_them(tmp_path, capsys):
    from torchjfa.cli import main

    text = (
        '<!DOCTYPE mujoco [<!ENTITY m "1.0">]>\n<mujoco><worldbody><body name="b">'
        '<joint name="j"/><inertial pos="0 0 0" mass="&m;" diaginertia="1 1 1"/></body>'
        "</worldbody></mujoco>"
    )
    with pytest.raises(ValueError, match=r"declares a document type or entities"):
        RigidBodyModel.from_mjcf(text)
    (tmp_path / "robot.xml").write_text(text)
    assert main(["excite", str(tmp_path / "robot.xml"), "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "entities" in err and not (tmp_path / "t").exists()
    # MuJoCo's own two-line messages come as one line
    with pytest.raises(ValueError, match=r"MuJoCo cannot compile this MJCF") as bad:
        RigidBodyModel.from_mjcf(text.split("\n", 1)[1].replace("&m;", "heavy"))
    assert "\n" not in str(bad.value)


def test_fixed_joints_equal_the_same_joints_written_fixed():
    model = RigidBodyModel.from_urdf(MIMIC, fixed_joints=("f1", "f2"))
    # written out by hand: both fingers attached by fixed joints at the same origins
    by_hand = _urdf(
        "abcd",
        [_joint("j1", "a", "b"), _joint("f1", "b", "c", "fixed"), _joint("f2", "b", "d", "fixed")],
    )
    reference = RigidBodyModel.from_urdf(by_hand)
    assert model.n_dof == 1 and model.lumped_bodies["j1"] == ("c", "d")
    _same_model(model, reference)
    # the source text is the locked description: saving and reloading gives the same model
    _same_model(RigidBodyModel.from_urdf(model.source_xml), model)
    one = RigidBodyModel.from_urdf(SMALL_URDF, fixed_joints="j_b2")
    assert one.joint_names == ("j_a1", "j_a2", "j_b1")
    with pytest.raises(ValueError, match=r"names \['nope'\], which are not joints.*'f1'"):
        RigidBodyModel.from_urdf(MIMIC, fixed_joints=("f1", "nope"))
    with pytest.raises(TypeError, match="joint names"):
        RigidBodyModel.from_urdf(MIMIC, fixed_joints=(1, 2))


# ----------------------------------------------------------------------------- a quiet parser
ROS_TAGS = """
  <transmission name="t_b1">
    <type>transmission_interface/SimpleTransmission</type>
    <joint name="j_b1"><hardwareInterface>hardware_interface/EffortJointInterface</hardwareInterface></joint>
    <actuator name="m_b1"><hardwareInterface>EffortJointInterface</hardwareInterface>
      <mechanicalReduction>100</mechanicalReduction></actuator>
  </transmission>
  <ros2_control name="arm" type="system">
    <hardware><plugin>mock_components/GenericSystem</plugin></hardware>
    <joint name="j_b1"><command_interface name="effort"/><state_interface name="position"/></joint>
  </ros2_control>
  <gazebo reference="b1"><material>Gazebo/Grey</material></gazebo>
  <link name="decorated"><visual><geometry><mesh filename="package://nowhere/m.stl"/></geometry>
    </visual><collision><geometry><mesh filename="package://nowhere/m.dae"/></geometry></collision>
  </link>
  <joint name="j_decorated" type="fixed"><parent link="b2"/><child link="decorated"/></joint>
"""


def test_ros_tags_and_mesh_paths_load_without_a_word(capfd):
    text = BODY.replace("</robot>", ROS_TAGS + "</robot>")
    model = RigidBodyModel.from_urdf(text)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # pytorch-kinematics' parser printed "Unknown tag" lines
    _same_model(model, RigidBodyModel.from_urdf(BODY))
    assert model.lumped_bodies["j_b2"] == ("decorated",)


def test_tags_pytorch_kinematics_would_refuse_are_not_needed():
    # urdf_parser_py requires effort and velocity in <limit>, and a <hardwareInterface> in a
    # <transmission>'s joint; the chain is built without either
    no_effort = BODY.replace(
        '<limit lower="-2" upper="2" effort="100" velocity="1"/>', '<limit lower="-2" upper="2"/>'
    )
    short = BODY.replace(
        "</robot>",
        '<transmission name="t"><type>x</type><joint name="j_b2"/></transmission></robot>',
    )
    for text in (no_effort, short):
        _same_model(RigidBodyModel.from_urdf(text), RigidBodyModel.from_urdf(BODY))


# ----------------------------------------------------------------------------- example-robot-data
def _erd(relative: str) -> str:
    return erd_path(relative)


# (file, fixed_joints, n_dof, starts with an encoding declaration)
ERD_ROBOTS = {
    "panda": (
        "panda_description/urdf/panda.urdf",
        ("panda_finger_joint1", "panda_finger_joint2"),
        7,
        False,
    ),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", (), 7, False),
    "talos_left_arm": ("talos_data/robots/talos_left_arm.urdf", (), 7, False),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", (), 6, True),
    "so101": ("so_arm_description/urdf/so101.urdf", (), 6, True),
}


def _pinocchio_model(pin, path: str, locked: tuple[str, ...]):
    full = pin.buildModelFromUrdf(path)
    if not locked:
        return full
    ids = [full.getJointId(n) for n in locked]
    return pin.buildReducedModel(full, ids, pin.neutral(full))


@pytest.mark.parametrize("name", list(ERD_ROBOTS))
def test_example_robot_data_arms_equal_pinocchios_rnea(name, capfd):
    relative, locked, n_dof, declared = ERD_ROBOTS[name]
    path = _erd(relative)
    head = Path(path).read_bytes()[:60]
    assert head.startswith(b'<?xml version="1.0" encoding="utf-8"?>') == declared
    model = RigidBodyModel.from_urdf(path, fixed_joints=locked)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    assert model.n_dof == n_dof and set(model.joint_types) <= {"revolute", "prismatic"}

    pin = pytest.importorskip("pinocchio")
    pm = _pinocchio_model(pin, path, locked)
    pd = pm.createData()
    names = list(pm.names)[1:]
    assert sorted(names) == sorted(model.joint_names)
    joints = [pm.joints[pm.getJointId(n)] for n in model.joint_names]
    assert all(j.nq == 1 and j.nv == 1 for j in joints)  # revolute/prismatic: q is the angle
    q, qd, qdd = random_state(model.n_dof, (16,), seed=5)
    tau = (model.regressor(q, qd, qdd) @ model.nominal_theta).numpy()
    expected = np.zeros_like(tau)
    for i in range(q.shape[0]):
        qp, vp, ap = (np.zeros(pm.nq) for _ in range(3))
        for k, j in enumerate(joints):
            qp[j.idx_q], vp[j.idx_v], ap[j.idx_v] = q[i, k], qd[i, k], qdd[i, k]
        out_pin = pin.rnea(pm, pd, qp, vp, ap)
        expected[i] = [out_pin[j.idx_v] for j in joints]
    # two float64 recursions from the same decimal inputs: eps (2.2e-16) times the ~1e3
    # operations of a 7-body recursion bounds the difference by ~2e-13 of the largest torque
    # (1e-15 measured); 1e-11 leaves margin for the regressor's different summation order
    scale = max(1.0, float(np.abs(expected).max()))
    np.testing.assert_allclose(tau, expected, rtol=0, atol=1e-11 * scale)


def test_example_robot_data_path_errors(monkeypatch):
    _erd("panda_description/urdf/panda.urdf")
    with pytest.raises(
        FileNotFoundError, match="has no file robots/nope/x.urdf.*panda_description"
    ):
        torchjfa.robots.example_robot_data_path("nope/x.urdf")

    def absent(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "distribution", absent)
    with pytest.raises(ModuleNotFoundError, match="pip install example-robot-data"):
        torchjfa.robots.example_robot_data_path("panda_description/urdf/panda.urdf")
