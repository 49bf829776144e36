"""The smoke run of scripts/sim_legged.py: it runs, prints its four fits, and the library's fit
with measured forces beats least squares on held-out torques with every body consistent."""

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
    rows = {tuple(ln.split()[:2]): ln.split() for ln in lines if ln.startswith(("forces", "flags"))}
    assert set(rows) == {(k, f) for k in ("forces", "flags") for f in ("reference", "torchjfa")}
    ours = rows[("forces", "torchjfa")]
    assert float(ours[3]) < 1.0 and ours[5] == "yes"  # ratio to the reference; consistent
    assert rows[("flags", "torchjfa")][5] == "yes"
