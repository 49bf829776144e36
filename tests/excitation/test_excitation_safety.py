"""Safe excitation by default: velocity and acceleration margins, the mounting plane and
self-collision, checked on a dense grid by code other than the optimiser's (URDF numbers read
with ElementTree, `RigidBodyModel.forward_kinematics` of every frame, MuJoCo's mesh vertices
and `mj_geomDistance` on the description's collision meshes)."""

import math
import sysconfig
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import torch

import torchjfa
from torchjfa.cli import main
from torchjfa.dynamics import RigidBodyModel
from torchjfa.excitation import (
    FourierTrajectory,
    check_limits,
    limits_from_model,
    optimize_excitation,
)

ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
UR5 = ERD / "ur_description/urdf/ur5_robot.urdf"
SMALL = {"duration": 4.0, "base_frequency": 0.25, "harmonics": 3, "n_grid": 60, "n_starts": 1,
         "max_iter": 8, "polish_iter": 8}  # fmt: skip
RATE = 50.0
SMOKE = ["--duration", "4", "--base-freq", "0.25", "--harmonics", "3", "--starts", "1",
         "--max-iter", "8", "--polish-iter", "8", "--grid", "60", "--rate", "50", "--quiet",
         "--no-plots"]  # fmt: skip


def _ur5():
    if not UR5.is_file():
        pytest.skip("example-robot-data is not installed")
    return RigidBodyModel.from_urdf(UR5)


def _urdf_limits(path, names):
    """(velocity, effort) per joint, read from the URDF's <limit> with ElementTree."""
    joints = {j.get("name"): j.find("limit") for j in ET.parse(path).getroot().findall("joint")}
    return (np.array([float(joints[n].get("velocity")) for n in names]),
            np.array([float(joints[n].get("effort")) for n in names]))  # fmt: skip


def _dense(traj, hz=1000.0):
    t = np.arange(int(traj.period * hz) + 1) / hz
    return t, traj.to_sinusoid().evaluate_numpy(t)


def _lowest_frames(model, q):
    """Per frame whose height changes with the joints: its lowest origin z over ``q``, m."""
    z = model.forward_kinematics(torch.as_tensor(q), model.frame_names)[..., 2, 3].numpy()
    rng = np.random.default_rng(1)
    qs = rng.uniform(-math.pi, math.pi, (64, model.n_dof))
    zs = model.forward_kinematics(torch.as_tensor(qs), model.frame_names)[..., 2, 3].numpy()
    moves = zs.max(0) - zs.min(0) > 1e-9
    return {f: float(z[:, i].min()) for i, f in enumerate(model.frame_names) if moves[i]}


def _mujoco_ur5():
    """MuJoCo's model of the UR5 with its collision meshes (paths resolved here)."""
    mujoco = pytest.importorskip("mujoco")
    root = ET.parse(UR5).getroot()
    for link in root.findall("link"):
        for vis in link.findall("visual"):
            link.remove(vis)
        for mesh in link.iter("mesh"):
            rel = mesh.get("filename").replace("package://example-robot-data/robots/", "")
            mesh.set("filename", str(ERD / rel))
    ET.SubElement(ET.SubElement(root, "mujoco"), "compiler", strippath="false")
    mj = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    return mujoco, mj, mujoco.MjData(mj)


def _mesh_checks(q, posture):
    """(lowest mesh vertex z of each body a joint moves off the vertical, smallest distance
    between non-adjacent bodies' meshes that are apart at the posture), MuJoCo, m."""
    mujoco, mj, d = _mujoco_ur5()
    adr = [mj.jnt_qposadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in
           ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
            "wrist_2_joint", "wrist_3_joint")]  # fmt: skip
    geoms = [g for g in range(mj.ngeom) if mj.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    body = mj.geom_bodyid
    pairs = [(a, b) for i, a in enumerate(geoms) for b in geoms[i + 1:]
             if body[a] != body[b] and mj.body_parentid[body[b]] != body[a]
             and mj.body_parentid[body[a]] != body[b]]  # fmt: skip

    def at(qi):
        d.qpos[adr] = qi
        mujoco.mj_kinematics(mj, d)

    at(posture)
    pairs = [p for p in pairs if mujoco.mj_geomDistance(mj, d, *p, 1.0, None) > 0]
    low, near = {}, math.inf
    for qi in q:
        at(qi)
        for g in geoms:
            if body[g] >= 2:  # upper arm onwards: what the shoulder lift moves
                m = mj.geom_dataid[g]
                v = mj.mesh_vert[mj.mesh_vertadr[m] : mj.mesh_vertadr[m] + mj.mesh_vertnum[m]]
                z = (d.geom_xpos[g] + v @ d.geom_xmat[g].reshape(3, 3).T)[:, 2].min()
                low[g] = min(low.get(g, math.inf), float(z))
        for p in pairs:
            near = min(near, mujoco.mj_geomDistance(mj, d, *p, 1.0, None))
    return low, near


def test_default_limits_keep_margins_and_add_an_acceleration_limit():
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    vel, eff = _urdf_limits(torchjfa.robots.path("panda_arm"), model.joint_names)
    limits = limits_from_model(model)
    np.testing.assert_allclose(limits.velocity, 0.85 * vel, rtol=1e-12)
    np.testing.assert_allclose(limits.acceleration, 0.85 * vel / 0.5, rtol=1e-12)
    np.testing.assert_allclose(limits.torque, eff, rtol=1e-12)
    assert limits.floor == 0.0 and limits.self_collision and limits.clearance == 0.02
    # what the user gives is used as given; the default acceleration follows the velocity
    user = limits_from_model(model, velocity=1.0, velocity_margin=0.3)
    np.testing.assert_allclose(user.velocity, 1.0)
    np.testing.assert_allclose(user.acceleration, 2.0)
    user = limits_from_model(model, velocity_margin=0.0, acceleration=7.0, floor=None)
    np.testing.assert_allclose(user.velocity, vel)
    np.testing.assert_allclose(user.acceleration, 7.0)
    assert user.floor is None
    with pytest.raises(ValueError, match="velocity_margin"):
        limits_from_model(model, velocity_margin=1.0)


@pytest.fixture(scope="module")
def ur5_default():
    model = _ur5()
    limits = limits_from_model(model)
    return model, limits, optimize_excitation(model, limits, rate=RATE, seed=0, **SMALL)


def test_ur5_default_design_stays_above_the_floor_and_inside_the_margins(ur5_default):
    model, limits, res = ur5_default
    traj = res.trajectory
    t, (q, qd, qdd) = _dense(traj)
    vel, _ = _urdf_limits(UR5, model.joint_names)
    assert np.all(np.abs(qd) <= 0.85 * vel + 1e-9)
    assert np.all(np.abs(qdd) <= 0.85 * vel / 0.5 + 1e-9)
    # the middle of the limits (all zeros) has the wrist below the base's plane: moved up
    assert res.posture_moved
    z0 = model.forward_kinematics(torch.zeros(6, dtype=torch.float64), "wrist_3_link")[2, 3]
    assert float(z0) < 0.0
    # every frame that the joints move up and down stays 2 cm above the plane
    low = _lowest_frames(model, q)
    assert set(low) >= {"forearm_link", "wrist_1_link", "wrist_3_link", "tool0"}
    assert min(low.values()) >= 0.02 - 1e-9
    # the collision meshes too (their vertices), and no two non-adjacent links touch
    mesh_low, near = _mesh_checks(q[::4], traj.posture)
    assert min(mesh_low.values()) >= 0.02 - 1e-6
    assert near > 0.0
    # the report's margins are in physical units and agree with the samples
    phys = res.physical_margins
    assert phys["velocity"]["unit"] == "rad/s" and phys["floor"]["unit"] == "m"
    peak = np.abs(qd).max(0)
    j = int(np.argmin(limits.velocity - peak))
    assert phys["velocity"]["margin"] == pytest.approx(limits.velocity[j] - peak[j], abs=1e-3)
    assert phys["floor"]["margin"] >= 0.0 and phys["collision"]["margin"] >= 0.0
    assert res.margins["floor"] >= 0.0 and res.margins["collision"] >= 0.0


def test_no_floor_relaxes_the_plane_and_a_sweep_through_it_is_refused():
    model = _ur5()
    # the motion: the shoulder lift sweeping through the mounting plane
    a = np.zeros((6, 3))
    a[1] = [2.0, -1.0, -1.0]  # rad/s: +-3.2 rad about the arm pointing up
    traj = FourierTrajectory(0.1, np.zeros(6) + [0, -1.57, 0, 0, 0, 0], a, np.zeros((6, 3)),
                             model.joint_names)  # fmt: skip
    q = _dense(traj)[1][0]
    assert min(_lowest_frames(model, q).values()) < -0.3  # it does go below z = 0
    fast = {"velocity": 10.0, "acceleration": 50.0}
    with pytest.raises(ValueError, match=r"too close to the floor at z = 0 m"):
        check_limits(model, traj, limits_from_model(model, **fast), rate=RATE)
    free = limits_from_model(model, floor=None, self_collision=False, **fast)
    assert min(check_limits(model, traj, free, rate=RATE).values()) >= 0.0
    # without the floor the default posture (the middle of the limits) is kept as it is
    res = optimize_excitation(model, free, rate=RATE, seed=0, **SMALL)
    assert not res.posture_moved
    np.testing.assert_allclose(res.trajectory.posture, 0.0, atol=1e-12)
    assert "floor" not in res.margins


def test_violations_end_the_command_with_one_line_and_status_2(tmp_path, capsys):
    ur5 = str(_ur5().source_path)
    # a posture with the wrist below the plane
    code = main(["excite", ur5, "--out", str(tmp_path / "a"), "--posture", "0,0,0,0,0,0",
                 *SMOKE])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "too low" in err and "--no-floor" in err and "Traceback" not in err
    # a floor above the robot's reach: no posture clears it
    code = main(["excite", ur5, "--out", str(tmp_path / "b"), "--floor", "2", *SMOKE])
    err = capsys.readouterr().err
    assert code == 2 and "no posture near the middle" in err and err.count("\n") == 1


def test_cli_report_gives_margins_in_physical_units(tmp_path, capsys):
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    out = tmp_path / "panda"
    assert main(["excite", "panda_arm", "--out", str(out), *SMOKE]) == 0
    report = (out / "report.md").read_text()
    for text in ("rad/s", "rad/s^2", "| floor |", "| collision |", "capsules of radius 0.05 m"):
        assert text in report
    import json

    s = json.loads((out / "report.json").read_text())
    assert s["physical_margins"]["optimised"]["floor"]["margin"] >= 0.0
    with np.load(out / "trajectory.npz") as z:
        q = z["q"]
    low = _lowest_frames(model, q)
    assert min(low.values()) >= 0.02 - 1e-9  # frame origins at the output rate
    # --no-floor and --no-self-collision drop both from the report
    out2 = tmp_path / "free"
    assert main(["excite", "panda_arm", "--out", str(out2), "--no-floor", "--no-self-collision",
                 *SMOKE]) == 0  # fmt: skip
    s2 = json.loads((out2 / "report.json").read_text())
    assert "floor" not in s2["margins"]["optimised"] and not s2["geometry"]
