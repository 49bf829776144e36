"""The batched regressor against MuJoCo's inverse dynamics and against autograd identities."""

from __future__ import annotations

import shutil

import mujoco
import numpy as np
import pytest
import torch
from dyn_robots import (
    ROBOTS,
    SMALL_URDF,
    mujoco_inverse,
    mujoco_mass_matrix,
    mujoco_model,
    random_state,
)

from torchjfa.dynamics import RigidBodyModel


def _model(name: str, **kw) -> RigidBodyModel:
    kind, source = ROBOTS[name]
    return (RigidBodyModel.from_urdf if kind == "urdf" else RigidBodyModel.from_mjcf)(source, **kw)


def _mj(name: str, gravity=None) -> mujoco.MjModel:
    kind, source = ROBOTS[name]
    return mujoco_model(kind, source, gravity)


@pytest.mark.parametrize("name", list(ROBOTS))
def test_body_inertials_equal_mujocos(name):
    """MuJoCo's compiled body inertials, lumped into the joint bodies, equal the model's."""
    model, m = _model(name), _mj(name)
    assert m.nv == model.n_dof
    assert [m.joint(j).name for j in range(m.njnt)] == list(model.joint_names)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)  # q = 0: world poses of every body
    theta = model.nominal_theta
    inertial, _ = model.layout.split(theta)
    for k in range(model.n_dof):
        body = m.jnt_bodyid[k]
        R_b, p_b = d.xmat[body].reshape(3, 3), d.xpos[body]
        # every MuJoCo body rigidly attached to this joint's body: its subtree minus moving bodies
        members = [body]
        for b in range(body + 1, m.nbody):
            if m.body_parentid[b] in members and m.body_jntnum[b] == 0:
                members.append(b)
        mass = sum(m.body_mass[b] for b in members)
        com_w = sum(m.body_mass[b] * d.xipos[b] for b in members) / mass
        inertia_w = np.zeros((3, 3))
        for b in members:
            Ri = d.ximat[b].reshape(3, 3)
            r = d.xipos[b] - com_w
            inertia_w += Ri @ np.diag(m.body_inertia[b]) @ Ri.T
            inertia_w += m.body_mass[b] * (r @ r * np.eye(3) - np.outer(r, r))
        mine = model.inertials(theta)[k]
        np.testing.assert_allclose(float(mine.mass), mass, rtol=1e-12)
        np.testing.assert_allclose(mine.com.numpy(), R_b.T @ (com_w - p_b), atol=1e-12)
        np.testing.assert_allclose(mine.inertia.numpy(), R_b.T @ inertia_w @ R_b, atol=1e-10)
        assert float(inertial[k, 0]) == pytest.approx(mass, rel=1e-12)


@pytest.mark.parametrize("name", list(ROBOTS))
@pytest.mark.parametrize("batch", [(), (7,), (3, 4)])
def test_regressor_times_nominal_equals_mj_inverse(name, batch):
    model, m = _model(name), _mj(name)
    q, qd, qdd = random_state(model.n_dof, batch, seed=len(batch) + 11)
    Y = model.regressor(q, qd, qdd)
    assert Y.shape == (*batch, model.n_dof, model.n_params)
    assert Y.dtype == torch.float64
    tau = Y @ model.nominal_theta
    flat = [v.reshape(-1, model.n_dof).numpy() for v in (q, qd, qdd)]
    expected = mujoco_inverse(m, *flat).reshape(*batch, model.n_dof)
    scale = max(1.0, float(np.abs(expected).max()))
    np.testing.assert_allclose(tau.numpy(), expected, rtol=1e-9, atol=1e-9 * scale)
    # the friction column of each joint is its velocity (viscous) and nothing else
    for j in range(model.n_dof):
        col = model.layout.index(j, "fv")
        np.testing.assert_array_equal(Y[..., j, col].numpy(), qd[..., j].numpy())
        others = [k for k in range(model.n_dof) if k != j]
        assert torch.all(Y[..., others, col] == 0)


@pytest.mark.parametrize("name", ["panda", "branched_tree"])
def test_other_gravity_matches_mujoco(name):
    g = (0.7, -1.2, -3.0)
    model, m = _model(name, gravity=g), _mj(name, gravity=g)
    torch.testing.assert_close(model.gravity, torch.tensor(g, dtype=torch.float64))
    q, qd, qdd = random_state(model.n_dof, (5,), seed=3)
    tau = model.regressor(q, qd, qdd) @ model.nominal_theta
    expected = mujoco_inverse(m, q.numpy(), qd.numpy(), qdd.numpy())
    np.testing.assert_allclose(tau.numpy(), expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


@pytest.mark.parametrize("name", list(ROBOTS))
def test_inertia_matrix_is_symmetric_and_equals_mj_fullM(name):
    model, m = _model(name, gravity=(0.0, 0.0, 0.0)), _mj(name)
    n = model.n_dof
    q = random_state(n, (), seed=5)[0]
    eye = torch.eye(n, dtype=torch.float64)
    M = model.regressor(q.expand(n, n), torch.zeros(n, n, dtype=torch.float64), eye)
    M = (M @ model.nominal_theta).T  # column k is the response to qdd = e_k
    torch.testing.assert_close(M, M.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(M.numpy(), mujoco_mass_matrix(m, q.numpy()), rtol=1e-9, atol=1e-12)
    assert bool((torch.linalg.eigvalsh(M) > 0).all())


def _link_inertials_from_xml(text: str) -> dict[str, tuple[float, np.ndarray]]:
    """Mass and centre of mass of every URDF link, read with ElementTree (independently)."""
    import xml.etree.ElementTree as ET

    out = {}
    for link in ET.fromstring(text).findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        origin = inertial.find("origin")
        xyz = (
            [0.0] * 3 if origin is None else [float(v) for v in origin.get("xyz", "0 0 0").split()]
        )
        out[link.get("name")] = (float(inertial.find("mass").get("value")), np.array(xyz))
    return out


@pytest.mark.parametrize("name", ["panda", "small_urdf"])
def test_gravity_term_is_gradient_of_potential_from_pk_fk(name):
    """g(q) = Y(q, 0, 0) theta equals dV/dq with V = -sum m g . c from pytorch-kinematics FK."""
    model = _model(name)
    text = model.source_xml
    links = _link_inertials_from_xml(text)
    chain = model.chain.to(dtype=torch.float64)
    gvec = model.gravity
    q = random_state(model.n_dof, (4,), seed=9)[0].requires_grad_(True)
    poses = chain.forward_kinematics(q)
    V = 0.0
    for link, (mass, com) in links.items():
        c_world = poses[link].transform_points(torch.as_tensor(com)[None])[:, 0]  # (4, 3)
        V = V - mass * (c_world @ gvec)
    (dV,) = torch.autograd.grad(V.sum(), q)
    zeros = torch.zeros_like(q)
    g_term = model.regressor(q.detach(), zeros, zeros) @ model.nominal_theta
    # pytorch-kinematics keeps its joint offsets in float32: agreement to ~1e-6 relative
    torch.testing.assert_close(g_term, dV, rtol=1e-5, atol=1e-5 * float(dV.abs().max()))
    assert float(dV.abs().max()) > 0.1


def test_float32_in_float32_out_and_close_to_float64():
    model = _model("panda")
    q, qd, qdd = random_state(model.n_dof, (6,), seed=1)
    Y32 = model.regressor(q.float(), qd.float(), qdd.float())
    assert Y32.dtype == torch.float32
    Y64 = model.regressor(q, qd, qdd)
    torch.testing.assert_close(Y32.double(), Y64, rtol=1e-4, atol=1e-4 * float(Y64.abs().max()))
    # numpy / list input is read as float64
    assert model.regressor(q.numpy(), qd.numpy(), qdd.tolist()).dtype == torch.float64


def test_gradients_match_finite_differences():
    model = _model("small_urdf")
    q, qd, qdd = (v.requires_grad_(True) for v in random_state(model.n_dof, (2,), seed=4))
    theta = model.nominal_theta
    assert torch.autograd.gradcheck(
        lambda a, b, c: model.regressor(a, b, c) @ theta, (q, qd, qdd), eps=1e-6, atol=1e-7
    )


def test_chunked_and_one_pass_agree():
    model = _model("branched_tree")
    q, qd, qdd = random_state(model.n_dof, (37,), seed=2)
    full = model.regressor(q, qd, qdd, chunk_size=5)
    one = model.regressor(q, qd, qdd, chunk_size=1000)
    torch.testing.assert_close(full, one, rtol=0, atol=0)


def test_coulomb_and_offset_columns():
    model = RigidBodyModel.from_urdf(SMALL_URDF, friction=("offset", "viscous", "coulomb"))
    assert model.friction == ("viscous", "coulomb", "offset")
    assert model.n_params == model.n_dof * 13
    q, qd, qdd = random_state(model.n_dof, (3,), seed=8)
    Y = model.regressor(q, qd, qdd)
    for j in range(model.n_dof):
        assert torch.equal(Y[:, j, model.layout.index(j, "fc")], torch.sign(qd[:, j]))
        assert torch.equal(Y[:, j, model.layout.index(j, "fo")], torch.ones(3, dtype=torch.float64))
    # the inertial columns do not depend on the friction terms chosen
    plain = RigidBodyModel.from_urdf(SMALL_URDF).regressor(q, qd, qdd)
    inert = model.layout.split(Y)[0]
    torch.testing.assert_close(inert, plain.reshape(3, model.n_dof, model.n_dof, 11)[..., :10])


@pytest.mark.parametrize("name", list(ROBOTS))
def test_autograd_path_equals_fast_path(name):
    # inputs that require grad take the differentiable path; the others the buffered fast path
    model = _model(name)
    q, qd, qdd = random_state(model.n_dof, (6,), seed=11)
    fast = model.regressor(q, qd, qdd)
    slow = model.regressor(q.clone().requires_grad_(True), qd, qdd)
    assert slow.requires_grad and not fast.requires_grad
    torch.testing.assert_close(slow.detach(), fast, rtol=1e-12, atol=1e-12)


def test_out_buffer_is_filled_and_bad_buffers_raise():
    model = _model("branched_tree")
    q, qd, qdd = random_state(model.n_dof, (4, 3), seed=12)
    expected = model.regressor(q, qd, qdd)
    out = torch.full_like(expected, float("nan"))
    result = model.regressor(q, qd, qdd, out=out)
    assert result.data_ptr() == out.data_ptr()
    torch.testing.assert_close(out, expected, rtol=0, atol=0)
    with pytest.raises(ValueError):
        model.regressor(q, qd, qdd, out=torch.empty(3, *expected.shape[1:], dtype=expected.dtype))
    with pytest.raises((ValueError, TypeError)):
        model.regressor(q, qd, qdd, out=torch.empty_like(expected, dtype=torch.float32))
    with pytest.raises(ValueError):
        model.regressor(
            q,
            qd,
            qdd,
            out=torch.empty_like(expected).transpose(-1, -2).contiguous().transpose(-1, -2),
        )


@pytest.mark.parametrize("name", list(ROBOTS))
def test_armature_and_damping_terms_equal_mj_inverse(name):
    # MuJoCo's armature adds a_j qdd_j and its damping b_j qd_j to joint j's inverse dynamics:
    # theta's "ia" and "fv" entries, in the torch autograd, torch fast and compiled paths
    model = _model(name, friction=("viscous", "armature"))
    assert model.friction == ("viscous", "armature") and model.n_params == model.n_dof * 12
    m = _mj(name)
    rng = np.random.default_rng(4)
    armature, damping = rng.uniform(0.01, 0.2, model.n_dof), rng.uniform(0.1, 2.0, model.n_dof)
    m.dof_armature[:] = armature
    m.dof_damping[:] = damping
    m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_DAMPER)
    theta = model.nominal_theta.clone()
    for j in range(model.n_dof):
        theta[model.layout.index(j, "ia")] = float(armature[j])
        theta[model.layout.index(j, "fv")] = float(damping[j])
    q, qd, qdd = random_state(model.n_dof, (9,), seed=21)
    expected = mujoco_inverse(m, q.numpy(), qd.numpy(), qdd.numpy())
    scale = max(1.0, float(np.abs(expected).max()))
    paths = {
        "torch": model.regressor(q, qd, qdd, compiled=False),
        "autograd": model.regressor(q.clone().requires_grad_(True), qd, qdd).detach(),
    }
    if shutil.which("g++") or shutil.which("c++") or shutil.which("clang++"):
        paths["compiled"] = model.regressor(q, qd, qdd, compiled=True)
    for path, Y in paths.items():
        np.testing.assert_allclose(
            (Y @ theta).numpy(), expected, rtol=1e-9, atol=1e-9 * scale, err_msg=path
        )
        for j in range(model.n_dof):  # the armature column is joint j's acceleration alone
            col = model.layout.index(j, "ia")
            np.testing.assert_array_equal(Y[:, j, col].numpy(), qdd[:, j].numpy())
            assert torch.all(Y[:, [k for k in range(model.n_dof) if k != j], col] == 0)
