"""The floating-base regressor against Pinocchio's free flyer and MuJoCo's mass matrix.

Pinocchio (``computeJointTorqueRegressor``, ``rnea``, ``crba`` on a model built with
``JointModelFreeFlyer``) and MuJoCo (``mj_fullM`` on the URDF compiled with a ``<freejoint>`` on
its root body) are independent implementations; the quadrupeds and humanoids come from
example-robot-data.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import torch
from _robots import PinocchioFreeFlyer, erd_path

from torchjfa.dynamics import FloatingBaseModel, RigidBodyModel
from torchjfa.dynamics._floating import quaternion_matrix
from torchjfa.dynamics._mjcf import strip_urdf_for_mujoco

LEGGED = {
    "solo12": "solo_description/robots/solo12.urdf",
    "go2": "go2_description/urdf/go2.urdf",
    "anymal_c": "anymal_c_simple_description/urdf/anymal.urdf",
    "talos": "talos_data/robots/talos_reduced.urdf",
    "g1": "g1_description/urdf/g1_29dof_rev_1_0.urdf",
}


def _state(n: int, batch: int, seed: int):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(batch, 7 + n))
    q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
    return q, rng.normal(size=(batch, 6 + n)), rng.normal(size=(batch, 6 + n))


@pytest.mark.parametrize("name", list(LEGGED))
def test_free_flyer_regressor_equals_pinocchio(name):
    pin = pytest.importorskip("pinocchio")
    path = erd_path(LEGGED[name])
    model = FloatingBaseModel.from_urdf(path, friction=())
    ref = PinocchioFreeFlyer(pin, path, model)
    np.testing.assert_allclose(
        model.nominal_theta.numpy(), ref.theta()[ref.cols], rtol=0, atol=1e-12
    )
    q, v, a = _state(model.n_dof, 6, seed=1)
    Y = model.regressor(q, v, a).numpy()
    assert Y.shape == (6, 6 + model.n_dof, model.n_params)
    tau = model.inverse_dynamics(q, v, a, model.nominal_theta).numpy()
    M = model.mass_matrix(q).numpy()
    com = model.center_of_mass(q).numpy()
    for b in range(q.shape[0]):
        Y_ref = ref.regressor(q[b], v[b], a[b])
        # two float64 recursions over the same decimal inputs: eps times the ~1e4 operations
        # of a 30-body tree bounds the difference by ~1e-12 of the largest entry
        scale = np.abs(Y_ref).max()
        np.testing.assert_allclose(Y[b], Y_ref, rtol=0, atol=1e-12 * scale)
        tau_ref = ref.rnea(q[b], v[b], a[b])
        np.testing.assert_allclose(tau[b], tau_ref, rtol=0, atol=1e-12 * np.abs(tau_ref).max())
        M_ref = ref.crba(q[b])
        np.testing.assert_allclose(M[b], M_ref, rtol=0, atol=1e-12 * np.abs(M_ref).max())
        com_ref = pin.centerOfMass(ref.pm, ref.pd, ref.state(q[b], v[b], a[b])[0])
        # a sum over the bodies of positions of order 1 m: round-off far below 1e-12 m
        np.testing.assert_allclose(com[b], com_ref, rtol=0, atol=1e-12)


def test_free_flyer_mass_matrix_equals_mujoco():
    mujoco = pytest.importorskip("mujoco")
    path = erd_path(LEGGED["solo12"])
    model = FloatingBaseModel.from_urdf(path, friction=())
    root = strip_urdf_for_mujoco(
        ET.parse(path).getroot(), fusestatic="false", balanceinertia="false"
    )
    spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    base = spec.worldbody.first_body()
    assert base.name == model.base_name
    base.add_freejoint()
    mj = spec.compile()
    q, _, _ = _state(model.n_dof, 4, seed=2)
    M = model.mass_matrix(q).numpy()
    for b in range(q.shape[0]):
        expected = _mujoco_mass_matrix(mujoco, mj, model, q[b], base.id)
        np.testing.assert_allclose(M[b], expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def _mujoco_mass_matrix(mujoco, mj, model, q, base_id: int) -> np.ndarray:
    """MuJoCo's mass matrix of a free-joint model at our state ``q``, in our velocity order
    and convention."""
    data = mujoco.MjData(mj)
    dof = np.array([*range(6), *(mj.jnt_dofadr[mj.joint(n).id] for n in model.joint_names)])
    adr = [mj.jnt_qposadr[mj.joint(n).id] for n in model.joint_names]
    data.qpos[:3] = q[:3]
    data.qpos[3:7] = q[[6, 3, 4, 5]]  # MuJoCo's quaternion is (w, x, y, z)
    data.qpos[adr] = q[7:]
    mujoco.mj_forward(mj, data)
    full = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, full)
    full = full[np.ix_(dof, dof)]
    # MuJoCo's free joint takes the linear velocity in world axes, ours in base axes
    T = np.eye(6 + model.n_dof)
    T[:3, :3] = data.xmat[base_id].reshape(3, 3)
    return T.T @ full @ T


def test_the_written_mjcf_has_a_free_joint_and_mujoco_gives_its_mass_matrix(tmp_path):
    mujoco = pytest.importorskip("mujoco")
    model = FloatingBaseModel.from_urdf(erd_path(LEGGED["go2"]), friction=("viscous",))
    # every body's 10 parameters scaled by its own positive factor: still consistent
    rng = np.random.default_rng(4)
    inertial, terms = model.joints.layout.split(model.nominal_theta[10:])
    scale = torch.as_tensor(rng.uniform(0.7, 1.3, size=(model.n_dof, 1)))
    theta = torch.cat([model.nominal_theta[:10] * 1.2,
                       model.joints.layout.join(inertial * scale, terms + 0.25)])  # fmt: skip
    model.write_mjcf(theta, tmp_path / "go2.xml")
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "go2.xml"))
    assert mj.nq == 7 + model.n_dof and mj.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    base_id = mj.body(model.base_name).id
    assert mj.body_mass.sum() == pytest.approx(float(theta[mass_columns(model)].sum()), rel=1e-12)
    np.testing.assert_allclose(mj.dof_damping[6:], 0.25, rtol=1e-12)
    q, _, _ = _state(model.n_dof, 2, seed=5)
    M = model.mass_matrix(q, theta).numpy()
    for b in range(q.shape[0]):
        expected = _mujoco_mass_matrix(mujoco, mj, model, q[b], base_id)
        # MuJoCo turns each full inertia into principal axes and back: round-off of 1e-15
        np.testing.assert_allclose(M[b], expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    back = FloatingBaseModel.from_mjcf(tmp_path / "go2.xml", friction=("viscous",))
    torch.testing.assert_close(back.nominal_theta[:10], theta[:10], rtol=0, atol=1e-12)


def mass_columns(model) -> list[int]:
    """theta's mass entries: the base's, then each joint body's."""
    inertial, _ = model.joints.layout.split(torch.arange(model.joints.n_params))
    return [0, *(10 + int(i) for i in inertial[:, 0])]


def test_the_joint_rows_of_a_base_at_rest_are_the_fixed_base_regressor():
    """With the base still and level, the joint rows are the fixed-base model's."""
    path = erd_path(LEGGED["solo12"])
    model = FloatingBaseModel.from_urdf(path, friction=("viscous", "coulomb", "offset"))
    fixed = RigidBodyModel.from_urdf(path, friction=("viscous", "coulomb", "offset"))
    q, v, a = _state(model.n_dof, 5, seed=3)
    q[:, 3:7] = (0.0, 0.0, 0.0, 1.0)
    v[:, :6] = 0.0
    a[:, :6] = 0.0
    Y = model.regressor(q, v, a)
    expected = fixed.regressor(q[:, 7:], v[:, 6:], a[:, 6:], compiled=False)
    torch.testing.assert_close(Y[:, 6:, 10:], expected, rtol=0, atol=1e-12)
    assert bool((Y[:, 6:, :10] == 0).all())  # the base body's inertia drives no joint
    assert model.parameter_names[:2] == ("base_link.m", "base_link.mcx")
    assert model.parameter_names[10:] == fixed.parameter_names


def test_base_rows_give_total_mass_and_centre_of_mass_from_statics():
    """At rest, the base's force rows carry the robot's whole weight: the sum of the URDF's
    masses (read here from the file) times gravity in base axes."""
    path = erd_path(LEGGED["go2"])
    model = FloatingBaseModel.from_urdf(path, friction=())
    q, _, _ = _state(model.n_dof, 3, seed=4)
    zeros = np.zeros((3, 6 + model.n_dof))
    wrench = model.inverse_dynamics(q, zeros, zeros, model.nominal_theta).numpy()
    masses = sum(float(m.get("value")) for m in ET.parse(path).getroot().iter("mass"))
    R = quaternion_matrix(torch.as_tensor(q[:, 3:7])).numpy()
    g_base = np.einsum("bji,j->bi", R, [0.0, 0.0, -9.81])
    # the base must push up with the robot's weight: f = -m g in base axes
    np.testing.assert_allclose(wrench[:, :3], -masses * g_base, rtol=1e-12)


def test_bad_floating_base_inputs_are_refused():
    path = erd_path(LEGGED["solo12"])
    model = FloatingBaseModel.from_urdf(path)
    q, v, a = _state(model.n_dof, 2, seed=5)
    with pytest.raises(ValueError, match=r"q must have shape \(\*batch, 19\)"):
        model.regressor(q[:, 1:], v, a)
    with pytest.raises(ValueError, match=r"v must have shape \(\*batch, 18\)"):
        model.regressor(q, v[:, 1:], a[:, 1:])
    q[1, 3:7] = (0.0, 0.0, 0.0, 2.0)
    with pytest.raises(ValueError, match="unit quaternion; sample 1 has norm 2"):
        model.regressor(q, v, a)
    q[1, 3:7] = np.nan
    with pytest.raises(ValueError, match="q"):
        model.regressor(q, v, a)
    with pytest.raises(ValueError, match=r"theta must have shape \(142,\)"):
        model.inverse_dynamics(q[:1], v[:1], a[:1], torch.zeros(3))


def test_floating_regressor_gradients_equal_finite_differences():
    """Autograd's directional derivative of a random weighting of Y against central
    differences (step 1e-6: truncation ~1e-12 and round-off ~1e-10 relative)."""
    path = erd_path(LEGGED["solo12"])
    model = FloatingBaseModel.from_urdf(path, friction=("viscous", "armature"))
    x = [torch.as_tensor(v) for v in _state(model.n_dof, 2, seed=6)]
    gen = torch.Generator().manual_seed(0)
    W = torch.randn(2, 6 + model.n_dof, model.n_params, generator=gen, dtype=torch.float64)

    def f(q, v, a):
        return (model.regressor(q, v, a) * W).sum()

    inputs = [v.clone().requires_grad_() for v in x]
    grads = torch.autograd.grad(f(*inputs), inputs)
    for _ in range(3):
        d = [torch.randn(v.shape, generator=gen, dtype=torch.float64) for v in x]
        d[0][:, 3:7] = 0.0  # keep the quaternion unit: the base orientation stays fixed
        h = 1e-6
        plus = f(*(v + h * e for v, e in zip(x, d, strict=True)))
        minus = f(*(v - h * e for v, e in zip(x, d, strict=True)))
        numeric = float((plus - minus) / (2 * h))
        analytic = float(sum((g * e).sum() for g, e in zip(grads, d, strict=True)))
        assert analytic == pytest.approx(numeric, rel=1e-6, abs=1e-6)
    # and through the orientation: a rotation of the quaternion about a random axis
    q = x[0].clone()
    qv = q.clone().requires_grad_()
    g_q = torch.autograd.grad(f(qv, x[1], x[2]), qv)[0]
    omega = torch.randn(3, generator=gen, dtype=torch.float64)
    dq = torch.zeros_like(q)
    w, xyz = q[:, 6], q[:, 3:6]
    dq[:, 3:6] = 0.5 * (w[:, None] * omega + torch.linalg.cross(xyz, omega.expand_as(xyz)))
    dq[:, 6] = -0.5 * (xyz * omega).sum(-1)
    h = 1e-6
    numeric = float((f(q + h * dq, x[1], x[2]) - f(q - h * dq, x[1], x[2])) / (2 * h))
    assert float((g_q * dq).sum()) == pytest.approx(numeric, rel=1e-6, abs=1e-6)


@pytest.mark.parametrize(
    ("name", "frames"),
    [
        ("go2", ("FL_foot", "RR_foot", "base", "FL_calf")),
        ("talos", ("left_sole_link", "arm_left_7_link")),
    ],
)
def test_frame_jacobians_equal_pinocchio(name, frames):
    pin = pytest.importorskip("pinocchio")
    path = erd_path(LEGGED[name])
    model = FloatingBaseModel.from_urdf(path)
    ref = PinocchioFreeFlyer(pin, path, model)
    q, _, _ = _state(model.n_dof, 3, seed=7)
    J = model.frame_jacobian(q, frames).numpy()
    assert J.shape == (3, len(frames), 6, 6 + model.n_dof)
    torch.testing.assert_close(model.frame_jacobian(q, frames[0]), torch.as_tensor(J[:, 0]))
    for b in range(q.shape[0]):
        for k, expected in enumerate(ref.frame_jacobians(q[b], frames)):
            # products of a few rotations of unit size: round-off of order 1e-15
            np.testing.assert_allclose(J[b, k], expected, rtol=0, atol=1e-12)


def _go2_mjcf(mujoco, path: str, scenery: bool) -> str:
    """Go2's MJCF (MuJoCo's URDF importer) with a free joint on its base, placed and turned
    away from the origin; with ``scenery``, a heavy table beside it."""
    from torchjfa.dynamics._mjcf import _full_precision, mjcf_from_urdf

    spec = mujoco.MjSpec.from_string(mjcf_from_urdf(Path(path).read_text()))
    base = spec.worldbody.first_body()
    base.add_freejoint(name="root")
    base.pos = [0.3, -0.2, 0.45]
    base.quat = [0.9, 0.1, 0.3, -0.2]
    if scenery:
        table = spec.worldbody.add_body(name="table", pos=[2.0, 0.0, 0.5])
        table.add_geom(size=[0.5, 0.5, 0.05], type=mujoco.mjtGeom.mjGEOM_BOX, mass=30.0)
    spec.compile()
    return _full_precision(spec.to_xml(), spec)  # to_xml alone writes 6 digits


def test_an_mjcf_free_joint_gives_the_urdfs_floating_model_and_mujocos_mass_matrix():
    mujoco = pytest.importorskip("mujoco")
    path = erd_path(LEGGED["go2"])
    text = _go2_mjcf(mujoco, path, scenery=True)
    model = FloatingBaseModel.from_mjcf(text)
    urdf = FloatingBaseModel.from_urdf(path)
    assert model.base_name == "base" and model.joint_names == urdf.joint_names
    # the MJCF keeps every digit of the URDF's numbers; MuJoCo's compile turns each inertia
    # into principal axes and back (an eigen-decomposition: round-off of 1e-15 of it)
    scale = float(urdf.nominal_theta.abs().max())
    torch.testing.assert_close(model.nominal_theta, urdf.nominal_theta, rtol=0, atol=1e-12 * scale)
    q, v, a = _state(model.n_dof, 3, seed=8)
    Y_urdf = urdf.regressor(q, v, a)
    torch.testing.assert_close(model.regressor(q, v, a), Y_urdf, rtol=1e-12, atol=1e-12)

    mj = mujoco.MjModel.from_xml_string(_go2_mjcf(mujoco, path, scenery=False))
    M = model.mass_matrix(q).numpy()
    for b in range(q.shape[0]):
        expected = _mujoco_mass_matrix(mujoco, mj, model, q[b], mj.body("base").id)
        np.testing.assert_allclose(M[b], expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_an_mjcf_file_with_a_free_joint_reads_as_its_text(tmp_path):
    mujoco = pytest.importorskip("mujoco")
    path = erd_path(LEGGED["go2"])
    text = _go2_mjcf(mujoco, path, scenery=False)
    (tmp_path / "go2.xml").write_text(text)
    from_file = FloatingBaseModel.from_mjcf(tmp_path / "go2.xml")
    assert from_file.joints.source_path == str(tmp_path / "go2.xml")
    torch.testing.assert_close(
        from_file.nominal_theta, FloatingBaseModel.from_mjcf(text).nominal_theta, rtol=0, atol=0
    )


def test_an_mjcf_without_one_free_joint_is_refused():
    mujoco = pytest.importorskip("mujoco")
    path = erd_path(LEGGED["go2"])
    from torchjfa.dynamics._mjcf import mjcf_from_urdf

    fixed = mjcf_from_urdf(Path(path).read_text())
    with pytest.raises(ValueError, match="exactly one <freejoint>.*found 0"):
        FloatingBaseModel.from_mjcf(fixed)
    spec = mujoco.MjSpec.from_string(_go2_mjcf(mujoco, path, scenery=False))
    box = spec.worldbody.add_body(name="box")
    box.add_freejoint(name="box_free")
    box.add_geom(size=[0.1, 0.1, 0.1], type=mujoco.mjtGeom.mjGEOM_BOX)
    with pytest.raises(ValueError, match=r"found 2: \['root', 'box_free'\]"):
        FloatingBaseModel.from_mjcf(spec.to_xml())
    with pytest.raises(ValueError, match="FloatingBaseModel.from_mjcf"):
        RigidBodyModel.from_mjcf(_go2_mjcf(mujoco, path, scenery=False))


def test_a_floating_descriptions_stated_damping_enters_its_description_theta():
    mujoco = pytest.importorskip("mujoco")
    from torchjfa.dynamics._mjcf import mjcf_from_urdf

    path = erd_path(LEGGED["go2"])
    spec = mujoco.MjSpec.from_string(mjcf_from_urdf(Path(path).read_text()))
    spec.worldbody.first_body().add_freejoint(name="root")
    for k, joint in enumerate(j for j in spec.joints if j.name != "root"):
        joint.damping = [0.1 * (k + 1), 0.0, 0.0]  # MuJoCo: the damping, then a polynomial
    spec.compile()
    model = FloatingBaseModel.from_mjcf(spec.to_xml(), friction=("viscous", "coulomb"))
    theta = model.description_theta
    torch.testing.assert_close(theta[:10], model.nominal_theta[:10])
    _, terms = model.joints.layout.split(theta[10:])
    names = [j.name for j in spec.joints if j.name != "root"]
    expected = torch.tensor([0.1 * (names.index(j) + 1) for j in model.joint_names],
                            dtype=torch.float64)  # fmt: skip
    torch.testing.assert_close(terms[:, 0], expected)
    assert bool((terms[:, 1] == 0).all())
