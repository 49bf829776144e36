"""Open-loop MuJoCo rollouts on a log (`torchjfa.sim.replay`): exact on the model that made the
log, worse for a wrong one; the evaluate command's --rollouts; a real UR10e log."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

import torchjfa
from torchjfa.cli import main
from torchjfa.data import JointLog
from torchjfa.identification import IdentificationWarning
from torchjfa.sim import description_model, generate_log, replay

# three hinges with damping and armature (no dry friction: its constraint solver starts from a
# warm start the rollout does not have, which would cost exactness)
XML = """<mujoco><option timestep="0.0005" integrator="RK4"><flag contact="disable"/></option>
<worldbody><body name="b1"><joint name="j1" axis="0 0 1" damping="0.2" armature="0.01"/>
 <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04" mass="2"/>
 <body name="b2" pos="0.3 0 0"><joint name="j2" axis="0 1 0" damping="0.1" armature="0.005"/>
  <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03" mass="1"/>
  <body name="b3" pos="0.25 0 0"><joint name="j3" axis="0 1 0" damping="0.05"/>
   <geom type="box" size="0.04 0.02 0.02" pos="0.04 0 0" mass="0.5"/></body></body></body>
</worldbody></mujoco>"""
RATE = 500.0


def _log(mj: mujoco.MjModel, seconds=3.0) -> JointLog:
    """The model driven by smooth torques held over each sample period (as a controller
    does), its state recorded at every sample: the log the rollouts should reproduce."""
    data = mujoco.MjData(mj)
    n, sub = int(seconds * RATE), round(1.0 / RATE / mj.opt.timestep)
    t = np.arange(n) / RATE
    tau = np.stack([2.0 * np.sin(2.1 * t), 4.0 + np.sin(3.3 * t), 0.8 * np.cos(1.7 * t)], 1)
    q, qd = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        q[i], qd[i] = data.qpos, data.qvel
        data.qfrc_applied[:] = tau[i]
        for _ in range(sub):
            mujoco.mj_step(mj, data)
    return JointLog(t=t, q=q, qd=qd, tau=tau, joint_names=("j1", "j2", "j3"))


def test_the_model_that_made_the_log_reproduces_it():
    mj = mujoco.MjModel.from_xml_string(XML)
    log = _log(mj)
    heavier = mujoco.MjModel.from_xml_string(XML.replace('mass="1"', 'mass="1.2"'))
    r = replay({"truth": mj, "heavier": heavier}, log, horizons=(0.05, 0.2), starts=10)
    assert r.starts == 10 and r.horizons == (0.05, 0.2) and r.diverged == {"truth": 0, "heavier": 0}
    # the same model, the same steps, the same torques: round-off only
    assert r.position["truth"].max() < 1e-10 and r.velocity["truth"].max() < 1e-8
    # a 20 % heavier middle link drifts, more over the longer horizon
    assert r.position["heavier"].max() > 1e-4
    assert (r.position["heavier"][1] > r.position["heavier"][0]).all()
    summary = r.summary()
    assert summary["models"]["truth"]["diverged"] == 0 and len(r.lines()) == 5


def test_a_log_without_velocities_or_too_short_is_refused():
    mj = mujoco.MjModel.from_xml_string(XML)
    log = _log(mj, seconds=0.3)
    with pytest.raises(ValueError, match="do not fit a log"):
        replay({"m": mj}, log, horizons=(0.5,))
    no_velocity = JointLog(t=log.t, q=log.q, tau=log.tau, joint_names=log.joint_names)
    with pytest.raises(ValueError, match="needs velocities"):
        replay({"m": mj}, no_velocity)
    other = JointLog(t=log.t, q=log.q, qd=log.qd, tau=log.tau, joint_names=("a", "j2", "j3"))
    with pytest.raises(ValueError, match="no joint 'a'"):
        replay({"m": mj}, other, horizons=(0.05,))


def test_evaluate_rolls_out_the_identified_model_and_the_description(tmp_path):
    sim = generate_log("head", n_samples=4200, seed=7, progress=False)
    log_path = tmp_path / "log.npz"
    np.savez(
        log_path,
        t=sim.t.numpy(),
        **{f"q_{j}": sim.q[:, k].numpy() for k, j in enumerate(sim.joint_names)},
        **{f"qd_{j}": sim.qd[:, k].numpy() for k, j in enumerate(sim.joint_names)},
        **{f"tau_{j}": sim.tau[:, k].numpy() for k, j in enumerate(sim.joint_names)},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        code = main(["identify", "head", str(log_path), "--cutoff", "15", "--jackknife", "0",
                     "--out", str(tmp_path / "id"), "--quiet", "--no-plots"])  # fmt: skip
    assert code == 0
    code = main(["evaluate", str(tmp_path / "id" / "model.npz"), str(log_path), "--rollouts",
                 "--out", str(tmp_path / "ev")])  # fmt: skip
    assert code == 0
    rollouts = json.loads((tmp_path / "ev" / "evaluation.json").read_text())["rollouts"]
    (only,) = rollouts.values()
    assert only["horizons_s"] == [0.05, 0.2, 0.5]
    assert set(only["models"]) == {"identified", "description"}
    assert (tmp_path / "ev" / "rollouts_0.png").is_file()
    # the description of the simulated head is the simulator itself (its damping, armature,
    # friction loss and stiffness are in the file), whose rollouts drift too: the logged torque
    # is a noisy sensor's, averaged over the control step. The identified model's rollouts
    # come within a small factor of the truth's (its armature, friction loss and stiffness are
    # what the default joint terms only approximate)
    ident = only["models"]["identified"]["mean_position_rms"]
    truth = only["models"]["description"]["mean_position_rms"]
    assert all(i < 3 * d for i, d in zip(ident, truth, strict=True))
    assert description_model(torchjfa.io.read_identified(tmp_path / "id" / "model.npz").model)


DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "ur10e_mamedov2020"
GAINS = "10.0,10.6956,8.4566,9.0029,9.48,10.1232"  # the dataset README's, N m/A


@pytest.mark.skipif(not (DATA / "robot.urdf").is_file(), reason=f"no UR10e logs in {DATA}")
def test_on_a_real_ur10e_log_the_identified_model_moves_like_the_robot(tmp_path):
    """Identified on three runs, rolled out on a fourth: the identified model's MuJoCo drifts
    far less than the description's (no rotor inertia, no friction: the measured currents
    accelerate its light links away)."""
    runs = ["50sec_12harm", "40sec_12harm"]
    logs = [str(next(DATA.glob(f"ident_ur-*{r}.csv"))) for r in runs]
    held = str(next(DATA.glob("ident_ur-*15harm50sec.csv")))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        assert main(["identify", str(DATA / "robot.urdf"), *logs, "--drive-gains", GAINS,
                     "--out", str(tmp_path / "id"), "--quiet", "--no-plots"]) == 0  # fmt: skip
    assert main(["evaluate", str(tmp_path / "id" / "model.npz"), held, "--drive-gains", GAINS,
                 "--rollouts", "--no-plots", "--out", str(tmp_path / "ev")]) == 0  # fmt: skip
    (only,) = json.loads((tmp_path / "ev" / "evaluation.json").read_text())["rollouts"].values()
    ident = np.array(only["models"]["identified"]["mean_position_rms"])
    desc = np.array(only["models"]["description"]["mean_position_rms"])
    assert (ident < 0.1 * desc).all()
    assert ident[0] < 0.01  # rad, over 50 ms
    assert torch.isfinite(torch.as_tensor(ident)).all()
