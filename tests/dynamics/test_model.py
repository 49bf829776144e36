"""RigidBodyModel: loading, parameter layout, inertial conversions, write-back, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from dyn_robots import ROBOTS, SMALL_URDF, random_state

import torchjfa.robots
from torchjfa import Moments
from torchjfa.dynamics import BodyInertial, RigidBodyModel

PANDA = torchjfa.robots.path("panda")
TREE = torchjfa.robots.path("branched_tree")


def test_panda_description():
    model = RigidBodyModel.from_urdf(PANDA)
    assert model.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8)) + (
        "panda_finger_joint1",
        "panda_finger_joint2",
    )
    assert model.joint_types == ("revolute",) * 7 + ("prismatic",) * 2
    assert model.n_dof == 9 and model.n_params == 99
    assert model.parents == (-1, 0, 1, 2, 3, 4, 5, 6, 6)  # the fingers branch off the hand
    assert model.lumped_bodies["panda_joint7"] == ("panda_link8", "panda_hand", "panda_hand_tcp")
    assert model.parameter_names[:11] == tuple(
        f"panda_joint1.{p}"
        for p in ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz", "fv")
    )
    assert model.source_format == "urdf" and model.source_path == PANDA
    assert model.chain.get_joint_parameter_names() == list(model.joint_names)
    theta = model.nominal_theta
    assert theta.dtype == torch.float64 and theta.shape == (99,)
    # link1's inertial written out from the URDF by hand: [m, m c, I_c + m(|c|^2 1 - c c^T)]
    m, c = 4.970684, np.array([0.003875, 0.002081, -0.04762])
    ic = np.array(
        [
            [0.70337, -0.000139, 0.006772],
            [-0.000139, 0.70661, 0.019169],
            [0.006772, 0.019169, 0.009117],
        ]
    )
    io = ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    expected = [m, *(m * c), io[0, 0], io[0, 1], io[1, 1], io[0, 2], io[1, 2], io[2, 2], 0.0]
    np.testing.assert_allclose(theta[:11].numpy(), expected, rtol=1e-14, atol=1e-16)
    # the hand (0.73 kg) is lumped into link 7 (0.735522 kg)
    assert float(theta[model.layout.index("panda_joint7", "m")]) == pytest.approx(0.735522 + 0.73)


def test_nominal_theta_equals_pinocchios_dynamic_parameters():
    pin = pytest.importorskip("pinocchio")
    model = RigidBodyModel.from_urdf(PANDA)
    pm = pin.buildModelFromUrdf(PANDA)
    theirs = np.concatenate([pm.inertias[k].toDynamicParameters() for k in range(1, pm.njoints)])
    mine = model.layout.split(model.nominal_theta)[0].reshape(-1).numpy()
    np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-14)


def test_branched_mjcf_description():
    model = RigidBodyModel.from_mjcf(TREE)
    assert model.joint_names == (
        "torso_yaw",
        "left_shoulder",
        "left_elbow",
        "right_shoulder",
        "right_slide",
    )
    assert model.parents == (-1, 0, 1, 0, 3)
    assert model.joint_types[-1] == "prismatic"
    assert model.lumped_bodies["right_slide"] == ("right_hand",)
    assert model.source_format == "mjcf"
    # a string of XML gives the same model
    text = Path(TREE).read_text()
    other = RigidBodyModel.from_mjcf(text)
    assert other.source_path is None
    torch.testing.assert_close(other.nominal_theta, model.nominal_theta, rtol=0, atol=0)


@pytest.mark.parametrize("name", list(ROBOTS))
def test_inertials_round_trip(name):
    kind, source = ROBOTS[name]
    model = (RigidBodyModel.from_urdf if kind == "urdf" else RigidBodyModel.from_mjcf)(source)
    bodies = model.inertials()
    assert [b.joint for b in bodies] == list(model.joint_names)
    assert all(isinstance(b, BodyInertial) and b.inertia.shape == (3, 3) for b in bodies)
    friction = torch.arange(model.n_dof, dtype=torch.float64)[:, None] + 1.0
    theta = model.theta_from_inertials(list(reversed(bodies)), friction=friction)
    inertial, fr = model.layout.split(theta)
    torch.testing.assert_close(inertial, model.layout.split(model.nominal_theta)[0])
    torch.testing.assert_close(fr, friction)


@pytest.mark.parametrize("name", list(ROBOTS))
def test_write_and_reload_gives_the_same_theta(name, tmp_path):
    kind, source = ROBOTS[name]
    load = RigidBodyModel.from_urdf if kind == "urdf" else RigidBodyModel.from_mjcf
    model = load(source)
    # a different, physically consistent theta: scale masses and move centres of mass
    g = torch.Generator().manual_seed(0)
    new = []
    for b in model.inertials():
        s = 1.0 + torch.rand((), generator=g, dtype=torch.float64)
        shift = 0.01 * torch.randn(3, generator=g, dtype=torch.float64)
        new.append(BodyInertial(b.joint, b.body, b.mass * s, b.com + shift, b.inertia * s))
    theta = model.theta_from_inertials(new)
    out = tmp_path / f"robot.{kind}"
    (model.write_urdf if kind == "urdf" else model.write_mjcf)(theta, out)
    again = load(out)
    assert again.joint_names == model.joint_names
    torch.testing.assert_close(again.nominal_theta, theta, rtol=1e-12, atol=1e-14)
    # kinematics unchanged: same regressor
    q, qd, qdd = random_state(model.n_dof, (3,), seed=1)
    torch.testing.assert_close(again.regressor(q, qd, qdd), model.regressor(q, qd, qdd))


def test_streaming_chunks_and_moments_equal_the_full_matrix():
    model = RigidBodyModel.from_mjcf(TREE)
    q, qd, qdd = random_state(model.n_dof, (5, 9), seed=3)
    tau = torch.randn(
        5, 9, model.n_dof, generator=torch.Generator().manual_seed(1), dtype=torch.float64
    )
    Y = model.regressor(q, qd, qdd).reshape(-1, model.n_params)
    chunks = list(model.regressor_chunks(q, qd, qdd, tau, chunk_size=7))
    assert [c[0].shape[0] for c in chunks] == [7 * model.n_dof] * 6 + [3 * model.n_dof]
    torch.testing.assert_close(torch.cat([c[0] for c in chunks]), Y, rtol=0, atol=0)
    torch.testing.assert_close(torch.cat([c[1] for c in chunks]), tau.reshape(-1), rtol=0, atol=0)
    m = model.moments(q, qd, qdd, tau, chunk_size=4)
    assert isinstance(m, Moments) and m.n_rows == 45 * model.n_dof
    torch.testing.assert_close(m.xtx, Y.T @ Y)
    torch.testing.assert_close(m.xty, Y.T @ tau.reshape(-1))
    torch.testing.assert_close(m.yty, tau.reshape(-1) @ tau.reshape(-1))


# ----------------------------------------------------------------------------- bad input
def test_bad_state_shapes_and_values():
    model = RigidBodyModel.from_urdf(SMALL_URDF)
    n = model.n_dof
    q, qd, qdd = random_state(n, (4,), seed=0)
    with pytest.raises(ValueError, match="shape"):
        model.regressor(q[:, :-1], qd[:, :-1], qdd[:, :-1])
    with pytest.raises(ValueError, match="same shape"):
        model.regressor(q, qd[:2], qdd)
    with pytest.raises(ValueError, match="shape"):
        model.regressor(torch.tensor(1.0), torch.tensor(1.0), torch.tensor(1.0))
    bad = q.clone()
    bad[1, 2] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        model.regressor(bad, qd, qdd)
    with pytest.raises(ValueError, match="infinite"):
        model.moments(q, qd, qdd, torch.full_like(q, float("inf")))
    with pytest.raises(ValueError, match="chunk_size"):
        model.regressor(q, qd, qdd, chunk_size=0)
    with pytest.raises(ValueError, match="theta"):
        model.inertials(torch.zeros(3))
    with pytest.raises(TypeError):
        model.regressor("abc", qd, qdd)


def test_missing_file_and_bad_sources():
    with pytest.raises(FileNotFoundError, match="no URDF file"):
        RigidBodyModel.from_urdf("/nonexistent/robot.urdf")
    with pytest.raises(FileNotFoundError, match="no MJCF file"):
        RigidBodyModel.from_mjcf("/nonexistent/robot.xml")
    with pytest.raises(ValueError, match="not valid XML"):
        RigidBodyModel.from_urdf("<robot><link></robot>")
    with pytest.raises(ValueError, match="unknown robot"):
        torchjfa.robots.path("r2d2")


def test_unknown_and_floating_joints_are_rejected():
    spherical = SMALL_URDF.replace('type="continuous"', 'type="spherical"')
    with pytest.raises(ValueError, match="unknown type 'spherical'"):
        RigidBodyModel.from_urdf(spherical)
    floating = SMALL_URDF.replace('type="continuous"', 'type="floating"')
    with pytest.raises(ValueError, match="floating"):
        RigidBodyModel.from_urdf(floating)
    free = (
        Path(TREE)
        .read_text()
        .replace('<joint name="torso_yaw" type="hinge" axis="0 0 1"/>', '<freejoint name="float"/>')
    )
    with pytest.raises(ValueError, match="free joint"):
        RigidBodyModel.from_mjcf(free)
    ball = (
        Path(TREE)
        .read_text()
        .replace(
            '<joint name="right_shoulder" type="hinge" axis="0 1 0"/>',
            '<joint name="right_shoulder" type="ball"/>',
        )
    )
    with pytest.raises(ValueError, match="ball"):
        RigidBodyModel.from_mjcf(ball)
    two = (
        Path(TREE)
        .read_text()
        .replace(
            '<joint name="right_shoulder" type="hinge" axis="0 1 0"/>',
            '<joint name="right_shoulder" type="hinge" axis="0 1 0"/>'
            '<joint name="extra" axis="1 0 0"/>',
        )
    )
    with pytest.raises(ValueError, match="2 joints"):
        RigidBodyModel.from_mjcf(two)


def test_massless_body_where_a_mass_is_needed():
    massless = SMALL_URDF.replace('<mass value="0.5"/>', '<mass value="0.0"/>')
    model = RigidBodyModel.from_urdf(massless)  # a regressor needs no mass
    assert float(model.nominal_theta[model.layout.index("j_b2", "m")]) == 0.0
    with pytest.raises(ValueError, match="'b2' moved by joint 'j_b2' has mass 0.0"):
        model.inertials()
    with pytest.raises(ValueError, match="positive mass"):
        model.write_urdf(model.nominal_theta, "/tmp/never_written.urdf")
    with pytest.raises(ValueError, match="positive mass|mass and inertia"):
        model.write_mjcf(model.nominal_theta, "/tmp/never_written.xml")


def test_write_mjcf_writes_the_joint_terms_and_simulates_them(tmp_path):
    import mujoco

    model = RigidBodyModel.from_mjcf(TREE, friction=("viscous", "coulomb", "armature"))
    g = torch.Generator().manual_seed(3)
    theta = model.nominal_theta.clone()
    rows = {k: [model.layout.index(j, k) for j in range(model.n_dof)] for k in ("fv", "fc", "ia")}
    for idx in rows.values():
        theta[idx] = 0.05 + torch.rand(len(idx), generator=g, dtype=torch.float64)
    out = tmp_path / "robot.xml"
    model.write_mjcf(theta, out)
    m = mujoco.MjModel.from_xml_path(str(out))
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in model.joint_names]
    dof = m.jnt_dofadr[jid]
    np.testing.assert_array_equal(m.dof_armature[dof], theta[rows["ia"]].numpy())
    np.testing.assert_array_equal(m.dof_damping[dof], theta[rows["fv"]].numpy())
    np.testing.assert_array_equal(m.dof_frictionloss[dof], theta[rows["fc"]].numpy())
    # the written robot's inverse dynamics (dry friction off: a constraint, not a force law)
    # is the regressor's with theta's armature and viscous terms
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    d = mujoco.MjData(m)
    q, qd, qdd = random_state(model.n_dof, (4,), seed=9)
    Y = model.regressor(q, qd, qdd)
    no_dry = theta.clone()
    no_dry[rows["fc"]] = 0.0
    for i in range(4):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[i].numpy(), qd[i].numpy(), qdd[i].numpy()
        mujoco.mj_inverse(m, d)
        np.testing.assert_allclose(d.qfrc_inverse, (Y[i] @ no_dry).numpy(), rtol=1e-9, atol=1e-9)
    bad = theta.clone()
    bad[rows["ia"][0]] = -0.1
    with pytest.raises(ValueError, match="negative armature"):
        model.write_mjcf(bad, tmp_path / "bad.xml")


def test_the_description_is_judged_with_the_damping_and_friction_it_states():
    import re

    text = Path(torchjfa.robots.path("panda_arm")).read_text()
    text = re.sub(r"<dynamics[^>]*/>", '<dynamics damping="0.7" friction="0.3"/>', text)
    model = RigidBodyModel.from_urdf(text, friction=("viscous", "coulomb", "offset"))
    inertial, terms = model.layout.split(model.description_theta)
    stated = text.count('<dynamics damping="0.7" friction="0.3"/>')
    assert stated >= model.n_dof  # the description states them for every joint
    torch.testing.assert_close(terms[:, 0], torch.full((model.n_dof,), 0.7, dtype=torch.float64))
    torch.testing.assert_close(terms[:, 1], torch.full((model.n_dof,), 0.3, dtype=torch.float64))
    assert bool((terms[:, 2] == 0).all())  # no offset in a description
    torch.testing.assert_close(inertial, model.layout.split(model.nominal_theta)[0])
    assert bool((model.layout.split(model.nominal_theta)[1] == 0).all())


def test_an_mjcfs_default_classes_give_the_stated_joint_terms():
    xml = """<mujoco><default><joint damping="0.4" frictionloss="0.1" armature="0.02"/>
      <default class="stiff"><joint damping="1.5"/></default></default>
      <worldbody><body name="a"><joint name="j1" axis="0 0 1"/>
        <geom size="0.1" mass="1"/>
        <body name="b" pos="0 0 0.3"><joint name="j2" class="stiff" axis="0 1 0"/>
          <geom size="0.1" mass="1"/></body></body></worldbody></mujoco>"""
    model = RigidBodyModel.from_mjcf(xml, friction=("viscous", "coulomb", "armature"))
    _, terms = model.layout.split(model.description_theta)
    expected = torch.tensor([[0.4, 0.1, 0.02], [1.5, 0.1, 0.02]], dtype=torch.float64)
    torch.testing.assert_close(terms, expected)
