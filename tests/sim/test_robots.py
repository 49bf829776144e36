"""The shipped MJCF robots: structure, switchable effects, and MuJoCo as the regressor's oracle."""

import mujoco
import numpy as np
import pytest
import torch

from torchjfa.dynamics import RigidBodyModel
from torchjfa.sim import (
    EFFECTS,
    UNMODELED,
    load_robot,
    model_path,
    robot_effects,
    true_parameters,
)

ROBOTS = {"head": 7, "arm": 10}


@pytest.mark.parametrize("robot, n_dof", ROBOTS.items())
def test_models_load_with_hinges_motors_ranges_and_no_contacts(robot, n_dof):
    m = load_robot(robot)
    assert m.njnt == m.nv == m.nu == n_dof
    assert np.all(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert np.all(m.jnt_limited) and np.all(m.jnt_range[:, 0] < m.jnt_range[:, 1])
    assert np.all(m.body_jntnum[1:] <= 1)
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    assert np.all(m.actuator_gear[:, 0] == 1.0) and not np.any(m.actuator_ctrllimited)
    assert np.array_equal(m.actuator_trnid[:, 0], np.arange(n_dof))
    assert np.all(m.body_mass[m.jnt_bodyid] > 0)
    # full inertias: some body has a rotated principal frame (non-diagonal inertia)
    assert np.any(np.abs(m.body_iquat[m.jnt_bodyid, 1:]).max(axis=1) > 1e-3)
    assert RigidBodyModel.from_mjcf(model_path(robot)).n_params == 11 * n_dof


def test_head_tree_branches_after_the_neck():
    model = RigidBodyModel.from_mjcf(model_path("head"))
    parent = dict(
        zip(
            model.joint_names,
            [model.joint_names[p] if p >= 0 else None for p in model.parents],
            strict=True,
        )
    )
    assert parent == {
        "neck_pan": None,
        "neck_tilt": "neck_pan",
        "neck_roll": "neck_tilt",
        "left_eye_pan": "neck_roll",
        "left_eye_tilt": "left_eye_pan",
        "right_eye_pan": "neck_roll",
        "right_eye_tilt": "right_eye_pan",
    }
    m = load_robot("head")
    body_parent = m.body_parentid[m.jnt_bodyid]
    names = [m.joint(i).name for i in range(m.njnt)]
    assert body_parent[names.index("left_eye_pan")] == body_parent[names.index("right_eye_pan")]


def test_arm_chain_and_fingers_branch_off_the_hand():
    model = RigidBodyModel.from_mjcf(model_path("arm"))
    assert model.parents == (-1, 0, 1, 2, 3, 4, 5, 6, 6, 6)
    assert model.joint_names[6] == "wrist_aa"


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_effects_switch(robot):
    true = robot_effects(robot)
    assert all(np.all(true[k] > 0) for k in EFFECTS)
    on = load_robot(robot, unmodeled=True)
    off = load_robot(robot, unmodeled=False)
    assert np.array_equal(on.dof_armature, true["armature"])
    assert np.array_equal(on.jnt_stiffness, true["stiffness"])
    for m in (on, off):
        assert np.array_equal(m.dof_damping, true["damping"])  # viscous friction stays on
    assert not off.dof_armature.any() and not off.dof_frictionloss.any()
    assert not off.jnt_stiffness.any()
    rigid = load_robot(robot, unmodeled={"damping": False})
    assert not rigid.dof_damping.any() and not rigid.dof_armature.any()
    mixed = load_robot(robot, unmodeled={"armature": True, "frictionloss": 0.01, "damping": 0.0})
    assert np.array_equal(mixed.dof_armature, true["armature"])
    assert np.all(mixed.dof_frictionloss == 0.01)
    assert not mixed.jnt_stiffness.any() and not mixed.dof_damping.any()
    n = on.njnt
    per_joint = load_robot(robot, unmodeled={"stiffness": np.arange(n) * 0.1})
    assert np.allclose(per_joint.jnt_stiffness, np.arange(n) * 0.1)


def test_bad_robot_and_effects_raise():
    with pytest.raises(ValueError, match="unknown robot"):
        load_robot("leg")
    with pytest.raises(ValueError, match="unknown effects"):
        load_robot("head", unmodeled={"backlash": 1.0})
    with pytest.raises(ValueError, match="shape"):
        load_robot("head", unmodeled={"armature": [0.1, 0.2]})
    with pytest.raises(ValueError, match="non-negative"):
        load_robot("head", unmodeled={"stiffness": -1.0})
    with pytest.raises(TypeError, match="mapping"):
        load_robot("head", unmodeled="yes")


def _states(m, n, seed):
    """Random states inside the ranges, with |qd| >= 0.5 rad/s so dry friction is saturated."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(m.jnt_range[:, 0], m.jnt_range[:, 1], (n, m.njnt))
    qd = rng.uniform(0.5, 2.0, (n, m.njnt)) * rng.choice([-1.0, 1.0], (n, m.njnt))
    qdd = rng.uniform(-10.0, 10.0, (n, m.njnt))
    return q, qd, qdd


def _mj_inverse(m, q, qd, qdd):
    d = mujoco.MjData(m)
    out = np.empty_like(q)
    for k in range(q.shape[0]):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(m, d)
        out[k] = d.qfrc_inverse
    return out


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_regressor_matches_mj_inverse_and_effects_by_hand(robot):
    model = RigidBodyModel.from_mjcf(model_path(robot))
    assert model.joint_names == tuple(load_robot(robot).joint(i).name for i in range(model.n_dof))
    q, qd, qdd = _states(load_robot(robot), 20, seed=1)
    Y = model.regressor(torch.as_tensor(q), torch.as_tensor(qd), torch.as_tensor(qdd)).numpy()
    theta = model.nominal_theta.clone()
    true = robot_effects(robot)
    tau_rigid = Y @ theta.numpy()
    scale = np.abs(tau_rigid).max(axis=0)  # per joint, N m

    rigid = load_robot(robot, unmodeled={"damping": False})
    assert np.abs(_mj_inverse(rigid, q, qd, qdd) - tau_rigid).max(axis=0).max() < 1e-9 * scale.max()

    # viscous damping on: the fv column carries it
    fv = [model.layout.index(j, "fv") for j in range(model.n_dof)]
    theta[fv] = torch.as_tensor(true["damping"])
    tau_fv = Y @ theta.numpy()
    damped = load_robot(robot, unmodeled=False)
    assert np.allclose(_mj_inverse(damped, q, qd, qdd), tau_fv, rtol=0, atol=1e-9 * scale.max())
    assert np.allclose(tau_fv - tau_rigid, true["damping"] * qd, rtol=1e-9, atol=1e-14)

    # armature, dry friction and cable stiffness on: the difference is exactly those effects
    full = load_robot(robot, unmodeled=True)
    by_hand = true["armature"] * qdd + true["stiffness"] * q + true["frictionloss"] * np.sign(qd)
    diff = _mj_inverse(full, q, qd, qdd) - tau_fv
    assert np.allclose(diff, by_hand, rtol=1e-9, atol=1e-9 * scale.max())
    assert np.abs(by_hand).min() > 0  # the check is not vacuous
    for effect in UNMODELED:  # and each one alone
        one = load_robot(robot, unmodeled={effect: True})
        part = {
            "armature": true["armature"] * qdd,
            "stiffness": true["stiffness"] * q,
            "frictionloss": true["frictionloss"] * np.sign(qd),
        }[effect]
        assert np.allclose(_mj_inverse(one, q, qd, qdd) - tau_fv, part, atol=1e-9 * scale.max())


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_true_parameters_reproduce_mujocos_torque_without_the_unmodeled_effects(robot):
    model = RigidBodyModel.from_mjcf(model_path(robot), friction=("viscous", "coulomb"))
    theta = true_parameters(robot, model)
    q, qd, qdd = _states(load_robot(robot), 20, seed=4)
    Y = model.regressor(torch.as_tensor(q), torch.as_tensor(qd), torch.as_tensor(qdd)).numpy()
    mj = _mj_inverse(load_robot(robot, unmodeled=False), q, qd, qdd)
    assert np.abs(Y @ theta.numpy() - mj).max() < 1e-9 * np.abs(mj).max()
    fc = [model.layout.index(j, "fc") for j in range(model.n_dof)]
    assert bool((theta[fc] == 0).all())  # a joint term the robot does not have is 0
    with pytest.raises(ValueError, match="no viscous"):
        true_parameters(robot, RigidBodyModel.from_mjcf(model_path(robot), friction=()))


@pytest.mark.parametrize("robot", ROBOTS)
def test_true_parameters_with_the_armature_reproduce_mujoco_with_its_armature_on(robot):
    model = RigidBodyModel.from_mjcf(model_path(robot), friction=("viscous", "armature"))
    theta = true_parameters(robot, model, armature=True)
    ia = [model.layout.index(j, "ia") for j in range(model.n_dof)]
    assert bool((theta[ia] > 0).all())  # the shipped robots have armature on every joint
    q, qd, qdd = _states(load_robot(robot), 20, seed=5)
    Y = model.regressor(torch.as_tensor(q), torch.as_tensor(qd), torch.as_tensor(qdd)).numpy()
    mj = _mj_inverse(load_robot(robot, unmodeled={"armature": True}), q, qd, qdd)
    assert np.abs(Y @ theta.numpy() - mj).max() < 1e-9 * np.abs(mj).max()
    # without armature=True the term is 0, and MuJoCo's torque differs by armature * qdd
    plain = true_parameters(robot, model)
    assert bool((plain[ia] == 0).all())
