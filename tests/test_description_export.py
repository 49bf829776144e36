"""The identified parameters written back into the robot's description: the report folder's
``identified.xml`` (MJCF) simulates in MuJoCo with the identified inertials and joint terms, and a
URDF gets each joint's ``<dynamics damping friction>``."""

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from _robots import TWO_LINK

import torchjfa
from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import IdentificationWarning
from torchjfa.sim import generate_log


def test_the_report_folder_holds_the_identified_mjcf(tmp_path):
    sim = generate_log("head", n_samples=2520, seed=5, progress=False)
    log = torchjfa.data.JointLog(
        t=sim.t, q=sim.q, qd=sim.qd, tau=sim.tau, joint_names=sim.joint_names
    )
    options = torchjfa.Options(cutoff=15.0, jackknife=0, bias_correction=0, armature="off")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify("head", log, options)
    paths = ident.write(tmp_path, plots=False)
    assert paths["description"].name == "identified.xml"
    assert "identified.xml" in paths["markdown"].read_text()
    # read back: the same inertials (the written file's nominal parameters) and joint terms
    model = ident.model
    back = RigidBodyModel.from_mjcf(str(paths["description"]), friction=model.friction)
    a, _ = model.layout.split(ident.theta)
    b, _ = back.layout.split(back.nominal_theta)
    assert torch.allclose(a, b, rtol=1e-9, atol=1e-12 * float(a.abs().max()))
    mj = mujoco.MjModel.from_xml_path(str(paths["description"]))
    _, terms = model.layout.split(ident.theta)
    fv = terms[:, model.friction.index("viscous")]
    for j, name in enumerate(model.joint_names):
        dof = mj.jnt_dofadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)]
        assert mj.dof_damping[dof] == float(fv[j])


def test_a_urdf_gets_the_joints_viscous_and_coulomb_friction(tmp_path):
    model = RigidBodyModel.from_urdf(TWO_LINK, friction=("viscous", "coulomb", "offset"))
    inertial, terms = model.layout.split(model.nominal_theta)
    terms[:] = torch.tensor([[0.3, 0.1, -0.2], [0.25, 0.05, 0.4]], dtype=torch.float64)
    theta = model.layout.join(inertial, terms)
    path = tmp_path / "arm.urdf"
    model.write_urdf(theta, path)
    joints = {j.get("name"): j for j in ET.parse(path).getroot().findall("joint")}
    for name, (fv, fc) in {"j1": (0.3, 0.1), "j2": (0.25, 0.05)}.items():
        dyn = joints[name].find("dynamics")
        assert float(dyn.get("damping")) == fv and float(dyn.get("friction")) == fc


def test_the_exported_urdf_gives_the_identified_rigid_body_torques_in_pinocchio(tmp_path):
    """Round trip: Pinocchio's inverse dynamics on the written URDF equal the identified
    model's rigid-body torques (``Y theta`` without the joint terms), to 1e-9 relative."""
    pin = pytest.importorskip("pinocchio")
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"), friction=("viscous",))
    g = torch.Generator().manual_seed(1)
    inertial, terms = model.layout.split(model.nominal_theta)
    inertial[:, 0] *= 1.0 + 0.2 * torch.rand(model.n_dof, generator=g, dtype=torch.float64)
    theta = model.layout.join(inertial, terms + 0.3)  # "identified": other masses, friction
    path = tmp_path / "identified.urdf"
    model.write_urdf(theta, path)
    pm = pin.buildModelFromUrdf(str(path))
    data = pm.createData()
    q, qd, qdd = (torch.randn(5, model.n_dof, generator=g, dtype=torch.float64) for _ in range(3))
    rigid = model.layout.join(inertial, torch.zeros_like(terms))
    want = model.regressor(q, qd, qdd) @ rigid
    names = [pm.names[i] for i in range(1, pm.njoints)]
    order = [names.index(j) for j in model.joint_names]
    for k in range(5):
        qq, vv, aa = (
            x[k].numpy()[[model.joint_names.index(n) for n in names]] for x in (q, qd, qdd)
        )
        tau = torch.from_numpy(pin.rnea(pm, data, qq, vv, aa).copy())[order]
        assert torch.allclose(tau, want[k], rtol=0, atol=1e-9 * float(want[k].abs().max()))


def test_a_urdf_robot_is_written_as_mjcf_that_mujoco_simulates_as_identified(tmp_path):
    """MuJoCo's URDF importer makes the MJCF; the identified inertials, armature and viscous
    friction then give MuJoCo's inverse dynamics the model's torques, and the Coulomb terms
    are the joints' friction loss."""
    model = RigidBodyModel.from_urdf(
        torchjfa.robots.path("panda_arm"), friction=("viscous", "coulomb", "armature")
    )
    inertial, terms = model.layout.split(model.nominal_theta)
    inertial = inertial.clone()
    inertial[:, 0] *= 1.2  # other masses than the description's (first moments and inertias
    inertial[:, 1:] *= 1.2  # scale with them: still consistent)
    g = torch.Generator().manual_seed(0)
    terms = 0.1 + torch.rand(terms.shape, generator=g, dtype=torch.float64)
    theta = model.layout.join(inertial, terms)
    model.write_mjcf(theta, tmp_path / "panda.xml")
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "panda.xml"))
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT  # no friction loss, limits
    data = mujoco.MjData(mj)
    without_dry = model.with_joint_terms(("viscous", "armature"))
    keep = [model.friction.index(k) for k in without_dry.friction]
    theta_wet = without_dry.layout.join(inertial, terms[:, keep])
    order = [mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, j) for j in model.joint_names]
    dofs = [int(mj.jnt_dofadr[j]) for j in order]
    for _ in range(5):
        q, qd, qdd = (torch.randn(7, generator=g, dtype=torch.float64) for _ in range(3))
        data.qpos[dofs], data.qvel[dofs], data.qacc[dofs] = q.numpy(), qd.numpy(), qdd.numpy()
        mujoco.mj_inverse(mj, data)
        expected = without_dry.inverse_dynamics(q, qd, qdd, theta_wet)
        got = torch.as_tensor(data.qfrc_inverse[dofs])
        assert torch.allclose(got, expected, rtol=1e-9, atol=1e-9 * float(expected.abs().max()))
    fc = terms[:, model.friction.index("coulomb")]
    for j, dof in enumerate(dofs):
        assert mj.dof_frictionloss[dof] == float(fc[j])


def test_the_public_write_functions_take_keywords(tmp_path):
    from torchjfa.dynamics import write_mjcf, write_urdf

    model = RigidBodyModel.from_urdf(TWO_LINK, friction=("viscous",))
    write_urdf(model=model, theta=model.nominal_theta, path=tmp_path / "a.urdf")
    write_mjcf(model=model, theta=model.nominal_theta, path=tmp_path / "a.xml")
    back = RigidBodyModel.from_urdf(str(tmp_path / "a.urdf"), friction=("viscous",))
    assert torch.allclose(back.nominal_theta, model.nominal_theta, rtol=1e-12, atol=1e-15)
    assert mujoco.MjModel.from_xml_path(str(tmp_path / "a.xml")).njnt == model.n_dof
    with pytest.raises(ValueError, match="theta must have shape"):
        write_urdf(model=model, theta=model.nominal_theta[:3], path=tmp_path / "b.urdf")


def test_an_exported_mjcf_keeps_every_digit_of_the_bodies_placements(tmp_path):
    """The xArm7's joint frames turn by angles whose quaternions have no short decimals: the
    MJCF written from its URDF must place the bodies to float64 precision for MuJoCo's
    inverse dynamics to give the model's torques to 1e-9 (six digits give about 1e-6)."""
    from _robots import erd_path

    path = erd_path("xarm_description/urdf/xarm7.urdf")
    model = RigidBodyModel.from_urdf(path, friction=())
    model.write_mjcf(model.nominal_theta, tmp_path / "xarm7.xml")
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "xarm7.xml"))
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    mj.dof_damping[:] = 0.0  # the description's own damping (10 N m s/rad) stays in the file
    data = mujoco.MjData(mj)
    order = [mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, j) for j in model.joint_names]
    dofs = [int(mj.jnt_dofadr[j]) for j in order]
    g = torch.Generator().manual_seed(1)
    for _ in range(5):
        q, qd, qdd = (torch.randn(model.n_dof, generator=g, dtype=torch.float64) for _ in range(3))
        data.qpos[dofs], data.qvel[dofs], data.qacc[dofs] = q.numpy(), qd.numpy(), qdd.numpy()
        mujoco.mj_inverse(mj, data)
        expected = model.inverse_dynamics(q, qd, qdd, model.nominal_theta)
        got = torch.as_tensor(data.qfrc_inverse[dofs])
        assert torch.allclose(got, expected, rtol=0, atol=1e-9 * float(expected.abs().max()))


def test_an_exported_urdf_finds_its_meshes_outside_ros(tmp_path, monkeypatch):
    """example-robot-data's xArm7 names its meshes package://example-robot-data/...: the
    written URDF names the files themselves, and MuJoCo loads it, meshes and all, from
    another folder."""
    from _robots import erd_path

    path = erd_path("xarm_description/urdf/xarm7.urdf")
    model = RigidBodyModel.from_urdf(path, friction=())
    out = tmp_path / "elsewhere" / "xarm7.urdf"
    out.parent.mkdir()
    model.write_urdf(model.nominal_theta, out)
    names = [m.get("filename") for m in ET.parse(out).getroot().iter("mesh")]
    assert names and all(Path(n).is_absolute() and Path(n).is_file() for n in names)
    monkeypatch.chdir(tmp_path)
    mj = mujoco.MjModel.from_xml_path(str(out))
    assert mj.nmesh > 0 and mj.njnt == model.n_dof


def test_mesh_names_resolve_by_package_path_and_folder(tmp_path, monkeypatch):
    from torchjfa.dynamics._writeback import resolve_mesh

    (tmp_path / "ws" / "my_robot" / "meshes").mkdir(parents=True)
    mesh = tmp_path / "ws" / "my_robot" / "meshes" / "a.stl"
    mesh.write_text("solid a\nendsolid a\n")
    urdf = tmp_path / "ws" / "my_robot" / "urdf" / "r.urdf"
    urdf.parent.mkdir()
    # the package found among the description's own ancestors, and a name relative to it
    assert resolve_mesh("package://my_robot/meshes/a.stl", str(urdf)) == str(mesh.resolve())
    assert resolve_mesh("../meshes/a.stl", str(urdf)) == str(urdf.parent / "../meshes/a.stl")
    # elsewhere, through ROS_PACKAGE_PATH only
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ws"))
    assert resolve_mesh("package://my_robot/meshes/a.stl", None) == str(mesh.resolve())
    assert resolve_mesh("package://other/meshes/a.stl", str(urdf)) is None
    assert resolve_mesh("file://" + str(mesh), None) == str(mesh)


def test_an_exported_mjcf_has_collision_meshes_and_motors_that_replay_the_model(tmp_path):
    """The xArm7 written as MJCF keeps its collision meshes (found outside ROS, by absolute
    paths) and has a torque motor per joint within its effort limits: the model's torques,
    sent through those motors, give MuJoCo's forward dynamics the accelerations they were
    computed for."""
    from _robots import erd_path

    path = erd_path("xarm_description/urdf/xarm7.urdf")
    model = RigidBodyModel.from_urdf(path, friction=("viscous",))
    theta = model.nominal_theta  # no viscous friction: the file's damping is 0
    model.write_mjcf(theta, tmp_path / "elsewhere.xml")
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "elsewhere.xml"))
    assert mj.nmesh > 0 and mj.ngeom >= mj.nmesh
    # every <visual> and <collision> of the URDF (all STL meshes here) is a geom: the visuals
    # in group 1 and in no contact, the collisions colliding
    urdf = ET.parse(path).getroot()
    n_visual, n_collision = (len(urdf.findall(f"link/{tag}")) for tag in ("visual", "collision"))
    touches = (mj.geom_contype != 0) | (mj.geom_conaffinity != 0)
    assert n_visual > 0 and int((~touches & (mj.geom_group == 1)).sum()) == n_visual
    assert int(touches.sum()) == n_collision
    assert mj.nu == model.n_dof and np.all(mj.actuator_gear[:, 0] == 1.0)
    order = [mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, j) for j in model.joint_names]
    assert [int(mj.actuator_trnid[k, 0]) for k in range(mj.nu)] == order
    assert np.all(mj.actuator_ctrlrange[:, 1] > 0)  # the URDF's effort limits
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT  # no contacts or limits
    mj.actuator_ctrllimited[:] = 0  # the torques of random states exceed the motors' limits
    data = mujoco.MjData(mj)
    dofs = [int(mj.jnt_dofadr[j]) for j in order]
    g = torch.Generator().manual_seed(3)
    for _ in range(5):
        q, qd, qdd = (torch.randn(model.n_dof, generator=g, dtype=torch.float64) for _ in range(3))
        data.qpos[dofs], data.qvel[dofs] = q.numpy(), qd.numpy()
        tau = model.inverse_dynamics(q, qd, qdd, theta)
        data.ctrl[:] = tau.numpy()  # actuator k drives joint k (the order asserted above)
        mujoco.mj_forward(mj, data)
        # the mass matrix solve of a 7-joint arm: round-off of 1e-12 of the accelerations
        np.testing.assert_allclose(data.qacc[dofs], qdd.numpy(), rtol=0, atol=1e-9)


def test_a_link_the_description_leaves_without_inertia_is_exported_with_the_identified_one(
    tmp_path,
):
    """MuJoCo refuses a moving body with no mass and inertia; the export gives it the
    identified ones (as a real TX40 description leaves its last link's inertia zero)."""
    text = TWO_LINK.replace(
        '<mass value="0.5"/>\n    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.006" iyz="0" '
        'izz="0.005"/>',
        '<mass value="0"/>\n    <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>',
    )
    assert text != TWO_LINK
    urdf = tmp_path / "massless.urdf"
    urdf.write_text(text)
    model = RigidBodyModel.from_urdf(str(urdf))
    reference = RigidBodyModel.from_urdf(TWO_LINK)
    theta = reference.nominal_theta  # the second link with mass and inertia
    model.write_mjcf(theta, tmp_path / "arm.xml")
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "arm.xml"))
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    data = mujoco.MjData(mj)
    g = torch.Generator().manual_seed(1)
    for _ in range(3):
        q, qd, qdd = (torch.randn(2, generator=g, dtype=torch.float64) for _ in range(3))
        data.qpos[:], data.qvel[:], data.qacc[:] = q.numpy(), qd.numpy(), qdd.numpy()
        mujoco.mj_inverse(mj, data)
        expected = reference.inverse_dynamics(q, qd, qdd, theta)
        got = torch.as_tensor(data.qfrc_inverse)
        assert torch.allclose(got, expected, rtol=1e-9, atol=1e-9 * float(expected.abs().max()))
