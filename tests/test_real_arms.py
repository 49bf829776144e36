"""The single-log real-arm scripts (``scripts/real_lwr4.py``, ``scripts/real_tx40.py``) and what
the library finds on those logs. Skipped where a log is absent (they are not shipped)."""

import dataclasses
import importlib.util
import io
import sys
from pathlib import Path

import pytest
import torch

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _load(name: str):
    if str(SCRIPTS) not in sys.path:  # the scripts import their shared module by name
        sys.path.insert(0, str(SCRIPTS))
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module", params=["real_lwr4", "real_tx40"])
def arm(request):
    return _load(request.param).ARM


def _needs(arm) -> None:
    if not (arm.folder / arm.log).is_file():
        pytest.skip(f"no {arm.title} log in {arm.folder}")


def test_the_script_runs_in_smoke_size(arm):
    _needs(arm)
    import _real_arm

    out = io.StringIO()
    result = _real_arm.last_part(arm, smoke=True, out=out)
    text = out.getvalue()
    assert result["consistent"] is True
    assert 0.0 < result["defaults"] < 10.0 and 0.0 < result["hand"] < 10.0  # N m
    assert result["ratio"] == pytest.approx(result["defaults"] / result["hand"])
    rows = [line.split() for line in text.splitlines()]
    labels = ("defaults", "description", "hand-tuned")
    table = [r for r in rows if r and r[0] in labels and r[1] not in ("/", "cut-offs")]
    n_dof = 7 if arm.name == "real_lwr4" else 6
    # a row: its label, each joint's RMS, the mean and the unfiltered mean (and the norm %)
    assert len(table) == 3 and all(len(r) >= n_dof + 3 for r in table)
    assert "SMOKE" in text


def test_the_script_says_so_without_the_log(arm, tmp_path):
    import _real_arm

    out = io.StringIO()
    assert _real_arm.last_part(dataclasses.replace(arm, folder=tmp_path), out=out) is None
    assert "nothing to do" in out.getvalue()


def test_the_normalised_error_is_flobaroids():
    import _real_arm

    lwr = _load("real_lwr4").ARM
    # RMS of 1 % of twice each joint's limit on every joint: 1 %
    r = 0.02 * torch.tensor(lwr.limits, dtype=torch.float64)
    assert _real_arm.normalised(lwr, r) == pytest.approx(1.0, rel=1e-12)
    assert _real_arm.normalised(_load("real_tx40").ARM, r[:6]) != _real_arm.normalised(lwr, r)


def test_the_tx40s_coupled_wrist_is_named_without_its_drive_train(tmp_path):
    """Motor 6 of the real TX40 turns joints 5 and 6: without the drive train the log names
    that pair (and no other); with it, nothing."""
    tx40 = _load("real_tx40")
    _needs(tx40.ARM)
    from torchjfa.data import coupled_drives, read_log
    from torchjfa.identification import load_model

    robot = tx40.ARM.folder / tx40.ARM.robot
    plain = load_model(robot)
    log = read_log(tx40.ARM.folder / tx40.ARM.log).reorder(plain.joint_names)
    found = coupled_drives(plain, log, 20.0)
    assert [f.joints for f in found] == [("joint_5", "joint_6")]
    geared = load_model(robot, transmission=tx40.write_transmission(tmp_path))
    assert coupled_drives(geared, log, 20.0) == []
