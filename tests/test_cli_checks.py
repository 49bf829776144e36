"""`torchjfa identify` on logs that cannot identify anything: one line and exit status 2, or a
result with warnings that say what the numbers mean."""

from __future__ import annotations

import pytest
import torch

from torchjfa.cli import main
from torchjfa.data import JointLog, read_log, write_log
from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import cap_period_noise as _cap_period_noise
from torchjfa.identification import coverage_warnings as _coverage_warnings
from torchjfa.sim import PeriodNoise, model_path

FAST = ["--quiet", "--estimator", "ols", "--jackknife", "0", "--bias-correction", "0", "--no-plots"]
FAST += ["--cutoff", "20", "--friction", "viscous", "--parametrization", "virtual"]  # as written


@pytest.fixture(scope="module")
def head_log(head_csv):
    """The session's simulated head log (`head_csv`), read; tests change copies only."""
    return read_log(head_csv)


def _run(capsys, log, tmp_path, *extra):
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "log.csv"
    write_log(log, path)
    code = main(["identify", "head", str(path), "--out", str(tmp_path / "out"), *FAST, *extra])
    out = capsys.readouterr()
    return code, out.out, out.err


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_a_gap_in_time_stops_with_one_line(head_log, tmp_path, capsys):
    t = head_log.t.clone()
    t[2500:] += 2.0
    code, _, err = _run(capsys, JointLog(**{**vars(head_log), "t": t, "info": {}}), tmp_path)
    assert code == 2 and "time jumps by 2 s" in _one_line(err)


def test_positions_in_degrees_stop_with_one_line(head_log, tmp_path, capsys):
    log = JointLog(**{**vars(head_log), "q": torch.rad2deg(head_log.q), "info": {}})
    code, _, err = _run(capsys, log, tmp_path)
    assert code == 2 and "look like degrees" in _one_line(err)


def test_a_standing_robot_stops_with_one_line(head_log, tmp_path, capsys):
    still = head_log.q[:1].expand_as(head_log.q).clone()
    log = JointLog(**{**vars(head_log), "q": still, "qd": 0 * head_log.qd, "info": {}})
    code, _, err = _run(capsys, log, tmp_path)
    assert code == 2 and "does not move" in _one_line(err)


def test_a_model_worse_than_the_mean_on_held_out_data_is_not_a_result(head_log, tmp_path, capsys):
    # one second of the head: 420 samples x 7 joints pass the row count, not the validation
    code, out, err = _run(capsys, head_log.select(slice(0, 420)), tmp_path)
    assert code == 2
    assert "worse than their mean" in err.strip().splitlines()[-1]
    assert (tmp_path / "out" / "report.md").is_file()  # written, for a look
    # the same command on the whole log is a result
    code, _, err = _run(capsys, head_log, tmp_path / "whole")
    assert code == 0, err


def test_held_out_data_beyond_the_identification_data_are_named():
    n = 400
    t = torch.arange(n, dtype=torch.float64) / 100
    names = ("a", "b")
    q = torch.stack([torch.sin(t), torch.cos(t)], 1)

    def log(scale):
        return JointLog(t=t, q=q, qd=q * scale, qdd=q, tau=q, joint_names=names)

    assert _coverage_warnings(log(1.0), log(1.0)) == []
    (w,) = _coverage_warnings(log(1.0), log(3.0))
    assert "measure extrapolation" in w and "a: qd up to" in w and "(3.0x)" in w


def test_period_noise_above_half_a_columns_power_is_capped_with_a_warning():
    model = RigidBodyModel.from_mjcf(model_path("head"))
    d = model.n_params
    power = torch.linspace(1.0, 2.0, d, dtype=torch.float64)
    power[13] = 1e-30  # a structurally zero column: round-off, left alone
    noise = 0.1 * power
    noise[[3, 40]] = 1.5 * power[[3, 40]]  # above the column's power
    noise[13] = 2e-30
    p = PeriodNoise(noise, torch.tensor(1.0), torch.ones(7), {}, 3, 10, column_power=power)
    capped, (warning,) = _cap_period_noise(model, p)
    expected = noise.clone()
    expected[[3, 40]] = 0.5 * power[[3, 40]]
    torch.testing.assert_close(capped.input_noise, expected, rtol=0, atol=0)
    names = model.layout.parameter_names
    assert "2 regressor column(s)" in warning and names[3] in warning and names[40] in warning
    fine = PeriodNoise(0.1 * power, torch.tensor(1.0), torch.ones(7), {}, 3, 10, power)
    assert _cap_period_noise(model, fine) == (fine, [])


def test_a_validation_log_is_checked_too(head_log, tmp_path, capsys):
    train = tmp_path / "train.csv"
    write_log(head_log, train)
    t = head_log.t.clone()
    t[2500:] += 2.0
    bad = tmp_path / "valid.csv"
    write_log(JointLog(**{**vars(head_log), "t": t, "info": {}}), bad)
    code = main(
        [
            "identify",
            "head",
            str(train),
            "--validation-log",
            str(bad),
            "--out",
            str(tmp_path / "o"),
            *FAST,
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "valid.csv: time jumps by 2 s" in _one_line(err)


def test_report_json_names_the_estimator_without_dumping_its_arrays(head_log, tmp_path, capsys):
    import json

    code, _, err = _run(
        capsys, head_log, tmp_path, "--estimator", "bayes-jfa", "--max-iter", "300",
        "--input-noise", "periods",
    )  # fmt: skip
    assert code == 0, err
    settings = json.loads((tmp_path / "out" / "report.json").read_text())["settings"]
    assert settings["estimator"].startswith("BayesianJFA(")
    assert "tensor(" not in settings["estimator"] and "input_noise=(given" in settings["estimator"]
