"""Legged logs with motor currents ``i_<joint>`` and drive gains (N m/A): read as the torques
they give, identified as the same log with torques, and every contradiction named."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.data import LogError, read_legged_log
from torchjfa.identification import Options, identify_legged
from torchjfa.sim import simulate_legged


def _read(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def _write(path, header, rows) -> None:
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows([header, *rows])


@pytest.fixture(scope="module")
def go2(tmp_path_factory):
    """A short noise-free Go2 log as CSV with torques, and the same with currents."""
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, GO2_FEET, GO2_STANCE, seconds=6.0, rate=100.0, perturb=0.2,
                          seed=3)  # fmt: skip
    folder = tmp_path_factory.mktemp("go2_currents")
    torques, currents = folder / "torques.csv", folder / "currents.csv"
    log.save(torques)
    joints = list(log.joint_names)
    gains = {j: 0.5 + 0.1 * k for k, j in enumerate(joints)}  # N m/A, a different one each
    header, rows = _read(torques)
    for j in joints:
        k = header.index(f"tau_{j}")
        header[k] = f"i_{j}"
        for row in rows:
            row[k] = repr(float(row[k]) / gains[j])
    _write(currents, header, rows)
    return {"path": path, "log": log, "torques": torques, "currents": currents, "gains": gains}


def test_currents_times_the_gains_are_the_torques(go2):
    a = read_legged_log(go2["torques"])
    b = read_legged_log(go2["currents"], drive_gains=go2["gains"])
    np.testing.assert_allclose(b.tau, a.tau, rtol=1e-12, atol=1e-12 * np.abs(a.tau).max())
    assert b.info["drive_gains"] == go2["gains"]


def test_identify_from_currents_is_identify_from_torques(go2):
    options = Options(cutoff=10.0, description_prior=1.0)
    a = identify_legged(go2["path"], go2["torques"], options)
    gains = [go2["gains"][j] for j in a.model.joint_names]  # in the model's joint order
    b = identify_legged(go2["path"], go2["currents"], options.replace(drive_gains=gains))
    # the same torques to round-off (a product and a quotient): the same weighted least-squares
    # estimate, to round-off amplified by the regression's conditioning (the consistency
    # projection afterwards stops at its own tolerance)
    scale = float(a.theta_hat.abs().max())
    assert torch.allclose(b.theta_hat, a.theta_hat, rtol=1e-6, atol=1e-8 * scale)
    assert b.total_mass == pytest.approx(a.total_mass, rel=1e-3)
    assert b.cutoff_hz == a.cutoff_hz and b.rows == a.rows
    assert b.settings["drive_gains"].startswith("motor currents times FL_hip_joint 0.5")
    assert a.settings["drive_gains"].startswith("none")


def test_contradictions_are_named_in_one_error(go2, tmp_path):
    with pytest.raises(LogError, match="motor currents .* without drive gains"):
        read_legged_log(go2["currents"])
    with pytest.raises(LogError, match="drive gains without motor-current columns"):
        read_legged_log(go2["torques"], drive_gains=go2["gains"])
    some = dict(list(go2["gains"].items())[:3])
    with pytest.raises(LogError, match="no drive gains for the joints"):
        read_legged_log(go2["currents"], drive_gains=some)
    with pytest.raises(LogError, match="not joints of the log"):
        read_legged_log(go2["currents"], drive_gains={**go2["gains"], "elbow": 1.0})
    with pytest.raises(LogError, match="finite and nonzero"):
        read_legged_log(go2["currents"], drive_gains={**go2["gains"], "FL_hip_joint": 0.0})
    both = tmp_path / "both.csv"
    header, rows = _read(go2["currents"])
    _write(both, [*header, "tau_FL_hip_joint"], [[*row, "0.0"] for row in rows])
    with pytest.raises(LogError, match="joint torques"):
        read_legged_log(both, drive_gains=go2["gains"])


def test_a_wrong_number_of_gains_is_named(go2):
    with pytest.raises(LogError, match="3 drive gains for the 12 joints"):
        identify_legged(go2["path"], go2["currents"], Options(drive_gains=[1.0, 2.0, 3.0]))
