"""The floating-base flow with an IMU: the base's motion from the gyroscope and the
accelerometer (in the frame ``imu_frame`` names) finds the total mass from noisy sensors where
the pose differentiated twice does not, and a frame that cannot carry the IMU is refused."""

from __future__ import annotations

from dataclasses import replace

import pytest
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.data import LogError
from torchjfa.identification import IdentificationWarning, Options, identify_legged
from torchjfa.sim import simulate_legged


@pytest.fixture(scope="module")
def go2():
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, GO2_FEET, GO2_STANCE, seconds=8.0, rate=200.0, perturb=0.2,
                          seed=1, imu="imu")  # fmt: skip
    truth = float(log.theta.reshape(-1, 10)[:, 0].sum())
    return {"path": path, "noisy": log.noisy(seed=2), "mass": truth}


def test_the_imu_gives_the_total_mass_that_the_noisy_pose_does_not(go2):
    options = Options(cutoff=10.0)
    with_imu = identify_legged(go2["path"], go2["noisy"], options.replace(imu_frame="imu"))
    pose_only = identify_legged(go2["path"], replace(go2["noisy"], imu={}), options)
    assert with_imu.settings["imu"].startswith("gyroscope and accelerometer in frame imu")
    assert pose_only.settings["imu"].startswith("none")
    err_imu = abs(with_imu.total_mass / go2["mass"] - 1)
    err_pose = abs(pose_only.total_mass / go2["mass"] - 1)
    # the base rows weigh the contact forces against the bodies' accelerations: noise in
    # those accelerations biases the mass down (errors in variables); the IMU's are 30x
    # less noisy than the pose's differentiated twice
    assert err_imu < 0.005 and err_imu < 0.25 * err_pose, (err_imu, err_pose)


def test_a_frame_that_cannot_carry_the_imu_is_refused(go2):
    with pytest.raises(LogError, match="moves with joint 'FL_calf_joint'"):
        identify_legged(go2["path"], go2["noisy"], Options(cutoff=10.0, imu_frame="FL_foot"))
    with pytest.raises(LogError, match="no IMU columns"):
        identify_legged(go2["path"], replace(go2["noisy"], imu={}),
                        Options(cutoff=10.0, imu_frame="imu"))  # fmt: skip


def test_simulate_with_an_imu_then_identify_on_the_command_line(go2, tmp_path, capsys):
    import json

    from _robots import GO2_STANCE

    from torchjfa.cli import main

    log = tmp_path / "go2.csv"
    stance = ",".join(f"{j}={v}" for j, v in GO2_STANCE.items())
    rc = main(["simulate", go2["path"], "--feet", ",".join(GO2_FEET), "--stance", stance,
               "--seconds", "6", "--rate", "100", "--imu", "imu", "--out", str(log),
               "--quiet"])  # fmt: skip
    assert rc == 0 and "--imu-frame imu" in capsys.readouterr().out
    assert {"imu_wx", "imu_az"} <= set(log.read_text().splitlines()[0].split(","))
    rc = main(["identify", go2["path"], str(log), "--imu-frame", "imu", "--cutoff", "10",
               "--out", str(tmp_path / "r"), "--quiet", "--no-plots"])  # fmt: skip
    assert rc == 0
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["settings"]["imu"].startswith("gyroscope and accelerometer in frame imu")
    rc = main(["identify", go2["path"], str(log), "--imu-frame", "FL_foot", "--cutoff", "10",
               "--out", str(tmp_path / "bad"), "--quiet", "--no-plots"])  # fmt: skip
    assert rc == 2 and "an IMU must be fixed to the base" in capsys.readouterr().err


def test_an_imu_without_its_frame_is_taken_at_the_base_and_said_so(go2):
    with pytest.warns(IdentificationWarning, match="taken to sit at the base frame"):
        ident = identify_legged(go2["path"], go2["noisy"], Options(cutoff=10.0))
    assert ident.settings["imu"].endswith("in frame base: the base's angular motion and linear "
                                          "acceleration")  # fmt: skip
    assert any("taken to sit at the base frame 'base'" in w and "--imu-frame" in w
               for w in ident.warnings)  # fmt: skip
