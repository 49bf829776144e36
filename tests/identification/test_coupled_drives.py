"""A coupled wrist (one motor turning two joints, as on many industrial arms) identified with its
transmission: the motors' inertia and friction recovered from noisy data, a model that predicts
held-out torques far better than the best one without the coupling, and the command line on a
log recorded at the motors."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch

import torchjfa
from torchjfa.cli import main
from torchjfa.dynamics import RigidBodyModel, Transmission
from torchjfa.identification import NoiseChoice, Options, fit, make_consistent

ALL = ("viscous", "coulomb", "offset", "armature")
# reductions of a geared 7-joint arm; motor 7 turns joints 6 and 7 (a coupled wrist)
RATIO = np.diag([100.0, 100, 100, 100, 50, -50, 50])
RATIO[6, 5] = 50.0
# motor-side truth: rotor inertia kg m^2, viscous N m s/rad, Coulomb N m, offset N m
TRUE = {
    "ia": [3e-5, 3e-5, 2e-5, 2e-5, 1e-5, 1e-5, 1e-5],
    "fv": [4e-4, 4e-4, 3e-4, 3e-4, 4e-4, 4e-4, 4e-4],
    "fc": [0.02, 0.02, 0.015, 0.015, 0.02, 0.02, 0.02],
    "fo": [0.002, -0.003, 0.001, 0.0, 0.001, -0.001, 0.002],
}


@pytest.fixture(scope="module")
def arm():
    base = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"), friction=ALL)
    geared = base.with_transmission(Transmission(base.joint_names, RATIO))
    theta = geared.nominal_theta.clone()
    for short, values in TRUE.items():
        for k, v in enumerate(values):
            theta[geared.layout.index(k, short)] = v
    return base, geared, theta


def _trajectory(model, seed, seconds=30.0, rate=200.0):
    """Sums of five harmonics of 0.1 Hz per joint inside a third of the joint ranges: exact
    positions, velocities and accelerations."""
    lo, hi = (np.asarray(v, dtype=float) for v in model.chain.get_joint_limits())
    g = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)[:, None]
    q, qd, qdd = (np.zeros((t.shape[0], 7)) + (0.5 * (lo + hi) if k == 0 else 0) for k in range(3))
    for h in range(1, 6):
        w = 2 * np.pi * 0.1 * h
        a = 0.35 * (hi - lo) / 2 * g.normal(size=7) / h / 2.2
        p = g.uniform(0, 2 * np.pi, size=7)
        q += a * np.sin(w * t + p)
        qd += a * w * np.cos(w * t + p)
        qdd -= a * w * w * np.sin(w * t + p)
    return t[:, 0], *(torch.tensor(v) for v in (q, qd, qdd))


def _noisy_log(geared, theta, seed):
    t, q, qd, qdd = _trajectory(geared, seed)
    tau = geared.regressor(q, qd, qdd) @ theta
    g = torch.Generator().manual_seed(seed)
    noise = lambda x, rel: x + rel * x.std(0) * torch.randn(x.shape, generator=g, dtype=x.dtype)  # noqa: E731
    return {"q": q, "qd": noise(qd, 1e-3), "qdd": noise(qdd, 5e-3), "tau": noise(tau, 0.02)}


def _identify(model, log):
    options = Options(estimator="ols", weighting="none", bias_correction=0, jackknife=0)
    result = fit(model, log, NoiseChoice.given(None, None), options)
    return make_consistent(result, options).theta


def _standard_errors(geared, log, short) -> np.ndarray:
    """Least squares' standard error of each motor's ``short`` term, relative to its truth,
    from the regressor and the torque noise: where the data alone cannot pin a term (the
    first joint's rotor inertia adds to its link's inertia about the same axis: one column),
    only the projection's prior does, and 5 % is more than one can ask."""
    Y = geared.regressor(log["q"], log["qd"], log["qdd"]).reshape(-1, geared.n_params)
    sigma = (0.02 * log["tau"].std(0)).repeat(log["q"].shape[0])
    cov = torch.linalg.pinv((Y / sigma[:, None]).T @ (Y / sigma[:, None]))
    idx = [geared.layout.index(k, short) for k in range(7)]
    return cov.diagonal()[idx].sqrt().numpy() / np.abs(TRUE[short])


@pytest.mark.parametrize("seed", [0, 3])
def test_the_coupled_motors_are_recovered_and_predict_far_better(arm, seed):
    base, geared, theta = arm
    log = _noisy_log(geared, theta, seed=seed)
    est = _identify(geared, log)
    for short in ("ia", "fv", "fc"):
        got = np.array([float(est[geared.layout.index(k, short)]) for k in range(7)])
        # 5 %, or four standard errors where the data determine a term less well than that
        rtol = np.maximum(0.05, 4 * _standard_errors(geared, log, short))
        assert (np.abs(got / TRUE[short] - 1) <= rtol).all(), (short, got / TRUE[short] - 1)
        if short != "ia":
            assert (rtol == 0.05).all()  # friction: every motor's within 5 %
    # held out: another trajectory, its exact torques
    _, q, qd, qdd = _trajectory(geared, seed=1)
    tau = geared.regressor(q, qd, qdd) @ theta
    coupled = (geared.regressor(q, qd, qdd) @ est - tau).square().mean().sqrt()
    # the best model without the coupling: every joint term of its own, armature included
    uncoupled = (base.regressor(q, qd, qdd) @ _identify(base, log) - tau).square().mean().sqrt()
    assert float(uncoupled) > 3.0 * float(coupled)


def test_the_command_identifies_a_log_recorded_at_the_motors(arm, tmp_path):
    base, geared, theta = arm
    t, q, qd, qdd = _trajectory(geared, seed=2, seconds=20.0)
    tau = geared.regressor(q, qd, qdd) @ theta
    ratio = torch.as_tensor(RATIO)
    motors = Transmission(base.joint_names, RATIO).motors
    q_motor = q @ ratio.T
    tau_motor = torch.linalg.solve(ratio.T, tau.T).T  # tau = R^T tau_motor
    columns = {"t": t}
    for k, m in enumerate(motors):
        columns[f"q_{m}"] = q_motor[:, k].numpy()
        columns[f"tau_{m}"] = tau_motor[:, k].numpy()
    np.savez(tmp_path / "motors.npz", **columns)
    spec = tmp_path / "drive.json"
    spec.write_text(json.dumps({"joints": list(base.joint_names), "ratio": RATIO.tolist()}))
    out = tmp_path / "out"
    code = main(
        [
            "identify",
            "panda_arm",
            str(tmp_path / "motors.npz"),
            "--transmission",
            str(spec),
            "--friction",
            ",".join(ALL),
            "--cutoff",
            "5",
            "--bias-correction",
            "0",  # the transmission is what this checks, not OLS's 20 refits
            "--out",
            str(out),
            "--quiet",
            "--no-plots",
        ]
    )
    assert code == 0
    saved = torchjfa.io.read_identified(out / "model.npz")
    assert saved.model.transmission == Transmission(base.joint_names, RATIO)
    # the description written back both ways: MJCF holds the motors as fixed tendons
    assert (out / "identified.urdf").is_file()
    tendons = ET.parse(out / "identified.xml").getroot().find("tendon")
    assert sorted(el.get("name") for el in tendons) == sorted(motors)
    report = (out / "report.md").read_text()
    assert "panda_joint7_motor" in report and "converted to the joints" in report
    # the motor-side log is read as the joints see it: the saved model predicts it
    pred = saved.inverse_dynamics()(q, qd, qdd).detach()
    assert float((pred - tau).square().mean().sqrt()) < 0.05 * float(tau.std())
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"joints": ["nope"], "ratio": [[1]]}))
    code = main(["identify", "panda_arm", str(tmp_path / "motors.npz"), "--transmission",
                 str(bad), "--out", str(tmp_path / "o2"), "--quiet"])  # fmt: skip
    assert code == 2
