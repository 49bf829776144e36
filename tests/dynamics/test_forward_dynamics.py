"""Forward dynamics, the mass matrix and rollouts from theta, against MuJoCo (``mj_fullM``,
``mj_forward``'s ``qacc``, its ``RK4`` and ``Euler`` integrators), against the inverse dynamics
they invert, against finite differences, and against their own convergence order."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from dyn_robots import ROBOTS, random_state

from torchjfa.dynamics import (
    InverseDynamics,
    RigidBodyModel,
    bias_forces,
    forward_dynamics,
    mass_matrix,
    rollout,
)
from torchjfa.sim import load_robot, model_path, true_parameters

EPS64 = float(torch.finfo(torch.float64).eps)
ALL_TERMS = ("viscous", "coulomb", "offset", "armature")


def _model(name: str, **kw) -> RigidBodyModel:
    kind, source = ROBOTS[name]
    return (RigidBodyModel.from_urdf if kind == "urdf" else RigidBodyModel.from_mjcf)(source, **kw)


def _with_joint_terms(model: RigidBodyModel, seed: int) -> torch.Tensor:
    """The nominal inertials with random viscous, Coulomb and armature terms in [0, 0.5) and a
    random offset in [-0.25, 0.25) (those of the layout)."""
    g = torch.Generator().manual_seed(seed)
    inertial, _ = model.layout.split(model.nominal_theta)
    terms = torch.rand(model.n_dof, model.layout.n_friction, generator=g, dtype=torch.float64)
    if "offset" in model.friction:
        terms[:, model.friction.index("offset")] -= 0.5
    return model.layout.join(inertial, terms * 0.5)


@pytest.mark.parametrize("name", ["branched_tree", "small_urdf", "panda"])
def test_inverse_dynamics_of_the_accelerations_gives_the_torques_back(name):
    model = _model(name, friction=ALL_TERMS)
    idyn = InverseDynamics(model, _with_joint_terms(model, seed=1))
    q, qd, tau = random_state(model.n_dof, (2, 3), seed=2)
    qdd = idyn.forward_dynamics(q, qd, tau)
    assert qdd.shape == (2, 3, model.n_dof) and qdd.dtype == torch.float64
    back = idyn(q, qd, qdd)
    # M qdd = tau - h by a backward-stable LU solve: the residual is a few n eps |M| |qdd|
    # (plus eps |h| from forming M and h); 1e3 eps covers n <= 9 with a wide margin
    M = idyn.mass_matrix(q)
    scale = M.abs().amax((-1, -2)) * qdd.abs().amax(-1) + tau.abs().amax(-1)
    err = (back - tau).abs().amax(-1)
    assert bool((err <= 1e3 * EPS64 * scale).all()), (err / scale).max()
    assert float(err.max()) < 1e-10


@pytest.mark.parametrize("name", ["branched_tree", "small_urdf"])
def test_the_mass_matrix_is_the_torque_per_acceleration(name):
    model = _model(name, friction=ALL_TERMS)
    theta = _with_joint_terms(model, seed=3)
    q, qd, qdd = random_state(model.n_dof, (4,), seed=4)
    M = mass_matrix(model, q, theta)
    assert M.shape == (4, model.n_dof, model.n_dof)
    torch.testing.assert_close(M, M.transpose(-1, -2), rtol=0, atol=0)
    assert bool((torch.linalg.eigvalsh(M)[:, 0] > 0).all())  # consistent theta: M > 0
    # tau is affine in qdd with slope M, intercept h
    h = bias_forces(model, q, qd, theta)
    tau = model.inverse_dynamics(q, qd, qdd, theta)
    expected = (M @ qdd[..., None])[..., 0] + h
    torch.testing.assert_close(tau, expected, rtol=1e-12, atol=1e-12 * float(tau.abs().max()))
    # the armature adds ia to the diagonal of M, and nothing else
    bare = theta.clone()
    for j in model.joint_names:
        bare[model.layout.index(j, "ia")] = 0.0
    ia = theta[[model.layout.index(j, "ia") for j in model.joint_names]]
    diff = M - mass_matrix(model, q, bare)
    torch.testing.assert_close(diff, torch.diag(ia).expand_as(diff), rtol=0, atol=1e-13)


def _mujoco_robot(robot: str, **effects):
    """The shipped robot with the given effects, its joint limits off (constraints disabled),
    our model of it with viscous and armature terms, their true values, and the permutation from
    MuJoCo's joint order to ours."""
    m = load_robot(robot, unmodeled=effects)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    model = RigidBodyModel.from_mjcf(model_path(robot), friction=("viscous", "armature"))
    theta = true_parameters(robot, model, armature=True)
    ia = [model.layout.index(j, "ia") for j in model.joint_names]
    fv = [model.layout.index(j, "fv") for j in model.joint_names]
    names = [m.joint(i).name for i in range(m.njnt)]
    perm = [names.index(j) for j in model.joint_names]
    theta[ia] = torch.as_tensor(m.dof_armature[perm])
    theta[fv] = torch.as_tensor(m.dof_damping[perm])
    return m, model, theta, perm


@pytest.mark.parametrize("robot", ["head", "arm"])
def test_mass_matrix_and_accelerations_equal_mujoco(robot):
    m, model, theta, perm = _mujoco_robot(robot, damping=True, armature=True)
    assert float(theta[model.layout.index(0, "ia")]) > 0  # the armature is really on
    d = mujoco.MjData(m)
    g = np.random.default_rng(5)
    for _ in range(4):
        d.qpos[:] = g.uniform(-1.2, 1.2, m.nq)
        d.qvel[:] = g.normal(size=m.nv)
        d.ctrl[:] = g.normal(size=m.nu)  # gear-1 motors: ctrl is the joint torque
        mujoco.mj_forward(m, d)
        M_mj = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M_mj)
        M_mj, qacc = M_mj[np.ix_(perm, perm)], d.qacc[perm]
        q, qd, tau = (torch.as_tensor(v[perm]) for v in (d.qpos, d.qvel, d.ctrl))
        M = mass_matrix(model, q, theta).numpy()
        # both sum the same ~n^2 products per entry: rounding of a few eps |M|
        np.testing.assert_allclose(M, M_mj, rtol=0, atol=100 * EPS64 * np.abs(M_mj).max())
        # solving amplifies relative rounding by at most cond(M)
        acc = forward_dynamics(model, q, qd, tau, theta).numpy()
        tol = 100 * EPS64 * np.linalg.cond(M_mj) * np.abs(qacc).max()
        np.testing.assert_allclose(acc, qacc, rtol=0, atol=tol)


def _mujoco_rollout(m, perm, q0, qd0, ctrl):
    """MuJoCo's own integration, ``ctrl (T, nu)`` in our joint order; states ``(T + 1, nv)``."""
    inv = np.argsort(perm)
    d = mujoco.MjData(m)
    d.qpos[:] = q0[inv]
    d.qvel[:] = qd0[inv]
    qs, qds = [d.qpos[perm].copy()], [d.qvel[perm].copy()]
    for u in ctrl:
        d.ctrl[:] = u[inv]
        mujoco.mj_step(m, d)
        qs.append(d.qpos[perm].copy())
        qds.append(d.qvel[perm].copy())
    return np.array(qs), np.array(qds)


@pytest.mark.parametrize(
    ("method", "integrator", "damping"),
    [
        ("rk4", mujoco.mjtIntegrator.mjINT_RK4, True),
        # MuJoCo's Euler treats damping implicitly: compare it without damping
        ("semi-implicit", mujoco.mjtIntegrator.mjINT_EULER, False),
    ],
)
def test_rollout_follows_mujoco_integration(method, integrator, damping):
    m, model, theta, perm = _mujoco_robot("head", damping=damping, armature=True)
    m.opt.integrator = integrator
    dt, steps = float(m.opt.timestep), 60
    g = np.random.default_rng(6)
    q0, qd0 = g.uniform(-0.5, 0.5, m.nq), g.normal(size=m.nv)
    ctrl = g.normal(scale=0.3, size=(steps, m.nu))
    q_mj, qd_mj = _mujoco_rollout(m, perm, q0, qd0, ctrl)
    idyn = InverseDynamics(model, theta)
    q, qd = rollout(
        idyn, torch.tensor(q0), torch.tensor(qd0), torch.tensor(ctrl), dt, method=method
    )
    assert q.shape == qd.shape == (steps + 1, model.n_dof)
    # the same scheme on the same accelerations: each step adds dt times their rounding,
    # cond(M) eps |qdd| ~ 1e3 * 2.2e-16 * 2e3 rad/s^2 (the eyes' accelerations), so 60 steps of
    # 1.2 ms add up to ~4e-11 rad/s; 1e-9 leaves a factor 25 for the flow's amplification, and
    # q integrates that error over 0.07 s
    np.testing.assert_allclose(qd.numpy(), qd_mj, rtol=0, atol=1e-9)
    np.testing.assert_allclose(q.numpy(), q_mj, rtol=0, atol=1e-11)
    assert np.abs(q_mj[-1] - q_mj[0]).max() > 1e-3  # it did move


@pytest.mark.parametrize(("method", "order"), [("rk4", 4), ("semi-implicit", 1)])
def test_rollout_converges_at_the_order_of_its_method(method, order):
    model = _model("branched_tree", friction=("viscous",))
    idyn = InverseDynamics(model)
    q0, qd0, _ = random_state(model.n_dof, (2,), seed=7)
    horizon, steps = 0.04, 16
    u = torch.randn(model.n_dof, dtype=torch.float64, generator=torch.Generator().manual_seed(8))

    def final(k):  # the state at `horizon` with k steps, constant torque
        tau = u.expand(k, 2, model.n_dof)
        q, qd = rollout(idyn, q0, qd0, tau, horizon / k, method=method)
        return torch.cat([q[-1], qd[-1]], -1)

    ref = final(64 * steps)
    e1 = float((final(steps) - ref).abs().max())
    e2 = float((final(2 * steps) - ref).abs().max())
    # in the asymptotic range (2.5 ms steps; 16 steps to 10 ms show orders 3.9 and 1.1),
    # halving the step divides the error by 2^order; the reference's own error is 1/32 of
    # e2's (first order) or ~1e-6 of it (fourth order)
    observed = np.log2(e1 / e2)
    assert order - 0.3 < observed < order + 0.3, observed


def test_gradients_match_finite_differences():
    model = _model("small_urdf", friction=("viscous", "armature"))
    theta = _with_joint_terms(model, seed=9)
    q, qd, tau = random_state(model.n_dof, (2,), seed=10)
    inputs = tuple(v.clone().requires_grad_(True) for v in (q, qd, tau, theta))
    assert torch.autograd.gradcheck(
        lambda *a: forward_dynamics(model, *a), inputs, eps=1e-6, atol=1e-6, rtol=1e-5
    )

    def final_state(theta, tau_seq):
        def accel(a, b, c):
            return forward_dynamics(model, a, b, c, theta)

        qs, qds = rollout(accel, q, qd, tau_seq, 0.01, method="rk4")
        return torch.cat([qs[-1], qds[-1]], -1)

    tau_seq = torch.randn(3, 2, model.n_dof, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(final_state, (inputs[3], tau_seq), eps=1e-6, atol=1e-6)


def test_dtype_device_and_bad_inputs():
    model = _model("branched_tree")
    idyn = InverseDynamics(model)
    q, qd, tau = random_state(model.n_dof, (3,), seed=11, dtype=torch.float32)
    qdd = idyn.forward_dynamics(q, qd, tau)
    assert qdd.dtype == torch.float32 and qdd.device == q.device
    ref = idyn.forward_dynamics(q.double(), qd.double(), tau.double())
    torch.testing.assert_close(qdd.double(), ref, rtol=1e-3, atol=1e-3)
    with pytest.raises(ValueError, match="tau must have the same shape as q"):
        idyn.forward_dynamics(q, qd, tau[:2])
    with pytest.raises(ValueError, match="NaN"):
        idyn.mass_matrix(torch.full_like(q, float("nan")))
    with pytest.raises(ValueError, match="theta must have shape"):
        mass_matrix(model, q, torch.zeros(3))
    with pytest.raises(ValueError, match="method"):
        rollout(idyn, q, qd, tau[None], 0.01, method="euler")
    with pytest.raises(ValueError, match="dt"):
        rollout(idyn, q, qd, tau[None], 0.0)
    with pytest.raises(ValueError, match=r"tau \(T, \*batch, n_dof\)"):
        rollout(idyn, q, qd, tau, 0.01)
    with pytest.raises(TypeError, match="forward_dynamics"):
        rollout(object(), q, qd, tau[None], 0.01)
