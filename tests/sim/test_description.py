"""Any description compiled for simulation: MuJoCo's model has the description's rigid body
(torchjfa's own inverse dynamics agree to rounding), motors, the chosen joint effects, and
clear errors for what cannot be simulated."""

import mujoco
import numpy as np
import pytest
import torch

from torchjfa.dynamics import RigidBodyModel
from torchjfa.robots import example_robot_data_path, path
from torchjfa.sim import (
    EFFECTS,
    DescriptionError,
    load_description,
    random_trajectory,
)
from torchjfa.sim._robots import joint_ranges


def _erd(relative):
    try:
        return example_robot_data_path(relative)
    except (ModuleNotFoundError, FileNotFoundError) as exc:
        pytest.skip(str(exc))


def _inverse_agrees(desc, rbm, n_states=8, seed=0):
    """The largest ``|mj_inverse - RigidBodyModel.inverse_dynamics|`` over random states inside
    the joint ranges (a joint limit would add its constraint force), relative to the largest
    torque."""
    rng = np.random.default_rng(seed)
    ranges = joint_ranges(desc.model)
    q = rng.uniform(ranges[:, 0], ranges[:, 1], (n_states, desc.n_dof))
    qd, qdd = rng.normal(size=(2, n_states, desc.n_dof))
    data = mujoco.MjData(desc.model)
    tau_mj = np.empty_like(q)
    for k in range(n_states):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(desc.model, data)
        tau_mj[k] = data.qfrc_inverse
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    tau = rbm.inverse_dynamics(as_t(q), as_t(qd), as_t(qdd), rbm.nominal_theta).numpy()
    return float(np.abs(tau - tau_mj).max() / np.abs(tau).max())


def test_a_urdf_compiles_with_its_inertials_limits_and_a_motor_per_joint():
    desc = load_description("panda_arm")
    m = desc.model
    assert desc.format == "urdf" and desc.name == "panda_arm" and desc.path == path("panda_arm")
    assert desc.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    assert m.njnt == m.nv == m.nu == 7 and np.all(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert np.array_equal(m.actuator_trnid[:, 0], np.arange(7))
    assert np.all(m.actuator_gear[:, 0] == 1.0) and not np.any(m.actuator_ctrllimited)
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert not np.any(m.jnt_actfrclimited)  # the effort limit is recorded, not enforced
    np.testing.assert_allclose(m.jnt_range[:, 1], [2.8973, 1.7628, 2.8973, -0.0698, 2.8973,
                                                   3.7525, 2.8973])  # fmt: skip
    np.testing.assert_array_equal(desc.effort_limit, [87.0] * 4 + [12.0] * 3)
    np.testing.assert_array_equal(desc.velocity_limit, [2.175] * 4 + [2.61] * 3)
    # the description's own <dynamics damping="0.003" friction="0"> is read but not simulated
    np.testing.assert_array_equal(desc.own_effects["damping"], [0.003] * 7)
    assert all(not v.any() for v in desc.effects.values())
    # MuJoCo's rigid body is the description's, as torchjfa reads it (the hand lumped into link 7)
    rbm = RigidBodyModel.from_urdf(path("panda_arm"))
    assert _inverse_agrees(desc, rbm) < 1e-12


def test_an_mjcf_with_slide_joints_and_a_urdf_with_meshes_compile_as_described():
    desc = load_description("branched_tree")  # MJCF: hinges and slides, rotated inertias
    assert desc.format == "mjcf" and mujoco.mjtJoint.mjJNT_SLIDE in set(desc.model.jnt_type)
    assert np.all(np.isinf(desc.effort_limit)) and np.all(np.isinf(desc.velocity_limit))
    assert _inverse_agrees(desc, RigidBodyModel.from_mjcf(path("branched_tree"))) < 1e-12
    ur5 = _erd("ur_description/urdf/ur5_robot.urdf")  # package:// meshes that cannot be found
    desc = load_description(ur5)
    assert desc.n_dof == 6 and desc.joint_names[0] == "shoulder_pan_joint"
    assert _inverse_agrees(desc, RigidBodyModel.from_urdf(ur5)) < 1e-12
    np.testing.assert_array_equal(desc.velocity_limit, [3.15] * 3 + [3.2] * 3)


def test_joint_effects_are_off_the_descriptions_own_or_set():
    own = load_description("panda_arm", own_effects=True)
    np.testing.assert_array_equal(own.model.dof_damping, [0.003] * 7)
    arm = [0.1, 0.1, 0.1, 0.1, 0.05, 0.05, 0.05]
    desc = load_description(
        "panda_arm", effects={"armature": arm, "frictionloss": 0.3}, own_effects=True
    )
    np.testing.assert_array_equal(desc.model.dof_armature, arm)
    np.testing.assert_array_equal(desc.model.dof_frictionloss, [0.3] * 7)
    np.testing.assert_array_equal(desc.model.dof_damping, [0.003] * 7)  # kept
    assert set(desc.effects) == set(EFFECTS)
    with pytest.raises(DescriptionError, match="damping must be a float or have shape"):
        load_description("panda_arm", effects={"damping": [1.0, 2.0]})
    with pytest.raises(DescriptionError, match="finite and non-negative"):
        load_description("panda_arm", effects={"armature": -1.0})
    with pytest.raises(DescriptionError, match="unknown effects"):
        load_description("panda_arm", effects={"backlash": 1.0})


_LINK = (
    '<link name="{}"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" '
    'ixy="0" ixz="0" iyz="0"/></inertial></link>'
)
_JOINT = (
    '<joint name="{}" type="{}"><parent link="{}"/><child link="{}"/><axis xyz="0 0 1"/>'
    '<limit lower="-1" upper="1" effort="10" velocity="1"/>{}</joint>'
)


def _urdf(tmp_path, *, kind="revolute", extra="", links=("a", "b", "c")):
    body = "".join(_LINK.format(n) for n in links)
    body += _JOINT.format("j1", kind, "a", "b", "")
    body += _JOINT.format("j2", "revolute", "b", "c", extra)
    p = tmp_path / "robot.urdf"
    p.write_text(f'<robot name="r">{body}</robot>')
    return p


@pytest.mark.parametrize(
    "case, match",
    [
        ("missing", "no robot file"),
        ("malformed", "not well-formed XML"),
        ("floating", "floating and planar joints are not supported"),
        ("repeated", "joint 'j2' is defined twice"),
        ("mimic", "equality constraints"),
        ("massless", "mass and inertia of moving bodies"),
        ("not-mjcf", "MuJoCo cannot read"),
    ],
)
def test_what_cannot_be_simulated_raises_a_clear_error(case, match, tmp_path):
    if case == "missing":
        robot = tmp_path / "nowhere.urdf"
    elif case == "malformed":
        robot = tmp_path / "bad.urdf"
        robot.write_text("<robot name='r'><link name='a'>")
    elif case == "floating":
        robot = _urdf(tmp_path, kind="floating")
    elif case == "mimic":
        robot = _urdf(tmp_path, extra='<mimic joint="j1"/>')
    elif case == "repeated":  # MuJoCo's importer would drop the second name
        robot = _urdf(tmp_path)
        robot.write_text(robot.read_text().replace('joint name="j1"', 'joint name="j2"'))
    elif case == "massless":
        robot = _urdf(tmp_path)
        robot.write_text(robot.read_text().replace(_LINK.format("c"), '<link name="c"/>'))
    else:
        robot = tmp_path / "robot.xml"
        robot.write_text("<mujoco><worldbody><body><joint/></body></mujoco>")
    with pytest.raises(DescriptionError, match=match):
        load_description(robot)


def test_a_random_excitation_keeps_within_the_velocity_limits():
    model = load_description("panda_arm").model
    free = random_trajectory(model, seed=3)
    omega = 2 * np.pi * free.base_frequency * free.harmonic
    bound = (np.abs(free.amplitude) * omega).sum(axis=1)
    limit = np.full(7, np.inf)
    limit[[1, 4]] = 0.5 * bound[[1, 4]]  # two joints too fast; the others have no limit
    slow = random_trajectory(model, seed=3, velocity_limit=limit)
    np.testing.assert_allclose((np.abs(slow.amplitude) * omega).sum(axis=1)[[1, 4]],
                               limit[[1, 4]], rtol=1e-12)  # fmt: skip
    keep = [0, 2, 3, 5, 6]
    np.testing.assert_array_equal(slow.amplitude[keep], free.amplitude[keep])
    np.testing.assert_array_equal(slow.phase, free.phase)  # the same draw
    t = np.linspace(0, slow.period, 4001)
    assert np.all(np.abs(slow.evaluate_numpy(t)[1]) <= limit + 1e-12)
    with pytest.raises(ValueError, match="velocity_limit must be positive"):
        random_trajectory(model, velocity_limit=0.0)
