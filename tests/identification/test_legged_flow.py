"""The floating-base flow (`identify_legged`, ``torchjfa identify`` on a legged log) on a
simulated Go2 whose bodies differ from its description: what it finds against the simulated
truth, what it writes (read back by Pinocchio), and its errors on bad input."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.cli import main
from torchjfa.data import LogError
from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import (
    IdentificationError,
    IdentificationWarning,
    LeggedIdentification,
    Options,
    contact_equations,
    contact_moments,
    identify,
    identify_legged,
    row_moments,
)
from torchjfa.identification._legged import mass_index
from torchjfa.io import read_identified, save_identified
from torchjfa.sim import simulate_legged

#: every test here prepares at this cut-off (the choice among cut-offs needs longer logs)
CUTOFF = 10.0


@pytest.fixture(scope="module")
def go2(tmp_path_factory):
    """The Go2 description, a noise-free simulated log of a perturbed Go2 (10 s at 100 Hz)
    written as CSV with forces and as CSV with contact flags only, and the truth's mass."""
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, GO2_FEET, GO2_STANCE, seconds=10.0, rate=100.0, perturb=0.2,
                          seed=1)  # fmt: skip
    folder = tmp_path_factory.mktemp("go2")
    forces, flags = folder / "forces.csv", folder / "flags.csv"
    log.save(forces)
    replace(log, wrench={}).save(flags)
    truth = float(log.theta.reshape(-1, 10)[:, 0].sum())
    return {"path": path, "log": log, "forces": forces, "flags": flags, "mass": truth}


def test_with_forces_it_finds_the_total_mass_and_predicts_better_than_the_description(go2):
    ident = identify(go2["path"], go2["forces"], Options(cutoff=CUTOFF))
    assert isinstance(ident, LeggedIdentification)  # the base columns chose the flow
    assert ident.rows == "all" and ident.consistent
    # noise-free data whose motion (below 1 Hz) the 10 Hz filter leaves intact: the base rows
    # give the mass to the filter's and the integrator's error, far inside 0.5 %
    assert ident.total_mass == pytest.approx(go2["mass"], rel=5e-3)
    assert ident.ratio() < 0.5
    # the description prior's weight was chosen on the training blocks, from the grid
    assert ident.settings["description_prior"].split()[1] == "(auto:"


def test_the_base_rows_alone_give_the_total_mass(go2):
    ident = identify_legged(go2["path"], go2["forces"],
                            Options(cutoff=CUTOFF, base_rows_only=True))  # fmt: skip
    assert ident.rows == "base" and ident.row_labels[:3] == (
        "base force x", "base force y", "base force z",
    )  # fmt: skip
    assert len(ident.held_out["identified"]) == 6
    assert ident.total_mass == pytest.approx(go2["mass"], rel=5e-3)


def test_with_flags_only_the_total_mass_constraint_holds_and_a_warning_says_why(go2):
    with pytest.warns(IdentificationWarning, match="weakly determined"):
        loose = identify_legged(go2["path"], go2["flags"], Options(cutoff=CUTOFF))
    assert loose.rows == "projected"
    ident = identify_legged(go2["path"], go2["flags"],
                            Options(cutoff=CUTOFF, total_mass=go2["mass"]))  # fmt: skip
    # the constraint row weighs 1e6 times the data's largest diagonal entry
    assert ident.total_mass == pytest.approx(go2["mass"], rel=1e-5)
    assert ident.consistent
    assert ident.ratio() < 1.0


def test_row_moments_match_the_rows_formed_one_by_one(go2):
    model = FloatingBaseModel.from_urdf(go2["path"], friction=("viscous",))
    log = go2["log"].select(np.arange(0, 200, 7))
    rm = row_moments(model, log, chunk_size=5)
    Y, y = contact_equations(model, log.q, log.v, log.a, log.tau, wrenches=log.wrench)
    theta = model.nominal_theta
    direct = (Y @ theta - y).pow(2).mean(0).sqrt()
    torch.testing.assert_close(rm.rms(theta), direct, rtol=1e-6, atol=1e-9)
    torch.testing.assert_close(rm.target_rms(), y.pow(2).mean(0).sqrt())
    whole = contact_moments(model, log)
    torch.testing.assert_close(rm.combined().xtx, whole.xtx)
    w = torch.linspace(0.5, 2.0, Y.shape[1], dtype=torch.float64)
    weighted = torch.einsum("brp,r,brq->pq", Y, w, Y)
    torch.testing.assert_close(rm.combined(w).xtx, weighted)


def test_the_command_writes_a_report_and_a_urdf_that_pinocchio_reads(go2, tmp_path, capsys):
    pin = pytest.importorskip("pinocchio")
    out = tmp_path / "result"
    rc = main(["identify", go2["path"], str(go2["forces"]), "--out", str(out), "--quiet",
               "--cutoff", str(CUTOFF), "--no-plots"])  # fmt: skip
    assert rc == 0
    printed = capsys.readouterr().out
    assert "floating base" in printed and "report:" in printed
    summary = json.loads((out / "report.json").read_text())
    assert summary["rows"] == "all" and summary["consistent"]
    text = (out / "report.md").read_text()
    assert "## Held-out prediction" in text and "base force z" in text
    mujoco = pytest.importorskip("mujoco")
    mj = mujoco.MjModel.from_xml_path(str(out / "identified.xml"))
    assert mj.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert mj.body_mass.sum() == pytest.approx(summary["total_mass"], rel=1e-12)
    pm = pin.buildModelFromUrdf(str(out / "identified.urdf"), pin.JointModelFreeFlyer())
    total = sum(float(inertia.mass) for inertia in pm.inertias)
    assert total == pytest.approx(summary["total_mass"], rel=1e-12)
    # the written description, read back, holds the identified inertial parameters
    back = FloatingBaseModel.from_urdf(out / "identified.urdf", friction=())
    rows = {name: float(v) for name, v in zip(
        (line.split(",")[0] for line in (out / "parameters.csv").read_text().splitlines()[1:]),
        (line.split(",")[3] for line in (out / "parameters.csv").read_text().splitlines()[1:]),
        strict=True,
    )}  # fmt: skip
    for name, value in zip(back.parameter_names, back.nominal_theta.tolist(), strict=True):
        assert value == pytest.approx(rows[name], rel=1e-9, abs=1e-12), name


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--drive-gains", "1,2"], "2 drive gains for the 12 joints"),
        (["--base-rows-only", "LOG=flags"], "needs the contact forces"),
        (["--flat-contacts", "nose"], "not contact frames"),
        (["--appendix"], "--appendix"),
    ],
)
def test_the_command_stops_with_one_line_on_options_the_logs_cannot_serve(
    go2, tmp_path, capsys, extra, message
):
    log = go2["flags"] if "LOG=flags" in extra else go2["forces"]
    extra = [e for e in extra if e != "LOG=flags"]
    if "--flat-contacts" in extra:
        log = go2["flags"]
    rc = main(["identify", go2["path"], str(log), "--out", str(tmp_path / "r"), "--quiet",
               "--cutoff", str(CUTOFF), *extra])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "r").exists()


def test_a_log_whose_joints_or_frames_do_not_match_names_them(go2, tmp_path):
    log = go2["log"]
    bad = replace(
        log,
        joint_names=("FL_hip_joint_x", *log.joint_names[1:]),
        contact={"FL_toe" if k == "FL_foot" else k: v for k, v in log.contact.items()},
    )
    path = tmp_path / "bad.csv"
    bad.save(path)
    with pytest.raises(LogError) as info:
        identify_legged(go2["path"], path, Options(cutoff=CUTOFF))
    text = str(info.value)
    assert "FL_hip_joint_x" in text and "['FL_hip_joint']" in text and "FL_toe" in text
    uneven = replace(log, t=log.t + np.where(np.arange(len(log.t)) >= 300, 0.003, 0.0))
    uneven.save(path)
    with pytest.raises(LogError, match="fixed rate"):
        identify_legged(go2["path"], path, Options(cutoff=CUTOFF))


def test_a_short_log_warns_that_the_cut_off_was_not_chosen(go2):
    with pytest.warns(IdentificationWarning, match="too short to choose the cut-off"):
        ident = identify_legged(go2["path"], go2["log"], Options(max_seconds=6.0))
    assert ident.cutoff_how == "the default"


def test_arm_options_are_refused_for_a_floating_base(go2):
    with pytest.raises(IdentificationError, match="jackknife"):
        identify_legged(go2["path"], go2["log"], Options(jackknife=5))


def test_simulate_then_identify_on_the_command_line(go2, tmp_path, capsys):
    log = tmp_path / "go2.csv"
    stance = ",".join(f"{j}={v}" for j, v in GO2_STANCE.items())
    rc = main(["simulate", go2["path"], "--feet", ",".join(GO2_FEET), "--stance", stance,
               "--seconds", "8", "--rate", "100", "--perturb", "0.2", "--out", str(log),
               "--quiet"])  # fmt: skip
    assert rc == 0
    assert "torchjfa identify" in capsys.readouterr().out
    header = log.read_text().splitlines()[0].split(",")
    assert {"base_qw", "contact_FL_foot", "f_RR_foot_z", "m_RR_foot_z", "tau_FL_calf_joint"} <= set(
        header
    )
    rc = main(["identify", go2["path"], str(log), "--out", str(tmp_path / "r"), "--quiet",
               "--cutoff", str(CUTOFF), "--no-plots"])  # fmt: skip
    assert rc == 0
    summary = json.loads((tmp_path / "r" / "report.json").read_text())
    # the same perturbed robot (truth seed 0) as the module's log: its mass, with the default
    # sensor noise (1 N on each force), to well within 2 %
    assert summary["total_mass"] == pytest.approx(go2["mass"], rel=0.02)
    rc = main(["simulate", go2["path"], "--feet", "FL_foot", "--n-samples", "10",
               "--out", str(tmp_path / "x.csv")])  # fmt: skip
    assert rc == 2
    assert "not for a floating-base robot" in capsys.readouterr().err
    rc = main(["simulate", go2["path"], "--feet", ",".join(GO2_FEET), "--stance", stance,
               "--step", "-0.05", "--out", str(tmp_path / "x.csv")])  # fmt: skip
    assert rc == 2
    assert "step must be a finite height >= 0 m" in capsys.readouterr().err


def test_simulate_steps_in_place_on_the_command_line(tmp_path):
    """``--step``: the feet leave the ground in turn (FL, then FR in the first 4 s), the log's
    flags say so."""
    log = tmp_path / "steps.csv"
    stance = ",".join(f"{j}={v}" for j, v in GO2_STANCE.items())
    path = erd_path("go2_description/urdf/go2.urdf")
    rc = main(["simulate", path, "--feet", ",".join(GO2_FEET), "--stance", stance,
               "--seconds", "4", "--rate", "100", "--step", "0.05", "--out", str(log),
               "--quiet"])  # fmt: skip
    assert rc == 0
    table = np.genfromtxt(log, delimiter=",", names=True)
    up = {f: float((table[f"contact_{f}"] == 0).mean()) for f in GO2_FEET}
    assert up["FL_foot"] > 0.01 and up["FR_foot"] > 0.01  # the slots of these two


#: a Unitree G1 standing on flat feet (four corner spheres each), knees bent, its waist and
#: arms moving while its legs hold the stance
G1 = "g1_description/urdf/g1_29dof_rev_1_0.urdf"
G1_FEET = ("left_ankle_roll_link", "right_ankle_roll_link")
G1_STANCE = {f"{s}_{j}_joint": v for s in ("left", "right")
             for j, v in (("hip_pitch", -0.3), ("knee", 0.6), ("ankle_pitch", -0.3))}  # fmt: skip
G1_MOTION = {"waist_yaw_joint": 0.1, **{f"{s}_{j}_joint": 0.1 for s in ("left", "right")
                                          for j in ("shoulder_pitch", "elbow", "wrist_pitch")}}  # fmt: skip


def test_a_humanoid_with_force_sensors_at_its_feet_gives_its_mass_and_centre_of_mass():
    path = erd_path(G1)
    log = simulate_legged(path, G1_FEET, G1_STANCE, seconds=8.0, rate=200.0, amplitude=G1_MOTION,
                          foot_size=(0.2, 0.08), gains=(300.0, 10.0), perturb=0.2)  # fmt: skip
    assert all(w.shape[1] == 6 for w in log.wrench.values())  # six-axis sensors
    assert min(float(c.mean()) for c in log.contact.values()) == 1.0  # both feet stay down
    ident = identify_legged(path, log, Options(cutoff=CUTOFF, base_rows_only=True))
    truth = torch.as_tensor(log.theta)
    assert ident.total_mass == pytest.approx(float(truth.reshape(-1, 10)[:, 0].sum()), rel=5e-3)
    bare = FloatingBaseModel.from_urdf(path, friction=())
    found = torch.cat([ident.theta[:10],
                       ident.model.joints.layout.split(ident.theta[10:])[0].reshape(-1)])  # fmt: skip
    q = torch.as_tensor(log.q[len(log.t) // 2])
    com, com_true = bare.center_of_mass(q, found), bare.center_of_mass(q, truth)
    # the base rows hold m g x c: the horizontal centre of mass, to 1 % of its height above
    # the ground; its height needs the base to tilt, which a robot standing level does not
    height = float(com_true[2])
    assert float((com - com_true)[:2].norm()) < 0.01 * height


def test_the_model_file_judges_other_legged_logs(go2, tmp_path, capsys):
    out = tmp_path / "result"
    assert main(["identify", go2["path"], str(go2["forces"]), "--out", str(out), "--quiet",
                 "--cutoff", str(CUTOFF), "--no-plots"]) == 0  # fmt: skip
    ident = read_identified(out / "model.npz")
    assert isinstance(ident.model, FloatingBaseModel) and ident.cutoff_hz == CUTOFF
    summary = json.loads((out / "report.json").read_text())
    masses = ident.theta[mass_index(ident.model)]
    assert float(masses.sum()) == pytest.approx(summary["total_mass"], rel=1e-12)
    for log, rows in ((go2["forces"], "all"), (go2["flags"], "projected")):
        capsys.readouterr()
        rc = main(["evaluate", str(out / "model.npz"), str(log), "--out", str(tmp_path / rows)])
        assert rc == 0
        assert "joint rows' RMS" in capsys.readouterr().out
        found = json.loads((tmp_path / rows / "evaluation.json").read_text())
        assert found["rows"] == rows and found["cutoff_hz"] == CUTOFF
        (entry,) = found["logs"]
        # the same robot and motion it was identified from: better than the description
        joints = slice(6, None)
        assert sum(np.square(entry["identified"][joints])) < sum(
            np.square(entry["description"][joints])
        )
    with pytest.raises(ValueError, match="fixed-base robot's module"):
        ident.inverse_dynamics()


@pytest.mark.parametrize("kind", ["urdf", "mjcf"])
def test_a_floating_base_model_file_round_trips(go2, tmp_path, kind):
    if kind == "urdf":
        model = FloatingBaseModel.from_urdf(go2["path"], friction=("viscous", "coulomb"))
    else:
        mujoco = pytest.importorskip("mujoco")
        from torchjfa.dynamics._mjcf import mjcf_from_urdf

        spec = mujoco.MjSpec.from_string(mjcf_from_urdf(Path(go2["path"]).read_text()))
        spec.worldbody.first_body().add_freejoint(name="root")
        spec.compile()
        xml = tmp_path / "go2.xml"
        xml.write_text(spec.to_xml())
        model = FloatingBaseModel.from_mjcf(xml, friction=("viscous",))
    theta = model.nominal_theta * 1.1
    save_identified(tmp_path / "m.npz", model, theta, cutoff_hz=7.0)
    back = read_identified(tmp_path / "m.npz")
    assert isinstance(back.model, FloatingBaseModel)
    assert back.model.parameter_names == model.parameter_names
    assert back.model.base_name == model.base_name
    q = go2["log"].q[:3]
    v, a = go2["log"].v[:3], go2["log"].a[:3]
    torch.testing.assert_close(back.model.regressor(q, v, a), model.regressor(q, v, a))
    torch.testing.assert_close(back.theta, theta)


def test_a_log_too_short_for_the_filter_is_refused_naming_it(go2, tmp_path):
    path = tmp_path / "tiny.csv"
    go2["log"].select(np.arange(6)).save(path)
    with pytest.raises(LogError, match=r"tiny\.csv: .*filter"):
        identify_legged(go2["path"], path, Options(cutoff=CUTOFF))
