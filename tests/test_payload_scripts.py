"""Smoke runs of the payload scripts: drive gains of the real UR10e from a known payload
(skipped without its logs) and the payload excitation on a simulated Panda. Both are marked
slow (a minute or more each); the full runs' numbers are the scripts'."""

import io

import pytest
import real_ur10e_gains
import sim_payload_excitation


@pytest.mark.slow
@pytest.mark.skipif(
    not (real_ur10e_gains.DATA / real_ur10e_gains.CHECK_PAIR[0]).is_file(),
    reason="no UR10e logs",
)
def test_the_gains_script_finds_gains_and_judges_both_sets():
    out = io.StringIO()
    res = real_ur10e_gains.run(smoke=True, out=out)
    joints = res["gains"]["joints"]
    assert len(joints) == 6 and all(j["gain"] > 0 and j["std"] >= 0 for j in joints.values())
    for name in ("README", "identified"):
        for way in ("pair", "robot"):
            assert res[name][way]["mass"] > 0 and len(res[name][way]["current_rms"]) == 6
    assert "not used above" in out.getvalue()


@pytest.mark.slow
def test_the_payload_excitation_script_runs_both_excitations(tmp_path):
    out = io.StringIO()
    rows = sim_payload_excitation.run(tmp_path, seconds=(4.0,), seeds=(0,), smoke=True, stream=out)
    assert {r["excitation"] for r in rows} == {"robot", "payload"}
    # a 2 kg box found from 4 s of either: the mass within a few per cent
    assert all(abs(r["mass_err_pct"]) < 5.0 for r in rows), rows
    assert "payload" in out.getvalue()
