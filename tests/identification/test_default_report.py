"""The default `torchjfa identify` on a simulated log gives the stored report: every number of
``report.json`` to 1e-10 relative.

``data/head_default_report.json`` was written by ``torchjfa identify head head.csv`` (all
defaults) on ``torchjfa simulate head --n-samples 5040``; the paths, the command line and the
wall time are left out. A change in the numbers means a change in behaviour: MuJoCo's
simulation or the flow itself (regenerate the file only for a change meant to move them, and
say so in the CHANGELOG). Entries the file does not hold (``verdict``) are not compared.

The same run's ``report.md`` (a 7-joint robot) reads in a minute: the verdict first, under 80
lines, every count of what the data determine the same, and ``parameters.csv`` marks what the
data do not determine.
"""

import csv
import json
import math
import re
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
def folder(tmp_path_factory):
    """The report folder of the default run (figures included: the report as users get it)."""
    folder = tmp_path_factory.mktemp("golden")
    log, out = folder / "head.csv", folder / "rep"
    assert main(["simulate", "head", "--out", str(log), "--n-samples", "5040", "--quiet"]) == 0
    assert main(["identify", "head", str(log), "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def report(folder):
    return json.loads((folder / "report.json").read_text())


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


def _counts(md: str) -> dict[str, tuple[int, ...]]:
    """The counts of what the data determine, as the verdict and the section say them."""
    verdict = re.search(
        r"Not determined by the data alone: (\d+) of (\d+) parameters \((\d+) only in "
        r"combinations, (\d+) poorly excited, (\d+) not excited\)",
        md,
    )
    section = re.search(
        r"- parameters: (\d+) determined by the data alone, (\d+) only in combinations with "
        r"others, (\d+) poorly excited .*, (\d+) not excited .*: (\d+) in all",
        md,
    )
    return {
        "verdict": tuple(int(x) for x in verdict.groups()),
        "section": tuple(int(x) for x in section.groups()),
    }


def test_the_default_report_reads_in_a_minute(folder, report):
    md = (folder / "report.md").read_text()
    lines = md.splitlines()
    assert lines[:3] == ["# Identification report: head", "", "## Verdict"]
    assert len(lines) < 80, len(lines)
    assert lines[4].startswith("- **Better than the description by ")
    assert any(line.startswith("- **Next step**: ") for line in lines[4:16])
    joints = report["joint_names"]
    assert len(joints) == 7
    for joint in joints:  # a row each, the name in full
        assert sum(line.startswith(f"| {joint} | ") for line in lines) == 2  # torques, noise
    assert "Target: the measured torque, unfiltered" in md
    cutoff = report["settings"]["prepare"]["cutoff_hz"]
    assert f"training data (filtered at {cutoff:g} Hz)" in md  # the noise table's heading
    assert f"(torque filtered at {cutoff:g} Hz, each joint's residual times its weight)" in md
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b|\bissue \d|#\d|\bsession\b", md)


def test_the_counts_agree_everywhere(folder, report):
    md = (folder / "report.md").read_text()
    found = _counts(md)
    n_not, n, comb, poor, silent = found["verdict"]
    det, comb2, poor2, silent2, n2 = found["section"]
    counts = report["base_parameters"]["counts"]
    assert (n, n2) == (report["n_params"], report["n_params"])
    assert (comb, poor, silent) == (comb2, poor2, silent2)
    assert (det, comb, poor, silent) == (
        counts["determined"], counts["combination"], counts["poorly excited"],
        counts["not excited"],
    )  # fmt: skip
    assert n_not == n - det == report["verdict"]["n_not_determined"]
    params = report["parameters"]
    assert sum(not p["excited"] for p in params) == silent  # one "not excited" count
    assert sum(not p["determined"] for p in params) == n_not
    with open(folder / "parameters.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert sum(r["determined"] == "False" for r in rows) == n_not
    assert sum(r["data"] == "not excited" for r in rows) == silent


def test_parameters_csv_leaves_no_zero_for_what_the_data_do_not_give(folder):
    with open(folder / "parameters.csv") as fh:
        rows = list(csv.DictReader(fh))
    silent = [r for r in rows if r["data"] == "not excited"]
    assert silent, "the head's first body turns about a fixed axis"
    for r in silent:
        # the description prior fills them; the estimator's 0 and its spread are left empty
        assert r["source"] == "description" and r["determined"] == "False"
        assert r["unconstrained"] == r["jackknife_std"] == ""
        assert float(r["identified"]) != 0.0 or float(r["description"]) == 0.0
    for r in rows:
        assert (r["source"] == "data") == (r["determined"] == "True")
