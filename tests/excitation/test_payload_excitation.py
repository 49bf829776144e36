"""An excitation for a payload's parameters alone (``torchjfa excite --payload LINK``)."""

import json

import pytest
import torch

from torchjfa.cli import main
from torchjfa.dynamics import RigidBodyModel
from torchjfa.excitation import limits_from_model
from torchjfa.excitation._information import payload_directions, trajectory_information

SMOKE = ["--duration", "2", "--base-freq", "0.5", "--harmonics", "3", "--starts", "1",
         "--max-iter", "5", "--polish-iter", "5", "--grid", "40", "--quiet"]  # fmt: skip

PLANAR = """<?xml version="1.0"?>
<robot name="planar">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0.2 0 0"/><mass value="1.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0 0"/><mass value="0.5"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.006" iyz="0" izz="0.005"/></inertial></link>
  <link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" velocity="2" effort="50"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.4 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" velocity="2" effort="50"/></joint>
  <joint name="flange" type="fixed"><parent link="l2"/><child link="tool"/>
    <origin xyz="0.25 0 0.05"/></joint>
</robot>
"""


def test_a_planar_arm_reveals_four_of_its_payloads_parameters():
    """An arm turning about y sees a payload's mass, its first moments along x and z and its
    inertia about y, and nothing else: the directions span exactly those coordinates."""
    from torchjfa.identification._payload import payload_regressor

    model = RigidBodyModel.from_urdf(PLANAR, friction=())
    limits = limits_from_model(model, floor=None, self_collision=False)
    V = payload_directions(model, limits, "tool", generator=torch.Generator().manual_seed(0))
    assert V.shape == (model.n_params, 4)
    j, A = payload_regressor(model, "tool")
    cols = model.layout.split(torch.arange(model.n_params))[0][j]
    B = torch.linalg.solve(A, V[cols])  # the directions in the payload's coordinates
    seen = B.norm(dim=1) > 1e-9  # m, hx, hy, hz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz
    assert seen.tolist() == [True, True, False, True, False, False, True, False, False, False]
    with pytest.raises(ValueError, match="no frame"):
        payload_directions(model, limits, "nosuch")


def test_excite_for_a_payload_writes_its_design_and_beats_the_robots_on_it(tmp_path, capsys):
    """On the Panda's flange, the payload design's condition number of the payload's
    information is lower than that of the robot's design (the same settings and seed)."""
    from torchjfa.excitation import FourierTrajectory
    from torchjfa.identification import load_model

    out = tmp_path / "payload"
    args = ["excite", "panda_arm", *SMOKE]
    assert main([*args, "--payload", "panda_link8", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["payload"] == "panda_link8"
    assert report["identifiable_directions"] == 10
    assert main([*args, "--out", str(tmp_path / "robot")]) == 0
    model = load_model("panda_arm")
    limits = limits_from_model(model)
    V = payload_directions(model, limits, "panda_link8", generator=torch.Generator().manual_seed(0))
    cond = {
        name: trajectory_information(
            model, FourierTrajectory.load(tmp_path / name / "trajectory.npz"), V, n_grid=400
        )["condition_number"]
        for name in ("payload", "robot")
    }
    assert cond["payload"] < cond["robot"], cond
    capsys.readouterr()
    assert main([*args, "--payload", "nosuch", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "no frame 'nosuch'" in err and err.count("\n") == 1
