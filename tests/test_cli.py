"""The torchjfa command: end to end on a simulated CSV log, and every bad input it must name."""

import argparse
import io
import json
import shutil
import subprocess
import sys
import zipfile
from subprocess import PIPE

import numpy as np
import pytest
import torch

from torchjfa.cli import build_parser, main
from torchjfa.data import read_log, write_log
from torchjfa.io import load_identified, read_identified
from torchjfa.report import torque_errors

# no bias correction (OLS's 20 refits by default): tests/identification/test_bias_correction.py
FAST_OLS = ["--quiet", "--jackknife", "2", "--no-plots", "--bias-correction", "0"]
FAST = [*FAST_OLS, "--max-iter", "300"]  # Bayesian JFA's (an error with another estimator)


# the defaults before the real-robot ones (a data-chosen cut-off, Coulomb and offset friction,
# log-Cholesky, OLS), given here so that these tests keep testing what they did on the simulated head;
# options a test gives come later and win. The defaults themselves: test_cli_defaults.py
OLD_DEFAULTS = ["--cutoff", "20", "--friction", "viscous", "--parametrization", "virtual"]
OLD_DEFAULTS += ["--estimator", "bayes-jfa"]


def _identify(capsys, *args):
    args = [str(a) for a in args]  # robot, log, options
    code = main(["identify", *args[:2], *OLD_DEFAULTS, *args[2:]])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_identify_end_to_end_smoke(head_csv, tmp_path, capsys):
    out = tmp_path / "result"
    code, stdout, err = _identify(
        capsys, "head", head_csv, "--out", out, "--smoke", "--quiet", "--jackknife", "2",
        "--friction", "viscous,coulomb",
    )  # fmt: skip
    assert code == 0, err
    for name in ("model.npz", "validation.npz", "parameters.csv", "report.json", "report.md"):
        assert (out / name).stat().st_size > 0
    for name in ("torques.png", "parameters.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = json.loads((out / "report.json").read_text())
    # the written model loads and predicts the torques the report says it does
    idyn = load_identified(out / "model.npz")
    assert idyn.model.friction == ("viscous", "coulomb")
    with np.load(out / "validation.npz") as z:
        names = tuple(str(s) for s in z["joint_names"])
        assert names == idyn.model.joint_names
        q, qd, qdd, tau = (torch.from_numpy(z[k]) for k in ("q", "qd", "qdd", "tau"))
    nmse, rms = torque_errors(tau, idyn(q, qd, qdd).detach())
    np.testing.assert_allclose(nmse.numpy(), report["validation"]["identified"]["nmse"], rtol=1e-9)
    np.testing.assert_allclose(rms.numpy(), report["validation"]["identified"]["rms"], rtol=1e-9)
    assert f"{report['validation']['identified']['mean_nmse']:.4g}" in stdout
    # the identified model predicts held-out torques, and on the neck joints (torques well
    # above the sensor noise) better than the description, which lacks the simulated robot's
    # friction and armature
    assert report["validation"]["identified"]["mean_nmse"] < 0.6
    neck = slice(0, 3)
    assert report["joint_names"][neck] == ["neck_pan", "neck_tilt", "neck_roll"]
    ident = np.array(report["validation"]["identified"]["nmse"][neck])
    assert (ident < np.array(report["validation"]["description"]["nmse"][neck])).all()
    assert report["stop_reason"] is not None
    # each joint's equations weighted by its inverse residual variance (the default)
    weights = report["noise"]["joint weights (weighted least squares, mean 1)"]
    assert len(weights) == 7 and np.mean(weights) == pytest.approx(1.0)
    assert report["settings"]["weighting"] == "residual"
    # the projection made the parameters consistent in the sense of eq. 5
    assert report["consistent_weakly"]
    # the parameter table: every parameter, with spread and relevance from Bayesian JFA
    params = report["parameters"]
    assert [p["parameter"] for p in params] == list(idyn.model.parameter_names)
    assert all(p["jackknife_std"] is not None and p["jackknife_std"] >= 0 for p in params)
    assert any(p["relevance"] is not None for p in params)
    md = (out / "report.md").read_text()
    for joint in idyn.model.joint_names:
        assert f"| {joint} |" in md
    assert "torchjfa identify head" in md
    extras = read_identified(out / "model.npz").extras
    np.testing.assert_allclose(
        extras["validation_nmse"], report["validation"]["identified"]["nmse"]
    )


def test_output_ard_reaches_the_estimator(head_csv, tmp_path, capsys):
    out = tmp_path / "ard"
    code, _, err = _identify(
        capsys, "head", head_csv, "--out", out, "--smoke", "--ard", "output",
        "--input-noise", "periods", "--no-project", *FAST,
    )  # fmt: skip
    assert code == 0, err
    settings = json.loads((out / "report.json").read_text())["settings"]
    assert "ard='output'" in settings["estimator"] and settings["input_noise"] == "periods"


def test_separate_validation_log_and_other_estimator(head_csv, tmp_path, capsys):
    vpath = tmp_path / "valid.parquet"
    assert (
        main(
            [
                "simulate",
                "head",
                "--out",
                str(vpath),
                "--n-samples",
                "2520",
                "--seed",
                "7",
                "--quiet",
            ]
        )
        == 0
    )
    out = tmp_path / "r"
    code, _, err = _identify(
        capsys,
        "head",
        head_csv,
        "--validation-log",
        vpath,
        "--estimator",
        "ols",
        "--out",
        out,
        "--weighting",
        "none",
        *FAST_OLS,
    )
    assert code == 0, err
    report = json.loads((out / "report.json").read_text())
    assert "separate log" in report["settings"]["validation"]
    assert all(p["relevance"] is None for p in report["parameters"])
    assert report["validation_samples"] < 2520
    assert "joint weights (weighted least squares, mean 1)" not in report["noise"]
    assert "## Appendix" not in (out / "report.md").read_text()
    code, _, err = _identify(
        capsys, "head", head_csv, "--validation-log", vpath, "--estimator", "ols", "--out",
        tmp_path / "a", "--weighting", "none", "--appendix", "--no-plots", *FAST_OLS,
    )  # fmt: skip
    assert code == 0, err
    assert "## Appendix" in (tmp_path / "a" / "report.md").read_text()


def test_compiled_regressor_gives_the_same_fit(head_csv, tmp_path, capsys, monkeypatch):
    if not any(shutil.which(c) for c in ("g++", "c++", "clang++")):
        pytest.skip("no C++ compiler")
    monkeypatch.setenv("TORCHJFA_CACHE_DIR", str(tmp_path / "kernels"))
    reports = []
    for flag in (("--no-compiled",), ("--compiled",)):
        out = tmp_path / flag[0].strip("-")
        code, _, err = _identify(
            capsys,
            "head",
            head_csv,
            *("--estimator", "ridge", "--weighting", "none", "--no-project", "--out", out),
            *flag,
            *FAST_OLS,
        )
        assert code == 0, err
        reports.append(json.loads((out / "report.json").read_text()))
    # ridge without projection: these few seconds of data leave OLS so ill-conditioned that
    # round-off changes its rank, and the projection's LBFGS path amplifies round-off too
    a, b = reports
    assert "--compiled" in b["settings"]["command"]
    assert b["train_rmse"] == pytest.approx(a["train_rmse"], rel=1e-9)
    va, vb = a["validation"]["unconstrained"]["nmse"], b["validation"]["unconstrained"]["nmse"]
    assert vb == pytest.approx(va, rel=1e-9)


@pytest.fixture()
def columns(head_csv):
    log = read_log(head_csv)
    return log, log.to_columns()


def _write(path, cols):
    names = list(cols)
    np.savetxt(path, np.column_stack([cols[c] for c in names]), delimiter=",",
               header=",".join(names), comments="", fmt="%.17g")  # fmt: skip
    return path


def test_missing_column(columns, tmp_path, capsys):
    _, cols = columns
    del cols["tau_neck_roll"]
    code, out, err = _identify(capsys, "head", _write(tmp_path / "m.csv", cols), *FAST)
    assert code == 2
    assert "missing column 'tau_neck_roll'" in err and "Traceback" not in err


def test_joint_the_robot_does_not_have(columns, tmp_path, capsys):
    _, cols = columns
    for kind in ("q", "qd", "tau"):
        cols[f"{kind}_jaw"] = cols[f"{kind}_neck_pan"]
    code, _, err = _identify(capsys, "head", _write(tmp_path / "j.csv", cols), *FAST)
    assert code == 2
    assert "['jaw'] are in the log but the robot has no joint" in err


def test_nan_rows_reported_and_dropped_on_request(columns, tmp_path, capsys):
    _, cols = columns
    cols["q_neck_tilt"] = cols["q_neck_tilt"].copy()
    cols["q_neck_tilt"][[10, 400]] = np.nan
    path = _write(tmp_path / "n.csv", cols)
    code, _, err = _identify(capsys, "head", path, *FAST)
    assert code == 2
    assert "2 of 5040 rows hold NaN or inf (rows 10, 400, counting" in err and "--drop-nan" in err
    code, _, err = _identify(capsys, "head", path, "--drop-nan", "--out", tmp_path / "o", *FAST)
    assert code == 0, err


def test_time_going_backwards(columns, tmp_path, capsys):
    _, cols = columns
    cols["t"] = cols["t"].copy()
    cols["t"][[100, 101]] = cols["t"][[101, 100]]
    code, _, err = _identify(capsys, "head", _write(tmp_path / "t.csv", cols), *FAST)
    assert code == 2
    assert "time must increase strictly, but at row 101" in err


def test_too_few_samples_for_the_parameters(columns, tmp_path, capsys):
    log, _ = columns
    short = log.select(slice(0, 10))  # 10 samples x 7 joints = 70 equations < 77 parameters
    path = tmp_path / "short.csv"
    write_log(short, path)
    code, _, err = _identify(capsys, "head", path, *FAST)
    assert code == 2
    assert "70 equations for 77 parameters" in err


def test_robot_file_that_does_not_parse(head_csv, tmp_path, capsys):
    bad = tmp_path / "broken.urdf"
    bad.write_text("<robot name='x'><link name='a'><inertial></link>")
    code, _, err = _identify(capsys, bad, head_csv, *FAST)
    assert code == 2
    assert "cannot build a robot model from" in err and "Traceback" not in err
    code, _, err = _identify(capsys, tmp_path / "nowhere.urdf", head_csv, *FAST)
    assert code == 2 and "no robot file" in err


def test_installed_command_help_and_clean_error(tmp_path):
    """The console script is installed, every command has --help, errors carry no traceback."""
    exe = shutil.which("torchjfa")
    cmd = [exe] if exe else [sys.executable, "-m", "torchjfa"]
    helps = [[*cmd, *sub, "--help"] for sub in ([], ["identify"], ["simulate"], ["evaluate"])]
    missing = [*cmd, "identify", "head", str(tmp_path / "nope.csv")]
    # all at once: each spends its time importing torch
    running = [subprocess.Popen(c, stdout=PIPE, stderr=PIPE, text=True) for c in [*helps, missing]]
    outputs = [p.communicate(timeout=120) for p in running]
    for p, (stdout, _) in zip(running[:-1], outputs[:-1], strict=True):
        assert p.returncode == 0 and "usage: torchjfa" in stdout
    assert running[-1].returncode == 2
    stderr = outputs[-1][1]
    assert "no log file" in stderr and "Traceback" not in stderr
    assert exe is not None, "pip install did not put the torchjfa command on PATH"


def test_evaluate_prints_per_joint_errors(tmp_path, capsys, head_csv):
    out = tmp_path / "r"
    code, _, err = _identify(capsys, "head", head_csv, "--out", out, *FAST)
    assert code == 0, err
    js = tmp_path / "eval.json"
    code = main(["evaluate", str(out / "model.npz"), "--robot", "head", "--n-samples", "2000",
                 "--control-seconds", "1", "--json", str(js), "--quiet"])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 0
    res = json.loads(js.read_text())
    assert len(res["nmse"]) == 7 and all(np.isfinite(res["nmse"]))
    assert "neck_pan" in text and "computed-torque control" in text
    code = main(["evaluate", str(out / "model.npz"), "--robot", "arm", "--quiet", "--no-control"])
    assert code == 2
    assert "are not the simulated arm's" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["truncated", "bit-flipped", "empty", "foreign"])
def test_evaluate_on_a_damaged_or_foreign_model_file_prints_one_line(kind, tmp_path, capsys):
    from torchjfa.dynamics import RigidBodyModel
    from torchjfa.io import save_identified
    from torchjfa.sim import model_path

    head = RigidBodyModel.from_mjcf(model_path("head"))
    good = tmp_path / "good.npz"
    save_identified(good, head, head.nominal_theta)
    blob = good.read_bytes()
    bad = {
        "truncated": blob[: len(blob) // 2],
        "bit-flipped": None,
        "empty": b"",
        "foreign": None,
    }[kind]
    if kind == "bit-flipped":  # a byte in the middle of the first member's compressed data
        n_name, n_extra = (int.from_bytes(blob[k : k + 2], "little") for k in (26, 28))
        start = 30 + n_name + n_extra  # the first local header is at 0 and 30 bytes long
        size = zipfile.ZipFile(io.BytesIO(blob)).infolist()[0].compress_size
        b = bytearray(blob)
        b[start + size // 2] ^= 0xFF  # the CRC-32 (or the deflate stream) catches it
        bad = bytes(b)
    elif kind == "foreign":
        np.savez(tmp_path / "other.npz", q=np.zeros((3, 7)))
        bad = (tmp_path / "other.npz").read_bytes()
    path = tmp_path / "model.npz"
    path.write_bytes(bad)
    code = main(["evaluate", str(path), "--robot", "head", "--quiet", "--no-control"])
    out = capsys.readouterr()
    assert code == 2
    lines = out.err.strip().splitlines()
    assert len(lines) == 1, out.err
    assert lines[0].startswith("torchjfa evaluate: error: ")
    assert "not a torchjfa model file, or it is damaged" in lines[0]
    assert "Traceback" not in out.err and out.out == ""


def _option_blocks(help_text: str) -> dict[str, str]:
    """Each option's entry in ``--help`` (its first line and the indented lines after it), by
    the option's first name, with the line breaks of the wrapping removed."""
    blocks: dict[str, list[str]] = {}
    name = None
    for line in help_text.splitlines():
        if line.startswith("  -"):
            name = line.split()[0].rstrip(",")
            blocks[name] = [line]
        elif name is not None and line.startswith("   "):
            blocks[name].append(line)
        else:
            name = None
    return {k: " ".join(" ".join(v).split()) for k, v in blocks.items()}


def _shown(default) -> str:
    if isinstance(default, tuple):
        return ",".join(map(str, default)) or "none"
    return f"{default:g}" if isinstance(default, float) else str(default)


def test_help_of_every_command_shows_every_default():
    parser = build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert {"identify", "simulate", "evaluate"} <= set(commands.choices)
    checked = 0
    for name, sub in commands.choices.items():
        blocks = _option_blocks(sub.format_help())
        for action in sub._actions:
            if not action.option_strings or action.help == argparse.SUPPRESS:
                continue
            block = blocks[action.option_strings[0]]
            if action.nargs == 0:  # a flag: off unless given, and its help says what it does
                assert len(block.split()) > 1, (name, action.option_strings)
                continue
            if action.default is None:
                continue
            assert f"(default: {_shown(action.default)})" in block, (name, block)
            assert block.count("(default") == 1, (name, block)
            checked += 1
    assert checked >= 23  # 17 options with a default in identify, 3 in simulate, 3 in evaluate
    identify = _option_blocks(commands.choices["identify"].format_help())
    assert "shortcut for --estimator-options max_iter=N" in identify["--max-iter"]
    assert identify["--friction"].endswith("(default: viscous,coulomb,offset)")
    assert identify["--cutoff"].endswith("(default: auto)")
    assert identify["--parametrization"].endswith("(default: log-cholesky)")
    assert identify["--estimator"].endswith("(default: ols)")


def test_description_prior_option(head_csv, tmp_path, capsys):
    out = tmp_path / "prior"
    code, stdout, err = _identify(
        capsys, "head", head_csv, "--out", out, "--smoke", *FAST_OLS, "--estimator", "ols",
        "--description-prior", "10",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((out / "report.json").read_text())
    assert summary["prior_weight"] == 10.0
    assert summary["base_parameters"]["rank"] > 0
    assert "## What the data determine" in (out / "report.md").read_text()
    for bad in (["--description-prior", "-1"], ["--description-prior", "x"]):
        with pytest.raises(SystemExit) as exc:
            main(["identify", "head", str(head_csv), "--out", str(out), *bad])
        assert exc.value.code == 2
        assert "expected 'auto' or a weight >= 0" in capsys.readouterr().err
    code, _, err = _identify(
        capsys, "head", head_csv, "--out", out, "--no-project", "--description-prior", "auto"
    )
    assert code == 2 and "drop --no-project" in err and "Traceback" not in err
