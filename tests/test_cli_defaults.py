"""`torchjfa identify` with its defaults: a cut-off chosen from the data, Coulomb and offset
friction, log-Cholesky (full consistency), OLS; one consistency verdict in the report."""

import json
import re

import numpy as np
import pytest

from torchjfa.cli import main
from torchjfa.data import COULOMB_GRID
from torchjfa.io import read_identified

#: the tests after the first are not about the bias correction: none (20 refits by default)
NO_SIMEX = ["--bias-correction", "0"]


def _identify(capsys, *args):
    code = main(["identify", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def _verdicts(md: str) -> tuple[str, str]:
    """The header's verdict of the identified parameters and the consistency table's."""
    (header,) = re.findall(r"physically consistent, identified: (yes|no \(\d+ of \d+)", md)
    (table,) = re.findall(r"physically consistent: (yes|no \(\d+ of \d+)", md)
    return header, table


def test_the_defaults_choose_the_cut_off_and_model_coulomb_and_offset(default_run):
    """On the session's default run (tests/conftest.py: every default, the cut-off choice
    watched), the run the golden report checks number by number."""
    out = default_run.folder
    report = json.loads((out / "report.json").read_text())
    cutoff = report["settings"]["prepare"]["cutoff_hz"]
    # one of the default grid's cut-offs (2..30 Hz), below the 420 Hz log's Nyquist frequency
    assert 2.0 <= cutoff <= 30.0
    md = (out / "report.md").read_text()
    assert f"- cut-off: {cutoff:g} Hz, chosen by held-out torque prediction over 2..30 Hz" in md
    assert "estimator: `OLS(" in md
    assert "friction viscous, coulomb, offset" in md
    # the Coulomb term's smoothing velocity is chosen with the cut-off and kept in the model
    v_c = report["settings"]["coulomb_velocity"]
    assert v_c in COULOMB_GRID and f"v_c = {v_c:g} rad/s" in md
    assert read_identified(out / "model.npz").model.coulomb_velocity == v_c
    # log-Cholesky: fully consistent, and the header says the table's verdict
    assert report["consistent"]
    assert _verdicts(md) == ("yes", "yes")
    assert "physically consistent: yes" in default_run.stdout
    # the choice saw none of the held-out part
    with np.load(out / "validation.npz") as z:
        first_held_out = float(z["t"][0])
    (last_seen,) = default_run.seen
    assert last_seen < first_held_out


def test_the_header_verdict_is_the_tables_with_virtual_parameters(head_csv, tmp_path, capsys):
    out = tmp_path / "v"
    code, stdout, err = _identify(
        capsys, "head", head_csv, "--out", out, "--smoke", "--quiet", "--jackknife", "0",
        "--no-plots", "--parametrization", "virtual", "--cutoff", "20", *NO_SIMEX,
    )  # fmt: skip
    assert code == 0, err
    md = (out / "report.md").read_text()
    header, table = _verdicts(md)
    assert header == table
    report = json.loads((out / "report.json").read_text())
    assert header.startswith("yes") == report["consistent"]


def test_a_log_too_short_to_choose_falls_back_with_a_warning(head_csv, tmp_path, capsys):
    # 5 s: the training part (4 s) is shorter than the 5 s that 3 blocks and the 1 s reach of
    # the 2 Hz filter need
    code, _, err = _identify(
        capsys, "head", head_csv, "--out", tmp_path / "s", "--max-seconds", "5",
        "--quiet", "--jackknife", "0", "--no-plots", *NO_SIMEX,
    )  # fmt: skip
    assert code == 0, err
    assert "warning: --cutoff auto:" in err and "too short to choose a cut-off" in err
    assert "20 Hz used" in err
    # the Coulomb term's smoothing velocity is still chosen from the data, at 20 Hz (its
    # held-out blocks need only the 20 Hz filter's short reach)
    report = (tmp_path / "s" / "report.md").read_text()
    assert "cut-off: 20 Hz, the default: the log is too short to choose one" in report
    assert "smoothing velocity tanh(qd / v_c) chosen at it" in report


@pytest.mark.parametrize("bad", ["0", "-3", "fast", "inf"])
def test_a_bad_cut_off_is_refused(head_csv, tmp_path, capsys, bad):
    with pytest.raises(SystemExit) as exc:
        main(["identify", "head", str(head_csv), "--out", str(tmp_path), "--cutoff", bad])
    assert exc.value.code == 2
    assert "expected 'auto' or a positive cut-off in Hz" in capsys.readouterr().err


@pytest.mark.parametrize("bad", ["-0.1", "fast", "inf"])
def test_a_bad_coulomb_velocity_is_refused(head_csv, tmp_path, capsys, bad):
    with pytest.raises(SystemExit) as exc:
        main(["identify", "head", str(head_csv), "--out", str(tmp_path), "--coulomb-velocity", bad])
    assert exc.value.code == 2
    assert "expected 'auto' or a smoothing velocity >= 0" in capsys.readouterr().err
