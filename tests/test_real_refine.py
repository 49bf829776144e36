"""The smoke run of scripts/real_refine.py on the real UR10e and Panda logs (skipped where they
or the sysid extra are absent; slow: it identifies two robots and fits both)."""

import io

import pytest

pytest.importorskip("mujoco.sysid._src.optimize", reason='no mujoco[sysid]: "torchjfa[sysid]"')
import real_refine  # noqa: E402


@pytest.mark.slow
def test_the_smoke_run_prints_every_robot_it_has_logs_of():
    out = io.StringIO()
    rows = real_refine.run(smoke=True, out=out)
    if not rows:
        pytest.skip("no real logs")
    text = out.getvalue()
    for row in rows:
        assert row["robot"].split()[0] in text
    assert "refined/identified" in text
