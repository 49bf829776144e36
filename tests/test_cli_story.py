"""The README's command-line story on a URDF robot the package does not ship (example-robot-data's
UR5), in smoke size: excite -> simulate -> identify -> evaluate, each command's output the next
one's input."""

import importlib.metadata
import json
import warnings

import pytest

import torchjfa
from torchjfa.cli import main
from torchjfa.identification import IdentificationWarning


@pytest.fixture(scope="module")
def ur5():
    try:
        importlib.metadata.distribution("example-robot-data")
        return torchjfa.robots.example_robot_data_path("ur_description/urdf/ur5_robot.urdf")
    except (importlib.metadata.PackageNotFoundError, FileNotFoundError):
        pytest.skip("example-robot-data is not installed")


def test_excite_simulate_identify_evaluate_on_a_urdf_the_package_does_not_ship(ur5, tmp_path):
    traj, log, result = tmp_path / "traj", tmp_path / "log.csv", tmp_path / "result"
    assert main(["excite", ur5, "--out", str(traj), "--duration", "10", "--harmonics", "3",
                 "--starts", "1", "--max-iter", "5", "--polish-iter", "5", "--polish-starts",
                 "1", "--grid", "60", "--no-plots", "--quiet"]) == 0  # fmt: skip
    assert main(["simulate", ur5, "--trajectory", str(traj / "trajectory.npz"), "--n-samples",
                 "15000", "--frictionloss", "0.3", "--out", str(log), "--quiet"]) == 0  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        assert main(["identify", ur5, str(log), "--cutoff", "10", "--out", str(result),
                     "--quiet", "--no-plots"]) == 0  # fmt: skip
    report = json.loads((result / "report.json").read_text())
    assert report["validation"]["identified"]["mean_nmse"] < 0.05
    assert (result / "identified.urdf").is_file() and (result / "identified.xml").is_file()
    assert main(["evaluate", str(result / "model.npz"), "--robot", ur5, "--n-samples", "2000",
                 "--control-seconds", "1"]) == 0  # fmt: skip
