"""The smoke run of scripts/sim_payload.py: payloads on a simulated Panda and UR5 found by
`identify_payload` with an identified robot model (the full run's numbers are the script's)."""

import importlib.metadata
import io
import math

import numpy as np
import pytest
import sim_payload as script

try:
    importlib.metadata.distribution("example-robot-data")
    HAVE_ERD = True
except importlib.metadata.PackageNotFoundError:
    HAVE_ERD = False


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = io.StringIO()
    res = script.run(
        ("panda", "ur5"),
        (0,),
        seconds=script.PERIOD,
        out=tmp_path_factory.mktemp("sim_payload"),
        smoke=True,
        stream=out,
    )
    return res, out.getvalue()


def _robots():
    return ["panda", "ur5"] if HAVE_ERD else ["panda"]


@pytest.mark.slow  # the smoke run simulates, identifies and excites two robots: about a minute
@pytest.mark.parametrize("robot", ["panda", "ur5"])
def test_a_heavy_payload_is_found_both_ways(smoke, robot):
    if robot not in _robots():
        pytest.skip("example-robot-data is not installed")
    res, text = smoke
    got = res["robots"][robot]
    assert got["excitation"].startswith("optimised")  # the excitation API as the script uses it
    (heavy,) = got["rows"]
    assert heavy["payload"] == script.SMOKE_PAYLOADS[robot] and heavy["true_mass"] == 5.0
    for way in script.WAYS:
        e = heavy[way]
        assert math.isfinite(e["mass"]) and all(math.isfinite(c) for c in e["com"])
        # the projection keeps the body physically consistent
        assert all(m > 0 for m in e["moments"])
        # one period with realistic noise: the mass within 2 %, the centre of mass within 5 mm
        # (the full run's criteria are 1 % and 5 mm over six periods)
        assert abs(e["mass_err_pct"]) < 2.0, (robot, way, e)
        assert e["com_err_mm"] < 5.0, (robot, way, e)
    # the peak torque against the effort limit, worst joint: more with the payload than without
    assert heavy["effort"] > got["seeds"][0]["effort"] > 0
    assert f"\n{robot}: " in text


@pytest.mark.slow
def test_the_table_and_the_verdicts_are_printed(smoke):
    res, text = smoke
    assert "pair: mass %" in text and "robot: mass %" in text
    for label in [*_robots(), "all rows"]:
        assert f"{label}: mass within 1 %" in text
        assert f"{label}: centre of mass within 5 mm" in text
        assert f"{label}: principal moments within 20 %" in text
    for way in script.WAYS:
        v = res["overall"][way]
        assert v["mass"] == (v["mass_pct"] <= script.MASS_PCT)
        assert v["com"] == (v["com_mm"] <= script.COM_MM)
    if not HAVE_ERD:
        assert res["robots"]["ur5"]["skipped"] and "ur5: skipped" in text


def test_the_payload_inertia_is_the_solid_body_turned():
    """A cylinder's principal moments are its own, whatever its axes turned by."""
    body = next(b for b in script.PAYLOADS if b.shape == "cylinder" and b.mass == 5.0)
    r, h = body.size
    m = body.mass
    want = sorted([0.5 * m * r * r, m * (3 * r * r + h * h) / 12, m * (3 * r * r + h * h) / 12])
    assert np.allclose(np.linalg.eigvalsh(body.inertia()), want)
    assert not np.allclose(body.inertia(), np.diag(np.diag(body.inertia())))
