"""The smoke run of scripts/sim_legged.py: it runs, prints its ten fits, and the library's fit
with measured forces (with and without the IMU) beats least squares on held-out torques with
every body consistent."""

import importlib.util
import math
from pathlib import Path

import pytest
from _robots import erd_path

SCRIPT = Path(__file__).parents[2] / "scripts" / "sim_legged.py"


def test_sim_legged_smoke(capsys):
    pytest.importorskip("pinocchio")
    erd_path("go2_description/urdf/go2.urdf")
    spec = importlib.util.spec_from_file_location("sim_legged", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--smoke"]) == 0
    lines = capsys.readouterr().out.splitlines()
    # a row: its contact information (20 columns), the fit, RMS, ratio, mass error, consistent
    rows = {(ln[:20].strip(), ln[20:].split()[0]): ln[20:].split() for ln in lines
            if ln.startswith(("forces", "flags"))}  # fmt: skip
    kinds = ("forces", "flags", "forces + IMU", "flags + IMU", "flags, stepping")
    assert set(rows) == {(k, f) for k in kinds for f in ("reference", "torchjfa")}
    for kind in ("forces", "forces + IMU"):
        ours = rows[(kind, "torchjfa")]
        assert float(ours[2]) < 1.0 and ours[4] == "yes"  # ratio to the reference; consistent
    for kind in ("flags", "flags + IMU", "flags, stepping"):
        assert rows[(kind, "torchjfa")][4] == "yes"


def test_sim_legged_estimators_smoke(capsys):
    """The estimators' comparison runs: least squares and Bayesian JFA (given the propagated
    noise), each with forces and with flags, one row each with finite figures."""
    erd_path("go2_description/urdf/go2.urdf")
    path = SCRIPT.with_name("sim_legged_estimators.py")
    spec = importlib.util.spec_from_file_location("sim_legged_estimators", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--smoke"]) == 0
    rows = [ln.split() for ln in capsys.readouterr().out.splitlines() if ln.startswith("x3 ")]
    assert [(r[1], r[2]) for r in rows] == [
        ("forces", "ols"), ("forces", "bayes-jfa"), ("flags", "ols"), ("flags", "bayes-jfa"),
    ]  # fmt: skip
    for r in rows:
        assert all(math.isfinite(float(x.rstrip("%"))) for x in r[3:])
