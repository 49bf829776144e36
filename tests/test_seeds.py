"""`experiments.seeds`: the headline scripts' --seeds parsing and summaries."""

from __future__ import annotations

import math

import pytest
from experiments import seeds


def test_parse_seeds():
    assert seeds.parse_seeds("0-2,7") == (0, 1, 2, 7)
    assert seeds.parse_seeds("3") == (3,)
    assert seeds.parse_seeds("1, 1,0-1") == (1, 0)
    for bad, match in (("a", "not an int"), ("", "no seed"), ("4-2", "empty")):
        with pytest.raises(ValueError, match=match):
            seeds.parse_seeds(bad)


def test_summarize_written_out():
    values = {0: 0.025, 1: 0.027, 2: 0.373}
    s = seeds.summarize(values)
    mean = (0.025 + 0.027 + 0.373) / 3
    std = math.sqrt(sum((v - mean) ** 2 for v in values.values()) / 2)
    assert s["mean"] == pytest.approx(mean, rel=1e-15)
    assert s["std"] == pytest.approx(std, rel=1e-14)
    assert (s["best_seed"], s["worst_seed"]) == (0, 2)
    assert s["max_over_min"] == pytest.approx(0.373 / 0.025, rel=1e-15)
    hi = seeds.summarize(values, lower_is_better=False)
    assert (hi["best_seed"], hi["worst_seed"]) == (2, 0)
    line = seeds.format_summary("identified only", values)
    assert line.startswith("identified only: mean 0.1417") and "worst 0.373 (seed 2)" in line
    assert seeds.summarize({5: 1.0})["std"] == 0.0
    with pytest.raises(ValueError):
        seeds.summarize({})


def test_for_each_seed_gives_each_run_its_folder(tmp_path, capsys):
    calls = []
    out = seeds.for_each_seed((3, 5), lambda s, f: calls.append((s, f)) or s * 10, tmp_path)
    assert out == {3: 30, 5: 50}
    assert calls == [(3, tmp_path / "seed_3"), (5, tmp_path / "seed_5")]
    assert capsys.readouterr().out.count("=== seed") == 2
    assert seeds.for_each_seed((7,), lambda s, f: f, tmp_path) == {7: tmp_path}
    assert capsys.readouterr().out == ""
