"""`scripts/real_rollouts.py` in smoke size: rows for the real logs present, finite errors that
grow with the horizon. Skipped where no real log is present (they are not shipped)."""

import io
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"

pytestmark = pytest.mark.skipif(
    not (SHARED / "ur10e_mamedov2020" / "robot.urdf").is_file()
    and not (SHARED / "panda_gaz2019" / "time.txt").is_file(),
    reason=f"no real logs in {SHARED}",
)


def test_the_script_runs_in_smoke_size():
    import real_rollouts as script

    out = io.StringIO()
    rows = script.run(smoke=True, out=out)
    assert rows
    for r in rows:
        assert r["horizons"] == (0.05, 0.2, 0.5)
        for name in ("identified", "description"):
            err = np.asarray(r[name])
            assert np.isfinite(err).all() and err[-1] > err[0] > 0
        assert "200 ms position error" in out.getvalue()
    ur = [r for r in rows if r["robot"].startswith("ur10e")]
    if ur:  # the description has no rotor inertia: the currents fling its links away
        assert ur[0]["ratio_200ms"] < script.GOAL
