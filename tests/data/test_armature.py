"""`armature_helps`: the motor's reflected inertia is added where the log shows it, and left
out where the robot has none (the simulated head, with MuJoCo's armature as large as each
joint's own inertia, as on geared arms, and without it).

On the head as shipped (armature 0.2 of each joint's inertia) the term is left out: the first
joint's armature is the same column as its link's inertia about the axis, and the rest is
within the held-out blocks' standard error."""

import pytest

from torchjfa.data import JointLog, armature_helps
from torchjfa.identification import load_model
from torchjfa.sim import generate_log, load_robot

TERMS = ("viscous", "coulomb", "offset")


def _log(armature: bool) -> JointLog:
    geared = [5.0 * a for a in load_robot("head").dof_armature]  # 5 x 0.2 of M_jj: M_jj
    effects = {"armature": geared if armature else False, "frictionloss": True}
    sim = generate_log("head", n_samples=5040, seed=4, unmodeled=effects, progress=False)
    return JointLog(t=sim.t, q=sim.q, qd=sim.qd, tau=sim.tau, joint_names=sim.joint_names)


@pytest.fixture(scope="module")
def model():
    return load_model("head", TERMS).with_coulomb_velocity(0.05)


def test_the_armature_is_added_where_the_robot_has_rotor_inertia(model):
    helps, how = armature_helps(model, _log(True).reorder(model.joint_names), 15.0)
    assert helps and how.endswith("armature added")


def test_the_armature_is_left_out_where_the_robot_has_none(model):
    helps, how = armature_helps(model, _log(False).reorder(model.joint_names), 15.0)
    assert not helps and "left out" in how


def test_a_model_with_the_armature_keeps_it(model):
    given = model.with_joint_terms((*TERMS, "armature"))
    assert given.n_params == model.n_params + model.n_dof
    assert armature_helps(given, _log(False).reorder(model.joint_names), 15.0) == (True, "given")
