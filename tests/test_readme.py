"""The README's quick start runs as written."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _quick_start() -> str:
    text = README.read_text(encoding="utf-8")
    match = re.search(r"^## Quick start\n\n```python\n(.*?)^```$", text, re.S | re.M)
    assert match, "README.md has no python block under '## Quick start'"
    return match.group(1)


def test_quick_start_runs_as_written(capsys):
    code = _quick_start()
    namespace: dict = {}
    exec(compile(code, str(README), "exec"), namespace)
    # it ends with a fitted, physically consistent model that predicts the training torques
    # to well under their spread (the head's torques vary by about 1 N m)
    rms = float(capsys.readouterr().out.split()[0])
    tau = namespace["tau"]
    assert rms < 0.2 * float(tau.std())


def test_the_python_version_of_the_command_runs_as_written(tmp_path, monkeypatch):
    import warnings

    from torchjfa.cli import main

    text = README.read_text(encoding="utf-8")
    match = re.search(
        r"^From Python the command is one call.*?```python\n(.*?)^```$", text, re.S | re.M
    )
    assert match, "README.md has no python block for torchjfa.identify"
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "head", "--out", "log.csv", "--n-samples", "5040", "--quiet"]) == 0
    namespace: dict = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the example says a warning may come
        exec(compile(match.group(1), str(README), "exec"), namespace)
    assert (tmp_path / "result" / "report.md").is_file()
    assert namespace["ident"].identified_well
    log = namespace["ident"].data.validation
    tau = namespace["dynamics"](log.q, log.qd, log.qdd)
    assert tau.shape == log.tau.shape


def test_the_torch_pipeline_example_runs_as_written(tmp_path, monkeypatch):
    import warnings

    import torch

    from torchjfa.cli import main

    text = README.read_text(encoding="utf-8")
    match = re.search(
        r"^## The identified model in a torch pipeline.*?```python\n(.*?)^```$", text, re.S | re.M
    )
    assert match, "README.md has no python block for the torch pipeline"
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "head", "--out", "log.csv", "--n-samples", "5040", "--quiet"]) == 0
    args = ["identify", "head", "log.csv", "--out", "result", "--quiet", "--no-plots"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main([*args, "--jackknife", "0", "--cutoff", "15"]) == 0
    ns: dict = {}
    exec(compile(match.group(1), str(README), "exec"), ns)
    # the forward dynamics invert the inverse, and the rollout stays finite
    assert torch.allclose(ns["accel"], ns["qdd"], atol=1e-9)
    assert bool(torch.isfinite(ns["path_q"]).all()) and ns["path_q"].shape[0] == 101
    assert torch.allclose(ns["with_residual"](ns["q"], ns["qd"], ns["qdd"]), ns["tau"])
