"""Drive trains: motors' joint terms through a (coupled) ratio matrix, against MuJoCo's fixed
tendons and an independently written formula, in every regressor path, saved and written back."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
import torch

import torchjfa.robots
from torchjfa.data import JointLog
from torchjfa.dynamics import RigidBodyModel, Transmission, mass_matrix, read_transmission
from torchjfa.io import identified_from_dict, identified_to_dict, read_identified, save_identified

# a 4-joint arm whose last motor turns joints 3 and 4 together (a coupled wrist)
XML = """<mujoco><option gravity="0 0 -9.81"><flag contact="disable"/></option><worldbody>
<body name="b1"><joint name="j1" type="hinge" axis="0 0 1"/>
 <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.05" mass="2"/>
 <body name="b2" pos="0 0 0.3"><joint name="j2" type="hinge" axis="0 1 0"/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04" mass="1.5"/>
  <body name="b3" pos="0.3 0 0"><joint name="j3" type="hinge" axis="1 0 0"/>
   <geom type="box" size="0.03 0.05 0.02" pos="0.05 0.01 0" mass="0.6"/>
   <body name="b4" pos="0.1 0 0"><joint name="j4" type="hinge" axis="0 1 0"/>
    <geom type="box" size="0.04 0.02 0.02" pos="0.04 0 0.01" mass="0.4"/></body>
  </body></body></body></worldbody></mujoco>"""
JOINTS = ("j1", "j2", "j3", "j4")
MOTORS = ("m1", "m2", "m3", "m4")
RATIO = np.array([[50, 0, 0, 0], [0, -40, 0, 0], [0, 0, 30, 0], [0, 0, 30, 30]], dtype=float)
ARMATURE = (4e-4, 3e-4, 2e-4, 1e-4)  # kg m^2 at the motor shaft
DAMPING = (2e-3, 3e-3, 1e-3, 1.5e-3)  # N m s/rad at the motor shaft
COULOMB = (0.02, 0.03, 0.01, 0.015)  # N m at the motor shaft
OFFSET = (0.01, -0.02, 0.005, 0.0)  # N m at the motor shaft
ALL = ("viscous", "coulomb", "offset", "armature")


def _tendons(ratio=RATIO, motors=MOTORS, joints=JOINTS) -> str:
    fixed = []
    for k, row in enumerate(ratio):
        coefs = "".join(
            f'<joint joint="{j}" coef="{c:g}"/>' for j, c in zip(joints, row, strict=True) if c
        )
        fixed.append(
            f'<fixed name="{motors[k]}" armature="{ARMATURE[k]:g}" damping="{DAMPING[k]:g}">'
            f"{coefs}</fixed>"
        )
    return f"<tendon>{''.join(fixed)}</tendon>"


def _model(friction=ALL, coulomb_velocity=0.0) -> RigidBodyModel:
    model = RigidBodyModel.from_mjcf(XML, friction=friction, coulomb_velocity=coulomb_velocity)
    return model.with_transmission(Transmission(JOINTS, RATIO, MOTORS))


def _theta(model) -> torch.Tensor:
    theta = model.nominal_theta.clone()
    values = {"fv": DAMPING, "ia": ARMATURE, "fc": COULOMB, "fo": OFFSET}
    for k in range(4):
        for short, column in values.items():
            if f"{MOTORS[k]}.{short}" in model.parameter_names:
                theta[model.layout.index(k, short)] = column[k]
    return theta


def _states(n=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(n, 4, generator=g, dtype=torch.float64) for _ in range(3)]


def test_armature_and_damping_of_coupled_motors_agree_with_mujoco_tendons():
    m = mujoco.MjModel.from_xml_string(XML.replace("</worldbody>", "</worldbody>" + _tendons()))
    d = mujoco.MjData(m)
    model = _model(("viscous", "armature"))
    theta = _theta(model)
    q, qd, qdd = _states()
    expected = []
    for i in range(q.shape[0]):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[i].numpy(), qd[i].numpy(), qdd[i].numpy()
        mujoco.mj_inverse(m, d)
        expected.append(d.qfrc_inverse.copy())
    expected = np.array(expected)
    scale = np.abs(expected).max()
    for compiled in (None, False):
        tau = model.regressor(q, qd, qdd, compiled=compiled) @ theta
        np.testing.assert_allclose(tau.numpy(), expected, rtol=0, atol=1e-9 * scale)


def _formula(q, qd, qdd, coulomb_velocity):
    """Rigid body (a model without joint terms) + R^T (I R qdd + fv R qd + fc s(R qd) + fo)."""
    rigid = RigidBodyModel.from_mjcf(XML, friction=())
    tau = (rigid.regressor(q, qd, qdd, compiled=False) @ rigid.nominal_theta).numpy()
    vel = qd.numpy() @ RATIO.T
    if coulomb_velocity:
        dry = np.tanh(vel / (coulomb_velocity * np.abs(RATIO).max(axis=1)))
    else:
        dry = np.sign(vel)
    motor = (
        np.array(ARMATURE) * (qdd.numpy() @ RATIO.T)
        + np.array(DAMPING) * vel
        + np.array(COULOMB) * dry
        + np.array(OFFSET)
    )
    return tau + motor @ RATIO


@pytest.mark.parametrize("coulomb_velocity", [0.0, 0.05])
def test_every_regressor_path_gives_the_motor_terms_of_the_formula(coulomb_velocity):
    model = _model(coulomb_velocity=coulomb_velocity)
    theta = _theta(model)
    q, qd, qdd = _states(seed=1)
    qd = 0.1 * qd  # velocities where tanh and sign differ
    expected = _formula(q, qd, qdd, coulomb_velocity)
    atol = 1e-12 * np.abs(expected).max()
    for compiled in (None, False):
        got = model.regressor(q, qd, qdd, compiled=compiled) @ theta
        np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=atol)
    # the autograd path, and its gradient against a central difference
    qdd_g = qdd.clone().requires_grad_(True)
    got = model.regressor(q, qd, qdd_g) @ theta
    np.testing.assert_allclose(got.detach().numpy(), expected, rtol=0, atol=atol)
    (grad,) = torch.autograd.grad(got[:, 3].sum(), qdd_g)
    h = 1e-6
    step = torch.zeros_like(qdd)
    step[:, 2] = h
    fd = ((model.regressor(q, qd, qdd + step) - model.regressor(q, qd, qdd - step)) @ theta)[
        :, 3
    ] / (2 * h)
    np.testing.assert_allclose(grad[:, 2].numpy(), fd.numpy(), rtol=1e-6, atol=1e-9)


def test_the_mass_matrix_holds_the_reflected_rotor_inertia():
    model = _model(("armature",))
    theta = _theta(model)
    rigid = RigidBodyModel.from_mjcf(XML, friction=())
    q = _states(4)[0]
    reflected = RATIO.T @ np.diag(ARMATURE) @ RATIO  # off-diagonal where motor 4 couples 3, 4
    assert reflected[2, 3] != 0
    diff = (mass_matrix(model, q, theta) - mass_matrix(rigid, q, rigid.nominal_theta)).numpy()
    np.testing.assert_allclose(diff, np.broadcast_to(reflected, diff.shape), rtol=1e-9, atol=1e-12)


def test_parameter_names_follow_the_motors_and_joints_outside_keep_theirs():
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"), friction=("viscous",))
    wrist = Transmission(("panda_joint6", "panda_joint7"), [[32, 0], [32, 32]], ("m6", "m7"))
    geared = model.with_transmission(wrist)
    names = geared.parameter_names
    assert "m6.fv" in names and "m7.fv" in names and "panda_joint6.fv" not in names
    assert "panda_joint1.fv" in names and geared.n_params == model.n_params
    assert "panda_joint6.m" in names  # the inertials stay the joints'
    assert geared.with_joint_terms(("viscous", "armature")).transmission == wrist
    assert geared.with_coulomb_velocity(0.1).parameter_names == names
    assert model.transmission is None and wrist.coupled == ("m7",)


def test_a_saved_model_keeps_its_transmission(tmp_path):
    model = _model()
    theta = _theta(model)
    save_identified(tmp_path / "m.npz", model, theta)
    back = read_identified(tmp_path / "m.npz")
    assert back.model.transmission == model.transmission
    assert back.model.parameter_names == model.parameter_names
    q, qd, qdd = _states(seed=2)
    np.testing.assert_array_equal(
        back.inverse_dynamics()(q, qd, qdd).detach().numpy(),
        model.inverse_dynamics(q, qd, qdd, theta).numpy(),
    )
    again = identified_from_dict(identified_to_dict(model, theta))
    assert again.model.transmission == model.transmission


def test_the_written_mjcf_simulates_the_motors_as_tendons(tmp_path):
    model = _model(("viscous", "coulomb", "armature"))
    theta = _theta(model)
    model.write_mjcf(theta, tmp_path / "geared.xml")
    root = ET.parse(tmp_path / "geared.xml").getroot()
    fixed = {el.get("name"): el for el in root.iter("fixed")}
    assert sorted(fixed) == sorted(MOTORS)
    assert [(j.get("joint"), float(j.get("coef"))) for j in fixed["m4"]] == [
        ("j3", 30.0),
        ("j4", 30.0),
    ]
    assert float(fixed["m2"].get("frictionloss")) == COULOMB[1]
    for joint in root.iter("joint"):
        assert joint.get("damping") is None  # the joints carry no terms of their own
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "geared.xml"))
    d = mujoco.MjData(m)
    no_dry = _model(("viscous", "armature"))
    q, qd, qdd = _states(6, seed=3)
    for i in range(q.shape[0]):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[i].numpy(), qd[i].numpy(), qdd[i].numpy()
        mujoco.mj_inverse(m, d)
        # MuJoCo's dry friction is a (soft) constraint force, which qfrc_inverse subtracts:
        # add it back and compare the rest
        assert np.abs(d.qfrc_constraint).max() > 0.1
        d.qfrc_inverse[:] += d.qfrc_constraint
        expected = no_dry.inverse_dynamics(q[i], qd[i], qdd[i], _theta(no_dry)).numpy()
        np.testing.assert_allclose(d.qfrc_inverse, expected, rtol=1e-9, atol=1e-9)


def test_the_written_urdf_holds_the_joint_side_terms_of_lone_motors(tmp_path):
    model = RigidBodyModel.from_urdf(
        torchjfa.robots.path("panda_arm"), friction=("viscous", "coulomb")
    )
    wrist = Transmission(("panda_joint6", "panda_joint7"), [[-20, 0], [32, 32]], ("m6", "m7"))
    geared = model.with_transmission(wrist)
    theta = geared.nominal_theta.clone()
    theta[geared.layout.index("panda_joint6", "fv")] = 0.001
    theta[geared.layout.index("panda_joint6", "fc")] = 0.05
    theta[geared.layout.index("panda_joint7", "fv")] = 0.002
    geared.write_urdf(theta, tmp_path / "geared.urdf")
    joints = {el.get("name"): el for el in ET.parse(tmp_path / "geared.urdf").iter("joint")}
    dyn6 = joints["panda_joint6"].find("dynamics")
    assert float(dyn6.get("damping")) == pytest.approx(0.001 * 400, rel=1e-15)
    assert float(dyn6.get("friction")) == pytest.approx(0.05 * 20, rel=1e-15)
    # motor 7 turns joints 6 and 7: no URDF field holds it, joint 7 keeps the file's own
    original = ET.fromstring(model.source_xml).find("joint[@name='panda_joint7']/dynamics")
    dyn7 = joints["panda_joint7"].find("dynamics")
    assert (dyn7 is None and original is None) or dyn7.attrib == original.attrib


def test_transmission_files_and_errors(tmp_path):
    spec = {"joints": ["a", "b"], "ratio": [[10, 0], [5, 5]]}
    (tmp_path / "t.json").write_text(json.dumps(spec))
    (tmp_path / "t.yaml").write_text("joints: [a, b]\nratio:\n  - [10, 0]\n  - [5, 5]\n")
    a, b = read_transmission(tmp_path / "t.json"), read_transmission(tmp_path / "t.yaml")
    assert a == b and a.motors == ("a_motor", "b_motor")
    assert Transmission.from_dict(a.to_dict()) == a
    for bad, words in [
        ({"joints": ["a", "b"], "ratio": [[1, 0]]}, "must be 2 x 2"),
        ({"joints": ["a", "b"], "ratio": [[1, 1], [1, 1]]}, "not invertible"),
        ({"joints": ["a", "a"], "ratio": [[1, 0], [0, 1]]}, "joints repeat"),
        ({"joints": ["a"], "ratio": [[float("nan")]]}, "not finite"),
        ({"joints": ["a"], "ratio": [[2]], "gears": 1}, "unknown ['gears']"),
        ({"joints": ["a"], "ratio": [[2]], "motors": ["a"]}, "different names"),
    ]:
        with pytest.raises(ValueError, match=None) as err:
            Transmission.from_dict(bad)
        assert words in str(err.value)
    (tmp_path / "bad.yaml").write_text("joints: [a\n")
    with pytest.raises(ValueError, match="neither JSON nor YAML"):
        read_transmission(tmp_path / "bad.yaml")
    with pytest.raises(FileNotFoundError):
        read_transmission(tmp_path / "missing.json")
    model = RigidBodyModel.from_mjcf(XML)
    with pytest.raises(ValueError, match=r"joints \['a', 'b'\] that the robot does not have"):
        model.with_transmission(a)


def test_a_log_recorded_at_the_motors_is_converted_to_the_joints():
    t = Transmission(("j3", "j4"), RATIO[2:, 2:], ("m3", "m4"))
    g = torch.Generator().manual_seed(4)
    q_joint = torch.randn(50, 2, generator=g, dtype=torch.float64)
    tau_joint = torch.randn(50, 2, generator=g, dtype=torch.float64)
    ratio = torch.as_tensor(RATIO[2:, 2:])
    tau_motor = torch.linalg.solve(ratio.T, tau_joint.T).T  # tau_joint = R^T tau_motor
    other = torch.randn(50, 1, generator=g, dtype=torch.float64)
    log = JointLog(
        t=torch.arange(50) * 0.01,
        q=torch.cat([other, q_joint @ ratio.T], 1),
        tau=torch.cat([other, tau_motor], 1),
        joint_names=("j1", "m3", "m4"),
    )
    joint = t.joint_side(log)
    assert joint.joint_names == ("j1", "j3", "j4")
    np.testing.assert_allclose(joint.q[:, 1:].numpy(), q_joint.numpy(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(joint.tau[:, 1:].numpy(), tau_joint.numpy(), rtol=1e-12, atol=1e-12)
    assert torch.equal(joint.q[:, 0], other[:, 0]) and "converted" in joint.info["read_notes"][-1]
    mixed = JointLog(t=log.t, q=log.q, tau=log.tau, joint_names=("j3", "m3", "m4"))
    with pytest.raises(ValueError, match="none of the joints they drive"):
        t.joint_side(mixed)
