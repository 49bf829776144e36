"""The default `torchjfa identify` on a simulated log gives the stored report: every number of
``report.json`` to 1e-10 relative.

``data/head_default_report.json`` was written by ``torchjfa identify head head.csv`` (all
defaults) on ``torchjfa simulate head --n-samples 5040``; the paths, the command line and the
wall time are left out. A change in the numbers means a change in behaviour: MuJoCo's
simulation or the flow itself (regenerate the file only for a change meant to move them, and
say so in the CHANGELOG).
"""

import json
import math
from pathlib import Path

import pytest

from torchjfa.cli import main

GOLDEN = Path(__file__).parent / "data" / "head_default_report.json"
RTOL = 1e-10
SKIP = {("settings", "command"), ("settings", "log"), ("settings", "identify_seconds")}


def _leaves(x, path=()):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, (*path, str(k)))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, (*path, i))
    else:
        yield path, x


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    folder = tmp_path_factory.mktemp("golden")
    log, out = folder / "head.csv", folder / "rep"
    assert main(["simulate", "head", "--out", str(log), "--n-samples", "5040", "--quiet"]) == 0
    code = main(["identify", "head", str(log), "--out", str(out), "--no-plots", "--quiet"])
    assert code == 0
    return json.loads((out / "report.json").read_text())


def test_the_default_report_on_a_simulated_log_is_unchanged(report):
    golden = json.loads(GOLDEN.read_text())
    want = {p: v for p, v in _leaves(golden) if p[:2] not in SKIP}
    got = {p: v for p, v in _leaves(report) if p[:2] not in SKIP}
    assert set(got) >= set(want), sorted(set(want) - set(got))[:5]
    # each top-level entry's values on one scale, so that a parameter at round-off (0 +- 1e-17)
    # is compared to its entry's largest value, not to itself
    scale: dict[str, float] = {}
    for p, v in want.items():
        if isinstance(v, float) and math.isfinite(v):
            scale[p[0]] = max(scale.get(p[0], 0.0), abs(v))
    wrong = []
    for p, v in want.items():
        g = got[p]
        if isinstance(v, float) and not isinstance(g, bool):
            if math.isnan(v):
                ok = isinstance(g, float) and math.isnan(g)
            else:
                ok = abs(g - v) <= RTOL * max(abs(v), 1e-6 * scale[p[0]])
        elif isinstance(v, str) and p[0] in ("settings", "estimator"):
            ok = True  # the settings' words may name the restructured stages
        else:
            ok = g == v
        if not ok:
            wrong.append((p, v, g))
    assert not wrong, f"{len(wrong)} of {len(want)} values moved, e.g. {wrong[:5]}"
