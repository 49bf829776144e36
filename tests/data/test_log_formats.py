"""Reading logs as robots write them: delimiters, decimal commas, time units, column patterns,
motor currents, velocities in deg/s and ROS bags."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torchjfa.data import JointLog, LogError, check_log, read_log, write_log
from torchjfa.data._columns import _unit
from torchjfa.data._log import _format
from torchjfa.data._schema import joints_from_columns

JOINTS = ("a", "b", "c")


def _columns(n=40, seed=0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    cols = {"t": np.arange(n) / 100.0}
    for kind in ("q", "tau"):
        for j in JOINTS:
            cols[f"{kind}_{j}"] = rng.standard_normal(n)
    return cols


def _repr(v) -> str:
    return repr(float(v))


def _write(path, cols, delimiter=",", decimal=".", fmt=_repr):
    """A text log with one delimiter and decimal mark; ``fmt`` writes each number (repr: the
    shortest text that reads back to the same float64)."""

    def text(v):
        return fmt(v).replace(".", decimal)

    names = list(cols)
    rows = [delimiter.join(names)]
    rows += [delimiter.join(text(cols[c][i]) for c in names) for i in range(len(cols[names[0]]))]
    path.write_text("\n".join(rows) + "\n")
    return path


def _assert_same(log: JointLog, cols, t_rtol=0.0):
    """Every value read bit for bit (as `_write` writes them)."""
    assert log.joint_names == JOINTS
    expect_t = torch.as_tensor(cols["t"], dtype=torch.float64)
    torch.testing.assert_close(log.t, expect_t, rtol=t_rtol, atol=0)
    for kind in ("q", "tau"):
        want = np.stack([cols[f"{kind}_{j}"] for j in JOINTS], axis=1)
        torch.testing.assert_close(getattr(log, kind), torch.as_tensor(want), rtol=0, atol=0)


# ------------------------------------------------------------------------------- delimiters
@pytest.mark.parametrize(
    "delimiter, decimal, suffix",
    [("\t", ".", ".csv"), (";", ".", ".csv"), (";", ",", ".csv"), ("\t", ",", ".tsv"),
     ("   ", ".", ".txt"), (",", ".", ".txt")],
)  # fmt: skip
def test_every_delimiter_and_decimal_commas_read_exactly(tmp_path, delimiter, decimal, suffix):
    cols = _columns()
    path = _write(tmp_path / f"log{suffix}", cols, delimiter, decimal)
    log = read_log(path)
    _assert_same(log, cols)
    assert log.info["delimiter"] == (
        " " if delimiter.isspace() and delimiter != "\t" else delimiter
    )


def test_spaces_of_varying_width_and_blanks_around_names(tmp_path):
    path = tmp_path / "log.txt"
    path.write_text("t    q_a  tau_a\n0.0  1.5  -2\n0.01 1.25 3e-1\n 0.02  1  4\n")
    log = read_log(path)
    torch.testing.assert_close(log.q[:, 0], torch.tensor([1.5, 1.25, 1.0], dtype=torch.float64))
    path = tmp_path / "log.csv"
    path.write_text("t, q_a, tau_a\n0.0, 1.5, -2\n0.01, 1.25, 0.3\n")
    assert read_log(path).joint_names == ("a",)


def test_a_comma_file_with_decimal_commas_is_refused_by_name(tmp_path):
    cols = _columns(n=5)
    path = _write(tmp_path / "log.csv", cols, ",", ",")
    with pytest.raises(LogError, match="cannot tell the delimiter") as err:
        read_log(path)
    assert "decimal commas" in str(err.value) and "semicolon" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_parse_failure_names_the_delimiter_tried(tmp_path):
    cols = _columns(n=80)
    path = _write(tmp_path / "log.csv", cols, ";", ",")
    lines = path.read_text().splitlines()
    lines[70] += ";1,5"  # past the lines the delimiter is found from
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogError, match="with the delimiter semicolon ';'"):
        read_log(path)


def test_text_in_a_decimal_comma_file_is_not_numeric(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text("t;q_a;tau_a\n0;1,5;x\n0,01;1,2.5;y\n")  # 1,2.5: neither mark alone
    with pytest.raises(LogError, match=r"columns 'q_a', 'tau_a' are not numeric"):
        read_log(path)


# ------------------------------------------------------------------------------- time units
@pytest.mark.parametrize(
    "step, scale",
    [(0.5, 1.0), (1e-4, 1.0), (0.6, 1e-3), (100, 1e-3), (101, 1e-6), (1e5, 1e-6),
     (1.01e5, 1e-9), (1e8, 1e-9)],
)  # fmt: skip
def test_the_time_unit_rule(step, scale):
    """Seconds down to 2 Hz; then the one of ms, us, ns with a rate in [10 Hz, 10 kHz)."""
    found, notes = _unit(step, "log")
    assert found == scale
    assert bool(notes) == (scale != 1.0)
    with pytest.raises(LogError, match=r"time_scale= \(--time-scale\)"):
        _unit(1.1e8, "log")


@pytest.mark.parametrize("unit, scale", [("milliseconds", 1e-3), ("microseconds", 1e-6)])
def test_time_in_ms_or_us_is_found_and_said(tmp_path, unit, scale):
    cols = _columns()
    stamps = {**cols, "t": np.round(cols["t"] / scale).astype(np.int64)}  # 100 Hz
    path = _write(tmp_path / "log.csv", stamps, fmt=str)
    log = read_log(path)
    _assert_same(log, {**cols, "t": stamps["t"] * scale})
    assert log.info["time_scale"] == scale
    (note,) = log.info["read_notes"]
    assert f"time read as {unit}" in note and "time_scale=1 (--time-scale 1)" in note
    assert log.rate_hz == pytest.approx(100.0, rel=1e-12)
    as_given = read_log(path, time_scale=1.0)  # an explicit scale is used as given
    assert as_given.info["read_notes"] == [] and as_given.rate_hz == pytest.approx(100 * scale)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_epoch_nanoseconds_keep_exact_steps(tmp_path, suffix):
    """ns since 1970 as int64: float64 holds them to 256 ns; subtracted first, the 1 ms steps
    stay exact to rounding of the product (a few 1e-19 s)."""
    n = 200
    stamps = 1_700_000_000_123_456_789 + np.arange(n, dtype=np.int64) * 1_000_000
    cols = {**_columns(n), "t": stamps}
    path = tmp_path / f"log{suffix}"
    if suffix == ".npz":
        np.savez(path, **cols)
    else:
        _write(path, cols, fmt=str)
    log = read_log(path)
    assert log.info["time_scale"] == 1e-9 and "nanoseconds" in log.info["read_notes"][0]
    assert log.info["time_origin_s"] == pytest.approx(1_700_000_000.123456789, abs=1e-6)
    assert float(log.t[0]) == 0.0
    steps = np.diff(log.t.numpy())
    assert np.abs(steps - 1e-3).max() < 1e-15  # as float64 epoch seconds: ~2e-7
    assert float(log.t[-1]) == pytest.approx((n - 1) * 1e-3, abs=1e-15)


def test_a_clock_near_zero_is_kept_and_bad_scales_are_refused(tmp_path):
    cols = _columns()
    cols["t"] = 10.0 + np.arange(40) / 100.0
    path = _write(tmp_path / "log.csv", cols)
    log = read_log(path)
    _assert_same(log, cols)
    assert "time_origin_s" not in log.info and log.info["read_notes"] == []
    with pytest.raises(LogError, match="time_scale must be"):
        read_log(path, time_scale=-1.0)


# ------------------------------------------------------------------- column mapping, missing
def _robot_file(tmp_path, n=30):
    cols = _columns(n)
    own = {"time": cols["t"]}
    for j in JOINTS:
        own[f"pos_{j}"] = cols[f"q_{j}"]
        own[f"effort_{j}"] = cols[f"tau_{j}"]
    return _write(tmp_path / "robot.csv", own), cols


def test_patterns_map_every_joint(tmp_path):
    path, cols = _robot_file(tmp_path)
    pattern = {"t": "time", "q_{joint}": "pos_{joint}", "tau_{joint}": "effort_{joint}"}
    _assert_same(read_log(path, columns=pattern), cols)
    # a plain entry overrides the pattern's for its name
    swapped = read_log(path, columns={**pattern, "q_a": "pos_b"})
    torch.testing.assert_close(swapped.q[:, 0], swapped.q[:, 1], rtol=0, atol=0)
    with pytest.raises(LogError, match="is not a pattern"):
        read_log(path, columns={"pos_{joint}": "q_{joint}"})


def test_every_missing_column_in_one_error(tmp_path):
    path, _ = _robot_file(tmp_path)
    with pytest.raises(LogError) as err:
        read_log(path, columns={"q_{joint}": "pos_{joint}", "tau_a": "effort_a", "t": "stamp"})
    message = str(err.value)
    assert "names 'stamp' (for 't')" in message
    assert "missing columns 'tau_b' (torque), 'tau_c' (torque)" in message
    assert "\n" not in message
    with pytest.raises(LogError) as err:
        read_log(path, columns={"q_{joint}": "pos_{joint}", "tau_{joint}": "volts_{joint}"})
    message = str(err.value)
    assert "the pattern 'volts_{joint}' (for 'tau_{joint}')" in message
    assert "missing columns 't' (time, s), 'tau_a' (torque)" in message


# ---------------------------------------------------------------------------- motor currents
GAINS = {"a": 0.5, "b": -2.0, "c": 0.1}


def _current_file(tmp_path, with_tau=False):
    cols = _columns()
    currents = {"t": cols["t"]}
    for j in JOINTS:
        currents[f"q_{j}"] = cols[f"q_{j}"]
        currents[f"i_{j}"] = cols[f"tau_{j}"]  # the same numbers, as amperes
        if with_tau:
            currents[f"tau_{j}"] = cols[f"tau_{j}"]
    return _write(tmp_path / "currents.csv", currents), cols


def test_currents_times_drive_gains_are_the_torques(tmp_path):
    path, cols = _current_file(tmp_path)
    torque_path = _write(tmp_path / "torque.csv", {
        **cols, **{f"tau_{j}": cols[f"tau_{j}"] * GAINS[j] for j in JOINTS}
    })  # fmt: skip
    log = read_log(path, drive_gains=GAINS)
    torques = read_log(torque_path)
    assert log.tau.dtype == torch.float64
    assert torch.equal(log.tau, torques.tau) and torch.equal(log.q, torques.q)
    assert log.info["effort"] == "current" and log.info["drive_gains"] == GAINS
    assert torques.info["effort"] == "torque" and "drive_gains" not in torques.info
    assert log.reorder(("c", "a", "b")).info["drive_gains"] == GAINS  # info follows the log


def test_currents_without_gains_or_with_some_missing(tmp_path):
    path, _ = _current_file(tmp_path)
    with pytest.raises(LogError, match=r"motor currents i_<joint> \(A\) and no torques") as err:
        read_log(path)
    assert "--drive-gains G1,G2,..." in str(err.value)
    with pytest.raises(LogError, match=r"no drive gain \(N m/A\) for joint\(s\) \['b', 'c'\]"):
        read_log(path, drive_gains={"a": 1.0})
    with pytest.raises(LogError, match="finite number other than 0"):
        read_log(path, drive_gains={**GAINS, "b": 0.0})


def test_torques_and_currents_both(tmp_path):
    path, cols = _current_file(tmp_path, with_tau=True)
    log = read_log(path)  # torques used, currents ignored
    _assert_same(log, cols)
    assert log.info["effort"] == "torque"
    with pytest.raises(LogError, match="ambiguous which to use"):
        read_log(path, drive_gains=GAINS)


def test_currents_through_a_pattern_and_joints_from_current_columns(tmp_path):
    assert joints_from_columns(["t", "q_x", "i_y", "tau_x", "i_x"]) == ["x", "y"]
    cols = _columns()
    own = {"stamp": cols["t"]}
    for j in JOINTS:
        own[f"{j}.pos"] = cols[f"q_{j}"]
        own[f"{j}.amps"] = cols[f"tau_{j}"]
    path = _write(tmp_path / "own.csv", own)
    mapping = {"t": "stamp", "q_{joint}": "{joint}.pos", "i_{joint}": "{joint}.amps"}
    log = read_log(path, columns=mapping, drive_gains=GAINS)
    want = np.stack([cols[f"tau_{j}"] * GAINS[j] for j in JOINTS], axis=1)
    assert torch.equal(log.tau, torch.as_tensor(want))


def test_gains_for_a_torque_log_are_noted_not_used(tmp_path):
    cols = _columns()
    log = read_log(_write(tmp_path / "log.csv", cols), drive_gains=GAINS)
    _assert_same(log, cols)
    (note,) = log.info["read_notes"]
    assert "drive gains are not used" in note


# ---------------------------------------------------------------------------------- ROS bags
def test_ros_bags_are_told_by_name_and_topic_is_for_them_only(tmp_path):
    for name in ("run.bag", "run.mcap", "run_0.db3"):
        assert _format(tmp_path / name, None) == "ros"
    folder = tmp_path / "rosbag2_run"
    folder.mkdir()
    with pytest.raises(LogError, match="format"):
        read_log(folder)
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert _format(folder, None) == "ros"
    csv = _write(tmp_path / "log.csv", _columns())
    with pytest.raises(LogError, match="topic applies to ROS bags only"):
        read_log(csv, topic="/joint_states")
    with pytest.raises(LogError, match="effort applies to ROS bags only"):
        read_log(csv, effort="current")
    with pytest.raises(LogError, match="not ROS bags"):
        write_log(read_log(csv), tmp_path / "out.bag")


@pytest.mark.skipif(
    importlib.util.find_spec("torchjfa.data._ros") is None, reason="no ROS bag reader yet"
)
def test_a_ros_bag_is_read_through_ros_columns(tmp_path, monkeypatch):
    import torchjfa.data._ros as ros

    cols = _columns()
    stamps = 1.7e9 + cols["t"]  # header stamps: seconds since 1970
    calls = []

    def ros_columns(path, *, topic=None, effort="torque"):
        calls.append((path, topic, effort))
        out = {"t": stamps}
        for j in JOINTS:
            out[f"q_{j}"] = cols[f"q_{j}"]
            out[f"i_{j}"] = cols[f"tau_{j}"]
        return out

    monkeypatch.setattr(ros, "ros_columns", ros_columns)
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    log = read_log(folder, topic="/arm/joint_states", effort="current", drive_gains=GAINS)
    assert calls == [(folder, "/arm/joint_states", "current")]
    assert log.info["format"] == "ros" and log.info["effort"] == "current"
    assert log.info["read_notes"] == [] and log.info["time_origin_s"] == 1.7e9
    np.testing.assert_allclose(log.t.numpy(), stamps - stamps[0], rtol=0, atol=0)
    want = np.stack([cols[f"tau_{j}"] * GAINS[j] for j in JOINTS], axis=1)
    assert torch.equal(log.tau, torch.as_tensor(want))


# ---------------------------------------------------------------------- velocities in deg/s
def _moving(qd_factor=(1.0, 1.0, 1.0), noise=0.0, n=3000, rate=500.0):
    """Sines of 0.8 rad; qd the exact derivative times a factor per joint."""
    t = np.arange(n) / rate
    w = 2 * np.pi * np.array([0.3, 0.7, 1.1])
    q = 0.8 * np.sin(w * t[:, None])
    qd = 0.8 * w * np.cos(w * t[:, None]) * np.array(qd_factor)
    rng = np.random.default_rng(1)
    q = q + noise * rng.standard_normal(q.shape)
    qd = qd + 10 * noise * rng.standard_normal(q.shape)
    return JointLog(t=t, q=q, qd=qd, tau=np.zeros_like(q), joint_names=JOINTS, source="log")


def test_velocities_in_rad_per_s_pass_and_their_ratio_is_one():
    from torchjfa.data._checks import velocity_ratios

    ratio, corr = velocity_ratios(_moving())
    # trapezoids over 2 ms on sines up to 6.9 rad/s: relative error (w h)^2 / 12 < 2e-5
    np.testing.assert_allclose(ratio, 1.0, rtol=2e-5)
    np.testing.assert_allclose(corr, 1.0, rtol=1e-9)
    assert check_log(_moving(noise=1e-4)) == []


def test_velocities_in_deg_per_s_are_fatal_and_name_the_joints():
    deg = 180.0 / math.pi
    problems = check_log(_moving((deg, 1.0, deg), noise=1e-4))
    (p,) = problems
    assert p.fatal and "['a', 'c'] look like deg/s" in p.message and "rad/s" in p.message
    assert "\n" not in p.message


def test_velocities_off_by_another_factor_are_a_warning():
    (p,) = check_log(_moving((1.0, 100.0, 1.0), noise=1e-4))
    assert not p.fatal and "['b'] disagree" in p.message and "b 100" in p.message
    (p,) = check_log(_moving((1.0, 1.0, -1.0)))  # a flipped sign
    assert not p.fatal and "['c'] disagree" in p.message and "c -1" in p.message
    (p,) = check_log(_moving((0.01, 0.01, 0.01)))
    assert "same factor for every joint" in p.message
    (p,) = check_log(_moving((math.pi / 180,) * 3))
    assert "are the positions in degrees?" in p.message
    scrambled = _moving()
    scrambled.qd = scrambled.qd[torch.randperm(3000, generator=torch.Generator().manual_seed(0))]
    (p,) = check_log(scrambled)
    assert not p.fatal and "do not follow" in p.message


def test_a_dropped_first_row_moves_the_time_origin(tmp_path):
    cols = _columns()
    cols["t"] = 1.7e9 + np.arange(40) / 100.0  # epoch seconds
    cols["q_b"] = cols["q_b"].copy()
    cols["q_b"][0] = np.nan
    log = read_log(_write(tmp_path / "log.csv", cols), drop_nan=True)
    assert log.n_samples == 39 and float(log.t[0]) == 0.0
    assert log.info["time_origin_s"] == cols["t"][1]
    np.testing.assert_array_equal(log.t.numpy(), cols["t"][1:] - cols["t"][1])


UR10E = Path(__file__).resolve().parents[3] / "shared" / "data" / "ur10e_mamedov2020"


@pytest.mark.skipif(not UR10E.is_dir(), reason="the real UR10e logs are not beside the project")
def test_the_real_ur10e_currents_and_velocities():
    """Positions in rad, velocities in rad/s as the controller reports them, motor currents."""
    from torchjfa.data._checks import velocity_ratios

    path = UR10E / "ident_ur-20_02_12-50sec_12harm.csv"
    with pytest.raises(LogError, match="motor currents"):
        read_log(path)
    joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
    joints += ["wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    log = read_log(path, drive_gains=dict.fromkeys(joints, 10.0))
    assert log.info["effort"] == "current" and log.joint_names == tuple(joints)
    ratio, corr = velocity_ratios(log)
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)  # 1e-4 rad resolution over 50 ms windows
    assert corr.min() > 0.99
    assert check_log(log) == []
    log.qd = log.qd * (180 / math.pi)
    (p,) = check_log(log)
    assert p.fatal and "deg/s" in p.message


# ------------------------------------------------------------------------ damaged and ragged
def test_a_cut_last_line_is_named_by_its_number(tmp_path):
    path = _write(
        tmp_path / "log.csv", _columns(n=80)
    )  # past the lines the delimiter is found from
    path.write_text(path.read_text() + "0.81,0.5")  # the writer was stopped mid-line
    with pytest.raises(
        LogError, match=r"line 82 \(the last\) has 2 fields where the header has 7"
    ) as err:
        read_log(path)
    assert "--drop-cut-line" in str(err.value) and "\n" not in str(err.value)
    log = read_log(path, drop_cut_line=True)
    whole = read_log(_write(tmp_path / "whole.csv", _columns(n=80)))
    assert log.n_samples == whole.n_samples == 80  # the cut line is gone, nothing else
    torch.testing.assert_close(log.q, whole.q, rtol=0, atol=0)
    assert any("dropped its last line 82" in n for n in log.info["read_notes"])
    # a ragged line with lines after it is no cut write: refused, even with the flag
    path.write_text(path.read_text() + "\n0.82,1,2,3,4,5,6\n")
    with pytest.raises(LogError, match=r"line 82 has 2 fields.*only a last line may be dropped"):
        read_log(path, drop_cut_line=True)


def test_a_column_named_twice_is_refused_by_name(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text("t,q_a,tau_a,tau_a\n0,1,2,3\n0.01,1,2,3\n0.02,1,2,3\n")
    with pytest.raises(LogError, match=r"the columns \['tau_a'\] are named more than once"):
        read_log(path)
    path.write_text("t, q_a ,q_a,tau_a\n0,1,2,3\n0.01,1,2,3\n0.02,1,2,3\n")  # equal once stripped
    with pytest.raises(LogError, match=r"\['q_a'\] are named more than once"):
        read_log(path)


def test_npz_columns_of_different_lengths_are_named(tmp_path):
    cols = _columns(n=30)
    cols["tau_b"] = cols["tau_b"][:-3]
    np.savez(tmp_path / "log.npz", **cols)
    with pytest.raises(LogError, match=r"the time has 30 rows, but 'tau_b' 27"):
        read_log(tmp_path / "log.npz")


def test_npz_object_arrays_are_refused_and_never_unpickled(tmp_path):
    cols = _columns(n=4)
    cols["q_a"] = np.array([1.0, "x", None, 2], dtype=object)
    np.savez(tmp_path / "log.npz", **cols)
    with pytest.raises(LogError, match=r"member 'q_a' holds Python objects, which are not read"):
        read_log(tmp_path / "log.npz")


# ------------------------------------------------------------------------------------ spikes
def test_spike_rows_finds_isolated_spikes_and_leaves_motion_alone():
    from torchjfa.data import spike_rows

    t = np.linspace(0.0, 20.0, 2000)
    x = np.column_stack([np.sin(t), 0.3 * np.sign(np.sin(3 * t)), np.round(1e-3 * t, 4)])
    assert not spike_rows(x).any()  # a smooth signal, a friction-like step, a quantised ramp
    burst = x.copy()
    burst[700:702, 0] += 50.0  # two samples: not isolated
    burst[1200, 2] += 2e-4  # two quanta on a channel that barely moves
    assert not spike_rows(burst).any()
    spiked = x.copy()
    spiked[500, 0], spiked[900, 1], spiked[1500, 2] = 1e30, -9.0, 0.5
    found = spike_rows(spiked)
    assert [np.flatnonzero(found[:, c]).tolist() for c in range(3)] == [[500], [900], [1500]]


def test_a_spiked_log_is_refused_by_channel_and_row_or_dropped_on_request(tmp_path, capsys):
    from torchjfa.cli import main

    cols = _columns(n=60)
    cols["tau_b"][31] = 1e30  # one sample of a missing value's stand-in
    path = _write(tmp_path / "log.csv", cols)
    with pytest.raises(LogError, match=r"isolated spikes.*\(tau_b row\(s\) 31,.*--drop-outliers"):
        read_log(path)
    log = read_log(path, drop_outliers=True)
    assert log.n_samples == 59 and float(log.tau.abs().max()) < 10
    assert any("dropped 1 rows holding isolated spikes" in n for n in log.info["read_notes"])
    assert main(["identify", "head", str(path), "--out", str(tmp_path / "r")]) == 2
    assert "--drop-outliers" in capsys.readouterr().err
