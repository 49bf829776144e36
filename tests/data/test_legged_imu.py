"""An IMU fixed to a legged robot's base: its gyroscope and accelerometer (MuJoCo's sensors in
a simulated Go2) give the base's angular velocity and accelerations, turned from the IMU's
frame and place to the base's; with sensor noise, far closer to the truth than the pose
differentiated twice. Read, written and refused as the other legged columns."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.data import IMU_COLUMNS, LogError, prepare_legged, read_legged_log
from torchjfa.dynamics import FloatingBaseModel
from torchjfa.sim import simulate_legged

#: samples dropped at each end (the filter's start and end), at 200 Hz
EDGE = 400


@pytest.fixture(scope="module")
def go2():
    """A Go2 with its IMU on the radar link (turned 165 degrees about y and 29 cm forward of
    the base origin, so that the turn and the lever arm both matter)."""
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, GO2_FEET, GO2_STANCE, seconds=6.0, rate=200.0, perturb=0.2,
                          seed=1, imu="radar")  # fmt: skip
    model = FloatingBaseModel.from_urdf(path, friction=())
    return {"path": path, "log": log, "pose": model.base_frame("radar")}


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _errors(prepared, truth) -> dict[str, float]:
    keep = slice(EDGE, -EDGE)
    return {
        "w": _rms(prepared.v[keep, 3:6] - truth.v[keep, 3:6]),
        "a_lin": _rms(prepared.a[keep, :3] - truth.a[keep, :3]),
        "dw": _rms(prepared.a[keep, 3:6] - truth.a[keep, 3:6]),
    }


def test_the_imu_gives_the_simulators_base_motion(go2):
    log = go2["log"]
    assert set(log.imu) == {"w", "a"}
    scale = {"w": _rms(log.v[:, 3:6]), "a_lin": _rms(log.a[:, :3]), "dw": _rms(log.a[:, 3:6])}
    bare = replace(log, v=None, a=None)
    got = _errors(prepare_legged(bare, cutoff_hz=10.0, imu_pose=go2["pose"]), log)
    # the gyroscope is the angular velocity (turned into base axes): exact but for the
    # filter's pass-band ripple on a motion below 1 Hz
    assert got["w"] < 1e-4 * scale["w"]
    # the accelerations: the 10 Hz filter's distortion and one differentiation (angular)
    assert got["a_lin"] < 0.02 * scale["a_lin"] and got["dw"] < 0.05 * scale["dw"]
    # without the lever arm and the turn, the accelerometer says something else
    wrong = _errors(prepare_legged(bare, cutoff_hz=10.0), log)
    assert wrong["a_lin"] > 10 * got["a_lin"]


def test_with_noise_the_imu_beats_the_pose_differentiated_twice(go2):
    log, noisy = go2["log"], go2["log"].noisy(seed=2)
    with_imu = _errors(prepare_legged(noisy, cutoff_hz=10.0, imu_pose=go2["pose"]), log)
    pose_only = _errors(prepare_legged(replace(noisy, imu={}), cutoff_hz=10.0), log)
    for key in ("w", "a_lin", "dw"):
        assert with_imu[key] < 0.2 * pose_only[key], (key, with_imu, pose_only)


def test_imu_columns_round_trip_and_contradictions_are_named(go2, tmp_path):
    path = tmp_path / "go2.csv"
    go2["log"].save(path)
    back = read_legged_log(path)
    for key in ("w", "a"):
        np.testing.assert_array_equal(back.imu[key], go2["log"].imu[key])
    header = path.read_text().splitlines()[0].split(",")
    assert all(c in header for names in IMU_COLUMNS.values() for c in names)
    for dropped, match in (
        (["imu_wx", "imu_wy", "imu_wz"], "accelerometer .* without the gyroscope"),
        (["imu_az"], "accelerometer: 2 of 3 columns"),
    ):
        keep = [i for i, c in enumerate(header) if c not in dropped]
        rows = [line.split(",") for line in path.read_text().splitlines()]
        cut = tmp_path / "cut.csv"
        cut.write_text("\n".join(",".join(r[i] for i in keep) for r in rows) + "\n")
        with pytest.raises(LogError, match=match):
            read_legged_log(cut)
