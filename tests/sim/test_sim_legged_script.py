"""The smoke run of scripts/sim_legged.py: it runs, prints its eight fits, and the library's fit
with measured forces (with and without the IMU) beats least squares on held-out torques with
every body consistent."""

import importlib.util
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
    kinds = ("forces", "flags", "forces + IMU", "flags + IMU")
    assert set(rows) == {(k, f) for k in kinds for f in ("reference", "torchjfa")}
    for kind in ("forces", "forces + IMU"):
        ours = rows[(kind, "torchjfa")]
        assert float(ours[2]) < 1.0 and ours[4] == "yes"  # ratio to the reference; consistent
    assert rows[("flags", "torchjfa")][4] == "yes" and rows[("flags + IMU", "torchjfa")][4] == "yes"
