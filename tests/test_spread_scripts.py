"""The smoke runs of scripts/spread_coverage.py and scripts/sim_bjfa_vs_ols.py: structure and
the bounds every printed number must keep (the numbers themselves are in docs)."""

import importlib.util
import math
from pathlib import Path

SCRIPTS = Path(__file__).parents[1] / "scripts"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_spread_coverage_smoke(capsys):
    mod = _load("spread_coverage")
    out = mod.main(["--smoke"])
    text = capsys.readouterr().out
    assert out["logs"] == 2 and out["rank"] > 0
    assert set(out["coverage"]) == set(mod.ESTIMATORS)
    for rows in out["coverage"].values():
        assert set(rows) == set(mod.AGAINST)
        for cov in rows.values():
            for pooled, median in cov.values():
                assert 0.0 <= pooled <= 1.0 and 0.0 <= median <= 1.0
            # a wider interval covers at least as much
            assert cov["95%"][0] >= cov["68%"][0]
    assert out["input_noise"]["OLS"] and out["input_noise"]["Bayesian JFA"]
    for e in mod.ESTIMATORS:
        for s in mod.AGAINST:
            assert f"{e:>13} {s:>20}" in text


def test_sim_bjfa_vs_ols_smoke(capsys):
    mod = _load("sim_bjfa_vs_ols")
    out = mod.main(["--smoke"])
    text = capsys.readouterr().out
    head = out["head"]
    (seed,) = head["per_seed"].values()
    assert set(seed) == set(mod.RUNS)
    for r in seed.values():
        assert math.isfinite(r["heldout_nmse"]) and r["heldout_nmse"] >= 0
        assert math.isfinite(r["param_error"]) and r["param_error"] >= 0
        assert not r["periods"]  # the excitation does not repeat within the log
    # the Bayesian runs take the propagated noise; all three run at OLS's cut-off
    assert seed["BJFA shared"]["noise"] == seed["BJFA output"]["noise"] == "propagated"
    assert len({r["cutoff_hz"] for r in seed.values()}) == 1
    assert set(head["claims"]) == {"BJFA shared", "BJFA output"}
    assert "geometric mean over seeds" in text and "below OLS" in text
