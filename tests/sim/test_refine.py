"""`refine` (mujoco.sysid) on a simulated three-link arm with known friction loss, damping and
armature: a wrong start moves to the truth and its held-out rollouts improve; a start at the
truth is kept; a torque delay is found; the extra's absence is named."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from torchjfa.data import JointLog
from torchjfa.dynamics import RigidBodyModel

try:  # mujoco.sysid imports without its extra's dependencies, but then has no optimize
    import mujoco.sysid._src.optimize  # noqa: F401

    HAVE_SYSID = True
except ImportError:
    HAVE_SYSID = False
needs_sysid = pytest.mark.skipif(not HAVE_SYSID, reason='no mujoco[sysid]: "torchjfa[sysid]"')

ARM = """<mujoco><option timestep="0.001" integrator="implicitfast"><flag contact="disable"/></option>
<worldbody><body name="b1"><joint name="j1" axis="0 0 1" {j1}/>
 <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04" mass="2"/>
 <body name="b2" pos="0.3 0 0"><joint name="j2" axis="0 1 0" {j2}/>
  <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03" mass="1"/>
  <body name="b3" pos="0.25 0 0"><joint name="j3" axis="0 1 0" {j3}/>
   <geom type="box" size="0.04 0.02 0.02" pos="0.04 0 0" mass="0.5"/></body></body></body>
</worldbody></mujoco>"""
JOINTS = ("j1", "j2", "j3")
TRUTH = {
    "frictionloss": np.array([0.3, 0.15, 0.05]),
    "damping": np.array([0.2, 0.1, 0.05]),
    "armature": np.array([0.01, 0.005, 0.002]),
}
SHORT = {"frictionloss": "fc", "damping": "fv", "armature": "ia"}
RATE = 500.0
FAST = {"max_windows": 24, "window": 0.15, "max_iters": 15}


def _truth_model() -> mujoco.MjModel:
    attrs = {f"j{i + 1}": " ".join(f'{k}="{v[i]}"' for k, v in TRUTH.items()) for i in range(3)}
    return mujoco.MjModel.from_xml_string(ARM.format(**attrs))


def _log(seconds: float, seed: int, delay_samples: int = 0) -> JointLog:
    """The true arm driven open loop by random sums of sines held over each sample (the joint
    feeling them ``delay_samples`` late), its state logged with small noise."""
    mj, rng = _truth_model(), np.random.default_rng(seed)
    data = mujoco.MjData(mj)
    n, sub = int(seconds * RATE), round(1.0 / RATE / mj.opt.timestep)
    t = np.arange(n) / RATE
    freq, phase = rng.uniform(0.5, 3.0, (3, 3)), rng.uniform(0.0, 2 * np.pi, (3, 3))
    amp = np.array([0.75, 1.5, 0.4])
    tau = np.stack([amp[j] * np.sin(2 * np.pi * freq[j] * t[:, None] + phase[j]).sum(1)
                    for j in range(3)], axis=1)  # fmt: skip
    q, qd = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        q[i], qd[i] = data.qpos, data.qvel
        data.qfrc_applied[:] = tau[max(0, i - delay_samples)]
        for _ in range(sub):
            mujoco.mj_step(mj, data)
    q += rng.normal(0.0, 1e-4, q.shape)
    qd += rng.normal(0.0, 2e-3, qd.shape)
    return JointLog(t=t, q=q, qd=qd, tau=tau, joint_names=JOINTS)


def _identified(values: dict[str, np.ndarray]) -> tuple[RigidBodyModel, torch.Tensor]:
    """The arm's rigid-body model (its own inertials) with these joint terms."""
    model = RigidBodyModel.from_mjcf(
        ARM.format(j1="", j2="", j3=""), friction=("viscous", "coulomb", "armature")
    )
    theta = model.nominal_theta.clone()
    for kind, v in values.items():
        for j, name in enumerate(JOINTS):
            theta[model.layout.index(name, SHORT[kind])] = float(v[j])
    return model, theta


@pytest.fixture(scope="module")
def logs() -> tuple[JointLog, JointLog]:
    return _log(6.0, seed=1), _log(4.0, seed=2)


@needs_sysid
def test_a_wrong_start_moves_to_the_truth_and_held_out_rollouts_improve(logs):
    from torchjfa.sim._refine import refine

    train, held = logs
    wrong = {"frictionloss": np.zeros(3), "damping": 2 * TRUTH["damping"],
             "armature": TRUTH["armature"]}  # fmt: skip
    r = refine(*_identified(wrong), train, held, **FAST)
    for kind in ("frictionloss", "damping"):
        np.testing.assert_allclose(r.before[kind], wrong[kind])
        err_before = np.abs(r.before[kind] - TRUTH[kind])
        err_after = np.abs(r.after[kind] - TRUTH[kind])
        assert (err_after < 0.2 * err_before).all(), (kind, r.after[kind])
    assert set(r.accepted) == set(JOINTS)
    before, after = r.held_out["before"].mean(1), r.held_out["after"].mean(1)
    assert (after < 0.2 * before).all()
    # the refined MJCF holds the kept values; rolled out again it gives the judged errors
    mj = r.model()
    np.testing.assert_allclose(mj.dof_frictionloss, r.after["frictionloss"], rtol=1e-12)
    np.testing.assert_allclose(mj.dof_damping, r.after["damping"], rtol=1e-12)
    again = r.replay(held).position["refined"]
    np.testing.assert_allclose(again, r.held_out["after"], rtol=1e-9, atol=1e-12)
    assert r.summary()["accepted"] == list(r.accepted) and len(r.lines()) > 5


@needs_sysid
def test_a_start_at_the_truth_is_kept(logs):
    from torchjfa.sim._refine import refine

    train, held = logs
    r = refine(*_identified(TRUTH), train, held, **FAST)
    # the noise moves the fit a little, the held-out rollouts do not confirm it: nothing kept
    for kind in TRUTH:
        np.testing.assert_allclose(r.fitted[kind], TRUTH[kind], rtol=0.1, atol=1e-4)
        np.testing.assert_array_equal(r.after[kind], r.before[kind])
    assert r.accepted == () and "nothing kept" in r.reasons["whole"]
    np.testing.assert_array_equal(r.held_out["after"], r.held_out["before"])
    np.testing.assert_allclose(r.model().dof_frictionloss, TRUTH["frictionloss"], rtol=1e-12)


@needs_sysid
def test_a_torque_delay_is_found():
    from torchjfa.sim._refine import refine

    train, held = _log(4.0, seed=3, delay_samples=2), _log(3.0, seed=4, delay_samples=2)
    r = refine(*_identified(TRUTH), train, held, parameters=("delay",), **FAST)
    assert r.delay[1] == pytest.approx(2.0 / RATE, abs=2e-4)
    assert r.accepted == ("delay",) and r.delay[2] == r.delay[1]
    assert (r.held_out["after"].mean(1) < 0.5 * r.held_out["before"].mean(1)).all()


def test_without_the_extra_the_error_names_it(monkeypatch, logs):
    import mujoco.sysid

    from torchjfa.sim._refine import refine

    if hasattr(mujoco.sysid, "optimize"):
        monkeypatch.delattr(mujoco.sysid, "optimize")
    with pytest.raises(ImportError, match=r"torchjfa\[sysid\]"):
        refine(*_identified(TRUTH), *logs)


@needs_sysid
def test_bad_arguments_are_refused(logs):
    from torchjfa.sim._refine import refine

    model, theta = _identified(TRUTH)
    with pytest.raises(ValueError, match="parameters must be some of"):
        refine(model, theta, *logs, parameters=("stiffness",))
    with pytest.raises(ValueError, match="no joints"):
        refine(model, theta, *logs, joints=("j9",))
    bare = JointLog(t=logs[0].t, q=logs[0].q, tau=logs[0].tau, joint_names=JOINTS)
    with pytest.raises(ValueError, match="no velocities"):
        refine(model, theta, bare, logs[1])


@needs_sysid
@pytest.mark.slow
def test_on_the_shipped_head_the_joint_terms_and_the_torque_sensors_lag_are_found():
    """The shipped head tracking its excitation in closed loop, every effect on, no noise; the
    identified model as the regression has it at best: the true inertials and damping, no
    friction loss, no armature. Its logged torque is the sensor's mean over the interval
    centred on the sample, half a sample behind the command held over it: a delay of -h/2."""
    from torchjfa.sim import SensorNoise, generate_log, model_path, robot_effects, true_parameters
    from torchjfa.sim._refine import PARAMETERS, refine

    rate = 420.0
    log = generate_log("head", n_samples=int(8 * rate), seed=3, noise=SensorNoise.zero())
    train, held = log.select(slice(0, int(5 * rate))), log.select(slice(int(5 * rate), None))
    model = RigidBodyModel.from_mjcf(
        model_path("head"), friction=("viscous", "coulomb", "armature")
    )
    r = refine(model, true_parameters("head", model), train, held, parameters=PARAMETERS, **FAST)
    truth = robot_effects("head")
    for kind in ("frictionloss", "damping", "armature"):
        np.testing.assert_allclose(r.after[kind], truth[kind], rtol=0.05)
    assert r.delay[2] == pytest.approx(-0.5 / rate, rel=0.05)
    assert (r.held_out["after"].mean(1) < 0.01 * r.held_out["before"].mean(1)).all()


@needs_sysid
def test_the_command_writes_the_refined_mjcf(tmp_path, capsys):
    """``torchjfa refine MODEL TRAIN --held-out LOG``: from no friction loss and twice the
    damping, the refined MJCF loads in MuJoCo, keeps some joints and says so."""
    import json

    from torchjfa.cli import main
    from torchjfa.data import write_log
    from torchjfa.io import save_identified

    start = {"frictionloss": np.zeros(3), "damping": 2 * TRUTH["damping"],
             "armature": TRUTH["armature"]}  # fmt: skip
    model, theta = _identified(start)
    save_identified(tmp_path / "model.npz", model, theta, cutoff_hz=40.0)
    write_log(_log(6.0, 0), tmp_path / "train.csv")
    write_log(_log(3.0, 1), tmp_path / "held.csv")
    args = ["refine", str(tmp_path / "model.npz"), str(tmp_path / "train.csv"),
            "--held-out", str(tmp_path / "held.csv"), "--out", str(tmp_path / "r")]  # fmt: skip
    assert main(args) == 0
    summary = json.loads((tmp_path / "r" / "refinement.json").read_text())
    assert summary["accepted"], summary["reasons"]
    refined = mujoco.MjModel.from_xml_path(str(tmp_path / "r" / "refined.xml"))
    assert refined.nv == 3
    assert "kept:" in capsys.readouterr().out
    assert main([*args[:3], "--held-out", str(tmp_path / "nosuch.csv"), "--out", "x"]) == 2
