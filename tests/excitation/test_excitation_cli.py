"""torchjfa excite -> simulate --trajectory -> identify, in smoke size, and bad input."""

import json

import numpy as np
import pytest

from torchjfa.cli import main
from torchjfa.data import read_log
from torchjfa.excitation import FourierTrajectory

SMOKE = ["--duration", "2", "--base-freq", "0.5", "--harmonics", "3", "--starts", "1",
         "--max-iter", "5", "--polish-iter", "5", "--grid", "40", "--quiet"]  # fmt: skip


@pytest.fixture(scope="module")
def traj_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("traj")
    assert main(["excite", "head", "--out", str(out), *SMOKE]) == 0
    return out


def test_excite_writes_the_trajectory_report_and_plots(traj_dir):
    for name in ("report.md", "coefficients.json"):
        assert (traj_dir / name).stat().st_size > 0
    for name in ("trajectory.png", "singular_values.png"):
        assert (traj_dir / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = json.loads((traj_dir / "report.json").read_text())
    assert min(report["margins"]["optimised"].values()) >= 0.0
    with np.load(traj_dir / "trajectory.npz") as z:
        t, q, qd, qdd = z["t"], z["q"], z["qd"], z["qdd"]
        assert float(z["rate"]) == 420.0  # the head's control rate
    assert t.shape == (840,) and q.shape == qd.shape == qdd.shape == (840, 7)
    # the coefficients in the same file give the tabulated motion
    traj = FourierTrajectory.load(traj_dir / "trajectory.npz")
    for mine, tab in zip(traj.evaluate_numpy(t), (q, qd, qdd), strict=True):
        np.testing.assert_allclose(tab, mine, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q[0], traj.posture, atol=1e-12)  # starts at rest at q0
    np.testing.assert_allclose(qd[0], 0.0, atol=1e-12)
    csv = np.loadtxt(traj_dir / "trajectory.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(csv[:, 1:8], q, rtol=1e-12, atol=1e-15)


def test_simulate_tracks_it_and_identify_reads_the_log(traj_dir, tmp_path, capsys):
    log_path = tmp_path / "log.csv"
    code = main(["simulate", "head", "--trajectory", str(traj_dir / "trajectory.npz"),
                 "--out", str(log_path), "--n-samples", "4200", "--quiet"])  # fmt: skip
    assert code == 0
    log = read_log(log_path)
    traj = FourierTrajectory.load(traj_dir / "trajectory.npz")
    perm = [traj.joint_names.index(j) for j in log.joint_names]
    q_ref = traj.evaluate_numpy(log.t.numpy())[0][:, perm]
    # computed-torque tracking (8 Hz bandwidth) of a <= 1.5 Hz motion plus 1e-3 rad sensor noise
    assert float(np.abs(log.q.numpy() - q_ref).max()) < 0.02
    code = main(["identify", "head", str(log_path), "--estimator", "ols", "--out",
                 str(tmp_path / "result"), "--quiet", "--no-plots", "--jackknife", "0",
                 "--bias-correction", "0"])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "held-out torque nMSE" in out.out


def test_bad_input_ends_with_one_line_and_status_2(traj_dir, tmp_path, capsys):
    code = main(["simulate", "arm", "--trajectory", str(traj_dir / "trajectory.npz"),
                 "--out", str(tmp_path / "x.csv"), "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "are not the simulated arm's" in err and err.count("\n") == 1
    code = main(["excite", "head", "--out", str(tmp_path / "t"), "--torque-limit", "1,2", *SMOKE])
    err = capsys.readouterr().err
    assert code == 2 and "--torque-limit takes 1 or 7 numbers" in err
    code = main(["excite", "panda_arm", "--out", str(tmp_path / "t"), "--torque-limit", "0.001",
                 *SMOKE])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "violates" in err and "|torque|" in err and err.count("\n") == 1
    code = main(["excite", "head", "--out", str(tmp_path / "t"), *SMOKE, "--polish-starts", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "polish_starts must be a positive int" in err and err.count("\n") == 1
