"""The mistakes a user makes with a real log's format and units, on the command line: each is
read and reported, or ends with one line and exit status 2."""

import json

import numpy as np
import pytest

from torchjfa.cli import main
from torchjfa.data import JointLog, write_log
from torchjfa.sim import generate_log

QUICK = ["--cutoff", "15", "--jackknife", "0", "--bias-correction", "0", "--no-project",
         "--quiet", "--no-plots"]  # fmt: skip


@pytest.fixture(scope="module")
def log():
    sim = generate_log("head", n_samples=2100, seed=3, progress=False)
    return JointLog(t=sim.t, q=sim.q, qd=sim.qd, tau=sim.tau, joint_names=sim.joint_names)


def _identify(capsys, robot, path, out, *extra):
    code = main(["identify", robot, str(path), "--out", str(out), *QUICK, *extra])
    return code, capsys.readouterr()


def _columns(log: JointLog) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in log.to_columns().items()}


def test_time_in_milliseconds_is_read_and_the_report_says_so(log, tmp_path, capsys):
    cols = _columns(log)
    cols["t"] = cols["t"] * 1e3
    path = tmp_path / "ms.csv"
    import pyarrow as pa
    from pyarrow import csv

    csv.write_csv(pa.table(cols), path)
    code, io = _identify(capsys, "head", path, tmp_path / "r")
    assert code == 0
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    notes = [w for w in report["settings"]["warnings"] if "milliseconds" in w]
    assert len(notes) == 1 and "--time-scale" in notes[0]
    assert "milliseconds" in io.err


def test_velocities_in_degrees_per_second_end_with_one_line(log, tmp_path, capsys):
    deg = JointLog(t=log.t, q=log.q, qd=log.qd * 180 / np.pi, tau=log.tau,
                   joint_names=log.joint_names)  # fmt: skip
    path = tmp_path / "deg.csv"
    write_log(deg, path)
    code, io = _identify(capsys, "head", path, tmp_path / "r")
    lines = io.err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "deg/s" in lines[0]


def test_semicolons_decimal_commas_and_column_patterns_are_read(log, tmp_path, capsys):
    """A ';' file with decimal commas and its own column names (mapped by a pattern) gives the
    identification of the plain CSV."""
    cols = _columns(log)
    renamed = {("time" if k == "t" else k.replace("tau_", "effort_").replace("q_", "pos_")): v
               for k, v in cols.items()}  # fmt: skip
    names = list(renamed)
    rows = [";".join(names)]
    for i in range(len(cols["t"])):
        rows.append(";".join(repr(float(renamed[n][i])).replace(".", ",") for n in names))
    semi = tmp_path / "semi.csv"
    semi.write_text("\n".join(rows) + "\n")
    plain = tmp_path / "plain.csv"
    write_log(log, plain)
    mapping = "t=time,q_{joint}=pos_{joint},tau_{joint}=effort_{joint}"
    code, _ = _identify(capsys, "head", semi, tmp_path / "a", "--columns", mapping)
    assert code == 0
    assert _identify(capsys, "head", plain, tmp_path / "b")[0] == 0
    a, b = (json.loads((tmp_path / d / "report.json").read_text()) for d in "ab")
    ua = [r["unconstrained"] for r in a["parameters"]]
    ub = [r["unconstrained"] for r in b["parameters"]]
    assert np.allclose(ua, ub, rtol=1e-9, atol=1e-12 * max(map(abs, ub)))
    # a mapping that names missing columns lists them all in one line
    code, io = _identify(capsys, "head", semi, tmp_path / "c", "--columns", "q_{joint}=p_{joint}")
    lines = io.err.strip().splitlines()
    assert code == 2 and len(lines) == 1
