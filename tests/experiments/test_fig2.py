import importlib.util
import json
from pathlib import Path

import pytest
from experiments import fig2

SCRIPT = Path(__file__).parents[2] / "scripts" / "reproduce_fig2.py"


def _rows():
    rows = []
    for trial, (a, b) in enumerate([(0.1, 0.3), (0.3, 0.5)]):
        for method, value in (("OLS", a), ("Bayes JFA, known noise", b / 4)):
            for test in ("clean", "noisy"):
                rows.append(
                    {
                        "redundant": 30,
                        "irrelevant": 60,
                        "input_snr": 2.0,
                        "trial": trial,
                        "method": method,
                        "test": test,
                        "nmse": value,
                        "fit_s": 1.0,
                        "n_iter": -1,
                    }
                )
    return rows


def test_summarize_and_improvement_written_out():
    summary = fig2.summarize(_rows())
    ols = [s for s in summary if s["method"] == "OLS" and s["test"] == "clean"][0]
    assert ols["nmse_mean"] == pytest.approx(0.2)
    assert ols["nmse_std"] == pytest.approx(0.1414213562, rel=1e-8)  # unbiased std of 0.1, 0.3
    (gain,) = fig2.improvement_table(summary)
    assert gain["best_bayes"] == "Bayes JFA, known noise" and gain["best_other"] == "OLS"
    assert gain["reduction"] == pytest.approx(0.5)  # mean 0.1 against 0.2
    assert gain["best_bayes_nmse"] == pytest.approx(0.1)


def test_quick_script_writes_table_json_and_plot(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("reproduce_fig2", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    result = module.run(quick=True, out=tmp_path, progress=False)
    for name in ("fig2.csv", "fig2.json", "fig2.png"):
        assert (tmp_path / name).stat().st_size > 0
    methods = {s["method"] for s in result["summary"]}
    assert methods == {m.name for m in fig2.default_methods()}
    saved = json.loads((tmp_path / "fig2.json").read_text())
    assert (
        len(saved["rows"]) == 2 * 1 * 2 * len(methods) * 2
    )  # scenarios x SNR x trials x methods x tests
    assert "nMSE reduction" in capsys.readouterr().out
