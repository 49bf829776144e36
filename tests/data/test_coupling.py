"""`coupled_drives`: a motor that turns two consecutive joints, which the model lacks, is named
from the log (the simulated head, its right eye's pan and tilt given a shared geared rotor
whose inertia and damping act on both, written independently of the library's drive trains);
on the head as shipped, nothing is named."""

import pytest
import torch

from torchjfa.data import JointLog, coupled_drives
from torchjfa.identification import load_model
from torchjfa.sim import generate_log

PAIR = ("right_eye_pan", "right_eye_tilt")


@pytest.fixture(scope="module")
def sim():
    return generate_log("head", n_samples=5040, seed=4, progress=False)


@pytest.fixture(scope="module")
def model():
    terms = ("viscous", "coulomb", "offset", "armature")
    return load_model("head", terms).with_coulomb_velocity(0.05)


def _log(sim, inertia: float, damping: float) -> JointLog:
    """The log with a rotor turning both joints of PAIR at ratio 1: its velocity is
    qd_j + qd_k, and its torque (inertia x acceleration + damping x velocity) acts on both."""
    j, k = (sim.joint_names.index(n) for n in PAIR)
    shared = inertia * (sim.qdd_true[:, j] + sim.qdd_true[:, k]) + damping * (
        sim.qd_true[:, j] + sim.qd_true[:, k]
    )
    tau = sim.tau.clone()
    tau[:, j] += shared
    tau[:, k] += shared
    return JointLog(t=sim.t, q=sim.q, qd=sim.qd, tau=tau, joint_names=sim.joint_names)


def test_a_shared_rotor_of_two_joints_is_named(sim, model):
    found = coupled_drives(model, _log(sim, 2e-3, 2e-2).reorder(model.joint_names), 15.0)
    assert [f.joints for f in found] == [PAIR]
    f = found[0]
    assert f.nmse_coupled <= 0.75 * f.nmse
    text = f.describe()
    assert "right_eye_pan and right_eye_tilt" in text and "--transmission" in text


def test_the_head_as_shipped_has_no_shared_rotor(sim, model):
    assert coupled_drives(model, _log(sim, 0.0, 0.0).reorder(model.joint_names), 15.0) == []


def test_identify_names_the_shared_rotor_and_the_fix_and_not_once_the_drive_is_given(sim, tmp_path):
    """`torchjfa.identify` warns of the shared rotor without a drive train, and not with one."""
    import json
    import warnings

    import torchjfa
    from torchjfa.identification import IdentificationWarning

    log = _log(sim, 2e-3, 2e-2)
    options = torchjfa.Options(cutoff=15.0, jackknife=0, bias_correction=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        plain = torchjfa.identify("head", log, options)
    assert any("coupled drive" in w and "right_eye_pan" in w for w in plain.warnings)
    steps = plain.report.judge().next_steps
    assert any(s.startswith("right_eye_pan and right_eye_tilt") and "--transmission" in s
               for s in steps)  # fmt: skip
    names = list(sim.joint_names)
    ratio = torch.eye(len(names))
    ratio[names.index(PAIR[1]), names.index(PAIR[0])] = 1.0  # motor k turns j and k
    drive = tmp_path / "drive.json"
    drive.write_text(json.dumps({"joints": names, "ratio": ratio.tolist()}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        given = torchjfa.identify("head", log, options.replace(transmission=str(drive)))
    assert not any("coupled drive" in w for w in given.warnings)
