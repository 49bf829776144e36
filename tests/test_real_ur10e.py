"""The real UR10e campaign (../shared/data/ur10e_mamedov2020): motor currents with drive gains,
several logs, rest at their ends. Skipped where the logs are absent (they are not shipped)."""

import io
from pathlib import Path

import pytest

from torchjfa.data import LogError, read_log

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur10e_mamedov2020"

pytestmark = pytest.mark.skipif(
    not (DATA / "robot.urdf").is_file(), reason=f"no UR10e logs in {DATA}"
)


def test_currents_without_gains_are_refused_in_one_line():
    path = sorted(DATA.glob("ident_ur-*.csv"))[0]
    with pytest.raises(LogError, match="drive") as err:
        read_log(path)
    assert "\n" not in str(err.value)


def test_the_script_runs_in_smoke_size():
    import real_ur10e as script

    out = io.StringIO()
    res = script.run(DATA, smoke=True, out=out)
    rows = res["rows"]
    assert set(rows) >= {"defaults", "description"} and len(rows) == 3
    # the description's inertials without friction predict the currents far worse than any
    # fit: the motors' friction and the rotor inertia are a large part of them
    mean = {k: sum(v) / len(v) for k, v in rows.items()}
    assert mean["defaults"] < 0.5 * mean["description"]
    assert res["consistent"]
    # every log starts and ends at rest (the dataset's README): each one's rest is dropped
    # and reported, and every log gives training and held-out samples
    assert len(res["logs"]) == 2 * script.SMOKE_LOGS  # identification parts, then held-out
    assert all(r["rest_dropped_s"][0] > 0 for r in res["logs"][: script.SMOKE_LOGS])
    assert all(r["rest_dropped_s"][1] > 0 for r in res["logs"][script.SMOKE_LOGS :])
    # real channels with the README's gains: no joint is flagged as measured the wrong way
    assert not any("runs against" in w for w in res["warnings"])
    assert "defaults / hand-tuned mean RMS" in out.getvalue()
    assert res["ratio"] > 0


def test_the_payloads_of_the_loaded_runs_are_found_and_explain_their_torques():
    """Both ways of `identify_payload` on both loaded runs: a positive mass of the right order
    (the dataset's README: 2.602 and 2.805 kg) that lowers the loaded run's held-out error."""
    import real_ur10e as script

    rows = script.payloads(DATA, out=io.StringIO())
    assert len(rows) == 2 * len(script.PAYLOADS)
    for r in rows:
        assert 0.5 * r["known"] < r["mass"] < 1.5 * r["known"]
        assert r["rms_with"] < 0.5 * r["rms_without"]
