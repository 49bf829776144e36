"""``torchjfa simulate`` and ``torchjfa evaluate --robot`` on any description: the logged torques
are the description's inverse dynamics (torchjfa's own), the joint effects asked for show up in
them, the log identifies, and bad input ends with one line and status 2."""

import json
from pathlib import Path

import numpy as np
import torch

from torchjfa.cli import main
from torchjfa.data import read_log
from torchjfa.dynamics import RigidBodyModel
from torchjfa.robots import path
from torchjfa.sim import SimulatedLog, load_description

PANDA = [f"panda_joint{i}" for i in range(1, 8)]
ARMATURE = [0.1, 0.1, 0.1, 0.1, 0.05, 0.05, 0.05]  # kg m^2, the Panda's motors' order
QUIET = ["--quiet", "--n-samples", "1000"]  # two periods of the 0.5 Hz trajectory at 500 Hz


def _trajectory(tmp_path, scale=0.4, names=PANDA, name="trajectory.npz"):
    """A 0.5 Hz, 3-harmonic trajectory of the Panda, at rest at the middle of the ranges; at
    scale 0.4 every joint stays within its range and its velocity limit, at 1.0 joint 2 passes
    its 2.175 rad/s."""
    from torchjfa.excitation import FourierTrajectory, constrain_coefficients

    rng = np.random.default_rng(1)
    lo, hi = load_description("panda_arm").model.jnt_range.T
    a, b = constrain_coefficients(*torch.as_tensor(rng.normal(size=(2, 7, 3))))
    traj = FourierTrajectory(0.5, (lo + hi) / 2, scale * a.numpy(), scale * b.numpy(), names)
    traj.save(tmp_path / name)
    return tmp_path / name, traj


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def _rigid(log):
    """The Panda description's rigid-body torque at the log's true state (torchjfa's RNEA)."""
    rbm = RigidBodyModel.from_urdf(path("panda_arm"))
    return rbm.inverse_dynamics(log.q_true, log.qd_true, log.qdd_true, rbm.nominal_theta)


def test_a_urdf_log_holds_the_descriptions_torques(tmp_path, capsys):
    traj_path, traj = _trajectory(tmp_path)
    full, csv, noisy = tmp_path / "log.npz", tmp_path / "log.csv", tmp_path / "noisy.csv"
    for out, scale, *full_log in ((full, "0", "--full"), (csv, "0"), (noisy, "1")):
        code, stdout, err = _run(capsys, "simulate", "panda_arm", "--trajectory", traj_path,
                                 "--out", out, "--noise-scale", scale, *QUIET, *full_log)  # fmt: skip
        assert code == 0 and err == "", err  # within the velocity and effort limits: no warning
    assert "(joint effects: none)" in stdout and "torchjfa identify panda_arm" in stdout
    log = SimulatedLog.load(full)
    assert log.joint_names == tuple(PANDA) and log.control_rate == 500.0
    # the command and its state agree with torchjfa's RNEA of the URDF to rounding
    tau = log.tau_true.numpy()
    assert np.abs(_rigid(log).numpy() - tau).max() < 1e-10 * np.abs(tau).max()
    # computed-torque tracking with the exact model: the reference to well under a milliradian
    q_ref = traj.evaluate_numpy(log.t.numpy())[0]
    assert np.abs(log.q_true.numpy() - q_ref).max() < 1e-3
    # the logged (noiseless) torque against the model at the logged q, qd and qd's central
    # difference: both are means over the same two half sample intervals, equal up to the
    # change of M(q) and the bias within +-h, relative (w h)^2 ~ (2 pi 1.5 Hz * 2 ms)^2 = 4e-4
    got = read_log(csv)
    t, q, qd, tau = (getattr(got, k).numpy() for k in ("t", "q", "qd", "tau"))
    qdd = np.gradient(qd, t, axis=0)
    rbm = RigidBodyModel.from_urdf(path("panda_arm"))
    pred = rbm.inverse_dynamics(*map(torch.as_tensor, (q, qd, qdd)), rbm.nominal_theta).numpy()
    rms = lambda a: np.sqrt(np.mean(a * a, axis=0))  # noqa: E731
    assert np.all(rms((pred - tau)[1:-1]) < 1e-3 * rms(tau))
    # the sensor noise: the same motion (the controller sees the true state), plus white noise
    # of 1e-3 rad, 0.02 rad/s and 0.02 N m; 7000 draws give each std to 0.85 %, so 5 % is 6 sigma
    other = read_log(noisy)
    for k, std in (("q", 1e-3), ("qd", 0.02), ("tau", 0.02)):
        diff = (getattr(other, k) - getattr(got, k)).numpy()
        assert abs(diff.std() / std - 1) < 0.05 and abs(diff.mean()) < 0.1 * std, k


def test_damping_armature_and_friction_settings_show_up_in_the_torques(tmp_path, capsys):
    traj_path, _ = _trajectory(tmp_path)
    a = ",".join(map(str, ARMATURE))
    code, stdout, err = _run(capsys, "simulate", "panda_arm", "--trajectory", traj_path, "--out",
                             tmp_path / "eff.npz", "--full", "--noise-scale", "0", "--damping",
                             "0.5", "--armature", a, *QUIET)  # fmt: skip
    assert code == 0, err
    assert "(joint effects: damping, armature)" in stdout
    log = SimulatedLog.load(tmp_path / "eff.npz")
    qd, qdd = log.qd_true.numpy(), log.qdd_true.numpy()
    extra = log.tau_true.numpy() - _rigid(log).numpy()
    np.testing.assert_allclose(extra, 0.5 * qd + np.array(ARMATURE) * qdd, rtol=0, atol=1e-9)
    # ... and torchjfa's viscous and armature terms with those values give the whole torque
    rbm = RigidBodyModel.from_urdf(path("panda_arm"), friction=("viscous", "armature"))
    theta = rbm.nominal_theta.clone()
    for j, name in enumerate(PANDA):
        theta[rbm.layout.index(name, "fv")] = 0.5
        theta[rbm.layout.index(name, "ia")] = ARMATURE[j]
    tau = rbm.inverse_dynamics(log.q_true, log.qd_true, log.qdd_true, theta).numpy()
    np.testing.assert_allclose(tau, log.tau_true.numpy(), rtol=0, atol=1e-9)
    # MuJoCo's dry friction: at most f, and f sign(qd) once the joint moves faster than its
    # soft constraint's linear zone (qdd / 105 here, under 0.2 rad/s on this trajectory)
    code, stdout, err = _run(capsys, "simulate", "panda_arm", "--trajectory", traj_path, "--out",
                             tmp_path / "dry.npz", "--full", "--noise-scale", "0",
                             "--frictionloss", "0.3", *QUIET)  # fmt: skip
    assert code == 0, err
    log = SimulatedLog.load(tmp_path / "dry.npz")
    dry = log.tau_true.numpy() - _rigid(log).numpy()
    qd = log.qd_true.numpy()
    assert np.abs(dry).max() <= 0.3 + 1e-9
    moving = np.abs(qd) > 0.2
    assert moving.mean() > 0.5
    np.testing.assert_allclose(dry[moving], 0.3 * np.sign(qd[moving]), rtol=0, atol=1e-9)


def test_an_mjcf_description_with_slide_joints_simulates_its_own_effects(tmp_path, capsys):
    out = tmp_path / "tree.npz"
    code, stdout, err = _run(capsys, "simulate", "branched_tree", "--out", out, "--full",
                             "--noise-scale", "0", "--stiffness", "0.5", *QUIET)  # fmt: skip
    assert code == 0, err
    log = SimulatedLog.load(out)
    rbm = RigidBodyModel.from_mjcf(path("branched_tree"))
    rigid = rbm.inverse_dynamics(log.q_true, log.qd_true, log.qdd_true, rbm.nominal_theta)
    spring = 0.5 * log.q_true.numpy()  # the joint spring to q = 0, N m/rad and N/m
    tau = log.tau_true.numpy()
    np.testing.assert_allclose(rigid.numpy() + spring, tau, rtol=0, atol=1e-10 * np.abs(tau).max())
    # the random excitation stays inside 60 % of each range ((-pi, pi) for an unlimited joint)
    from torchjfa.sim._robots import joint_ranges

    lo, hi = joint_ranges(load_description("branched_tree").model).T
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    assert np.all(np.abs(log.q_true.numpy() - mid) <= 0.6 * half + 1e-9)


def test_a_description_log_identifies_and_the_model_evaluates_in_simulation(tmp_path, capsys):
    log = tmp_path / "panda.csv"
    code, _, err = _run(capsys, "simulate", "panda_arm", "--out", log, "--quiet",
                        "--n-samples", "4000", "--damping", "0.4")  # fmt: skip
    assert code == 0, err
    result = tmp_path / "result"
    code, stdout, err = _run(capsys, "identify", "panda_arm", log, "--estimator", "ols",
                             "--friction", "viscous", "--out", result, "--quiet", "--no-plots",
                             "--jackknife", "0")  # fmt: skip
    assert code == 0, err
    assert "held-out torque nMSE" in stdout
    from torchjfa.io import read_identified

    ident = read_identified(result / "model.npz")
    viscous = [float(ident.theta[ident.model.layout.index(j, "fv")]) for j in PANDA]
    # the simulated damping comes out as viscous friction (measured: within 4 % on every joint)
    np.testing.assert_allclose(viscous, 0.4, rtol=0.1)
    js = tmp_path / "eval.json"
    code, stdout, err = _run(capsys, "evaluate", result / "model.npz", "--robot", "panda_arm",
                             "--damping", "0.4", "--n-samples", "1000", "--control-seconds", "1",
                             "--json", js, "--quiet")  # fmt: skip
    assert code == 0, err
    res = json.loads(js.read_text())
    assert max(res["nmse"]) < 0.01 and res["control"]["success"]
    assert res["control"]["rms_position"] < 1e-3
    assert "panda_joint7" in stdout and "computed-torque control" in stdout


def test_limits_the_simulation_does_not_enforce_are_warned_about(tmp_path, capsys):
    traj_path, _ = _trajectory(tmp_path, scale=1.0)
    code, stdout, err = _run(capsys, "simulate", "panda_arm", "--trajectory", traj_path,
                             "--out", tmp_path / "fast.csv", *QUIET)  # fmt: skip
    assert code == 0 and "wrote 1000 samples" in stdout
    assert "warning: joint 'panda_joint2' reaches a speed of" in err
    assert "over the description's limit 2.175" in err


def _bad_cases(tmp_path):
    """(argv, what the one error line must say) for each kind of bad input."""
    traj_path, _ = _trajectory(tmp_path)
    head_names = ["neck_pan", "neck_tilt", "neck_roll", "left_eye_pan", "left_eye_tilt",
                  "right_eye_pan", "right_eye_tilt"]  # fmt: skip
    head_traj, _ = _trajectory(tmp_path, 0.01, head_names, "head.npz")
    wide_traj, _ = _trajectory(tmp_path, 3.0, name="wide.npz")
    floating = tmp_path / "floating.urdf"
    text = Path(path("panda_arm")).read_text()
    floating.write_text(
        text.replace(
            '<joint name="panda_joint1" type="revolute">',
            '<joint name="panda_joint1" type="floating">',
        )
    )
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody>")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    out = ["--out", tmp_path / "x.csv", "--quiet"]
    sim = ["simulate", "panda_arm", *out]
    return [
        (["simulate", tmp_path / "nowhere.urdf", *out], "no robot file"),
        (["simulate", broken, *out], "MuJoCo cannot read"),
        (["simulate", floating, *out], "floating and planar joints are not supported"),
        ([*sim, "--trajectory", head_traj], "are not the simulated panda_arm's"),
        (
            [*sim, "--trajectory", wide_traj],
            "leaves the range [-1.763, 1.763] of joint 'panda_joint2'",
        ),
        ([*sim, "--trajectory", junk], "not an .npz file of torchjfa excite"),
        ([*sim, "--trajectory", tmp_path / "none.npz"], "no trajectory file"),
        ([*sim, "--damping", "1,2"], "--damping takes 1 or 7 numbers"),
        ([*sim, "--armature", "-1"], "--armature must be finite and non-negative"),
        ([*sim, "--trajectory", traj_path, "--rate", "333.3"], "whole number of samples"),
        ([*sim, "--rate", "0"], "--rate must be a positive"),
        (["simulate", "head", *out, "--description-effects"], "not head or arm"),
    ]


def test_bad_input_ends_with_one_line_and_status_2(tmp_path, capsys):
    for argv, message in _bad_cases(tmp_path):
        code, stdout, err = _run(capsys, *argv)
        assert code == 2, (argv, err)
        assert message in err and err.count("\n") == 1 and "Traceback" not in err, (argv, err)
        assert err.startswith("torchjfa simulate: error: ")
    # a model of other joints
    from torchjfa.io import save_identified
    from torchjfa.sim import model_path

    head = RigidBodyModel.from_mjcf(model_path("head"))
    save_identified(tmp_path / "head.npz", head, head.nominal_theta)
    code, _, err = _run(capsys, "evaluate", tmp_path / "head.npz", "--robot", "panda_arm",
                        "--quiet", "--no-control")  # fmt: skip
    assert code == 2 and "are not the simulated panda_arm's" in err and err.count("\n") == 1
    code, _, err = _run(capsys, "evaluate", tmp_path / "head.npz", "--robot",
                        tmp_path / "nowhere.xml", "--quiet")  # fmt: skip
    assert code == 2 and "no robot file" in err


def test_the_old_python_m_command_warns_and_runs_simulate(tmp_path, capsys):
    import pytest

    from torchjfa.sim.__main__ import main as old

    out = tmp_path / "head.npz"
    with pytest.warns(FutureWarning, match="torchjfa simulate"):
        code = old(["head", "--n-samples", "840", "--quiet", "--out", str(out)])
    assert code == 0 and "wrote 840 samples" in capsys.readouterr().out
    log = SimulatedLog.load(out)  # the whole SimulatedLog, as --full writes it
    assert log.n_samples == 840 and log.tau_true.shape == (840, 7)


def test_evaluate_robot_reads_the_library_defaults():
    import inspect

    from torchjfa.cli import build_parser
    from torchjfa.sim import evaluate_simulated, simulate

    parser = build_parser()
    sim = parser.parse_args(["simulate", "head", "--out", "x.csv"])
    ev = parser.parse_args(["evaluate", "model.npz", "--robot", "head"])
    for args, function, names in (
        (sim, simulate, ("n_samples", "seed", "noise_scale")),
        (ev, evaluate_simulated, ("n_samples", "seed", "control_seconds")),
    ):
        defaults = inspect.signature(function).parameters
        for name in names:
            assert getattr(args, name) == defaults[name].default, name
