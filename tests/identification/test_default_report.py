"""The default `torchjfa identify` on a simulated log gives the stored report: every number of
``report.json`` to the round-off of its computation.

``data/head_default_report.json`` was written by ``torchjfa identify head head.csv`` (all
defaults) on ``torchjfa simulate head --n-samples 5040``; the paths, the command line and the
wall time are left out. A change in the numbers means a change in behaviour: MuJoCo's
simulation or the flow itself (regenerate the file only for a change meant to move them, and
say so in the CHANGELOG). Entries the file does not hold (``verdict``) are not compared.

Tolerances, from the arithmetic of the run (float64, eps = 2.2e-16):

- The data's path (filter, least squares, SIMEX, jackknife, the unconstrained estimate and
  its errors), `RTOL` of each value. The positions are filtered at the chosen cut-off (13.8
  Hz) and differentiated twice: round-off in them reaches the accelerations amplified by
  about (f_c / f_0)^2 = 190 against the motion's ~1 Hz. The least-squares solve through the
  normal equations amplifies a relative error of its rows by kappa^2, with kappa = 271 the
  base parameters' condition number (the report's own). So kappa^2 (f_c / f_0)^2 eps = 3e-9;
  `RTOL` is three times that. (Measured once: one ulp of change in every q, qd and tau moves
  these values by at most 3e-9; one torch thread instead of two by at most 1e-12.)
- The projection's answer (the ``identified`` parameters and what is computed from them: the
  held-out and training errors of the identified model), `PROJECTED`. It is a semidefinite
  program polished by LBFGS that stops when a cycle gains less than tol = 1e-5 of the
  objective, floored at 1e-3 of its value at theta = 0 (torchjfa.physical.project): the
  objective is settled to tol * 1e-3 = 1e-8 of that value, and the parameters, about which it
  is quadratic with a curvature of one over their physical scale squared (the description
  prior's units, weight 100 here), to sqrt(1e-8) = 1e-4 of their scales: each kind's root
  mean square in the description (friction: in the identified values). The torque errors of
  the identified model are compared to 1e-4 of their own value.
- The base parameters' combinations, printed to four significant digits: the same names, the
  coefficients to one unit of the last digit (one ulp of change in the log rounds one of them
  the other way).

Changes the report is there to catch move far more: a cut-off of 15 Hz instead of the chosen
13.8 Hz moves a joint's held-out error by 9 % and unconstrained parameters by up to four times
their scales; the virtual parametrisation instead of log-Cholesky (the data's path unchanged)
moves 88 of the 91 identified parameters by more than 1e-4 of their scales (the median one by
1e-2), the training error by 0.5 % and the mean held-out error by 0.13 %.

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

GOLDEN = Path(__file__).parent / "data" / "head_default_report.json"
#: the data's path, relative to each value (see the module)
RTOL = 1e-8
#: the projection's answer, relative to each parameter's physical scale (see the module)
PROJECTED = 1e-4
SKIP = {("settings", "command"), ("settings", "log"), ("settings", "identify_seconds")}
#: the numbers computed from the projected parameters, besides those under "identified"
FROM_PROJECTED = {("train_rmse",), ("noise", "training residual RMS of the weighted equations")}


def _leaves(x, path=()):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, (*path, str(k)))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, (*path, i))
    else:
        yield path, x


def _kind(name: str) -> str:
    """A parameter's kind, as `torchjfa.physical.parameter_scales` groups them: ``m``, ``mc``,
    ``I`` or the joint term (``fv``, ``fc``, ``fo``)."""
    short = name.rsplit(".", 1)[-1]
    return "mc" if short.startswith("mc") else "I" if short.startswith("I") else short


def _scales(parameters: list[dict]) -> dict[str, float]:
    """Each parameter's physical scale, by name: its kind's root mean square over the
    description's values, over the identified ones where the description has none."""
    kinds: dict[str, list[dict]] = {}
    for p in parameters:
        kinds.setdefault(_kind(p["parameter"]), []).append(p)
    rms = {}
    for kind, rows in kinds.items():
        key = "description" if any(r["description"] for r in rows) else "identified"
        rms[kind] = math.sqrt(sum(r[key] ** 2 for r in rows) / len(rows))
    return {p["parameter"]: rms[_kind(p["parameter"])] for p in parameters}


def _terms(combination: str) -> list[tuple[float, str]]:
    """``"a.m + 0.2 b.mcz - 1 c.Izz"`` -> ``[(1.0, "a.m"), (0.2, "b.mcz"), (-1.0, "c.Izz")]``."""
    parts = re.split(r" ([+-]) ", combination)
    terms = []
    for sign, term in zip(["+", *parts[1::2]], parts[::2], strict=True):
        coef, _, name = term.rpartition(" ")
        terms.append(((-1.0 if sign == "-" else 1.0) * float(coef or 1.0), name))
    return terms


def _same_combination(want: str, got: str) -> bool:
    """The same parameters with coefficients equal to the printed four significant digits (the
    last digit may round the other way)."""
    a, b = _terms(want), _terms(got)
    if [n for _, n in a] != [n for _, n in b]:
        return False
    return all(
        abs(x - y) <= 1.000001 * 10.0 ** (math.floor(math.log10(max(abs(x), abs(y)))) - 3)
        for (x, _), (y, _) in zip(a, b, strict=True)
    )


@pytest.fixture(scope="module")
def folder(default_run):
    """The report folder of the default run (figures included: the report as users get it) on
    ``torchjfa simulate head --n-samples 5040`` (the session's, tests/conftest.py)."""
    return default_run.folder


@pytest.fixture(scope="module")
def report(folder):
    return json.loads((folder / "report.json").read_text())


def test_the_default_report_on_a_simulated_log_is_unchanged(report):
    golden = json.loads(GOLDEN.read_text())
    want = {p: v for p, v in _leaves(golden) if p[:2] not in SKIP}
    got = {p: v for p, v in _leaves(report) if p[:2] not in SKIP}
    assert set(got) >= set(want), sorted(set(want) - set(got))[:5]
    # each top-level entry's values on one scale, so that a value at round-off (0 +- 1e-17) is
    # compared to its entry's largest value, not to itself
    scale: dict[str, float] = {}
    for p, v in want.items():
        if isinstance(v, float) and math.isfinite(v):
            scale[p[0]] = max(scale.get(p[0], 0.0), abs(v))
    physical = _scales(golden["parameters"])
    names = [p["parameter"] for p in golden["parameters"]]
    wrong = []
    for p, v in want.items():
        g = got[p]
        if isinstance(v, float) and not isinstance(g, bool):
            size = max(abs(v), 1e-6 * scale[p[0]])
            if math.isnan(v):
                ok = isinstance(g, float) and math.isnan(g)
            elif p[0] == "parameters" and p[-1] == "identified":
                ok = abs(g - v) <= PROJECTED * physical[names[p[1]]]
            elif p[0] == "base_parameters" and p[-1] == "identified":
                terms = _terms(golden["base_parameters"]["combinations"][p[2]]["combination"])
                ok = abs(g - v) <= PROJECTED * sum(abs(c) * physical[n] for c, n in terms)
            elif "identified" in p or p in FROM_PROJECTED or p[:2] == ("settings", "logs"):
                ok = abs(g - v) <= PROJECTED * size  # the identified model's torque errors
            else:
                ok = abs(g - v) <= RTOL * size
        elif p[:2] == ("base_parameters", "combinations") and p[-1] == "combination":
            ok = _same_combination(v, g)
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
    # the head's MJCF states damping and dry friction: the description is judged with them
    assert "against the description's (with its own damping and friction) " in lines[4]
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
