"""The README: every Python block runs as written (in order, in one namespace, as a reader
pasting them one after the other would), its commands are the ones `.ci/run` runs, and it stays
a short page without dates or issue numbers."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 150


def _blocks() -> list[str]:
    text = README.read_text(encoding="utf-8")
    return re.findall(r"^```python\n(.*?)^```$", text, re.S | re.M)


def test_every_python_block_runs_as_written(tmp_path, monkeypatch, capsys):
    import torch

    blocks = _blocks()
    assert len(blocks) >= 2, "README.md has fewer python blocks than expected"
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for i, code in enumerate(blocks):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the identification's warnings are its report's
            exec(compile(code, f"{README}, python block {i + 1}", "exec"), ns)
    # the first block identified a consistent model, wrote its report and printed its headline
    assert "physically consistent: yes" in capsys.readouterr().out
    assert (tmp_path / "result" / "report.md").is_file()
    assert (tmp_path / "result" / "identified.xml").is_file()
    log = ns["ident"].data.validation
    assert ns["dynamics"](log.q, log.qd, log.qdd).shape == log.tau.shape
    # the second: the forward dynamics invert the inverse, and the rollout stays finite
    assert torch.allclose(ns["accel"], ns["qdd"], atol=1e-9)
    assert bool(torch.isfinite(ns["path_q"]).all()) and ns["path_q"].shape[0] == 101
    assert torch.allclose(ns["with_residual"](ns["q"], ns["qd"], ns["qdd"]), ns["tau"])


def test_the_readme_gives_the_commands_ci_runs():
    text = README.read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    for label in ("install", "test", "demo"):
        match = re.search(rf"^# README: {label}\n(.+)$", ci, re.M)
        assert match, f".ci/run has no '# README: {label}' line"
        assert re.search(rf"^    {re.escape(match.group(1))}$", text, re.M), match.group(1)
    # the CPU-only torch comes before the install
    cpu = text.index("pip install torch --index-url https://download.pytorch.org/whl/cpu")
    assert cpu < text.index('pip install -e ".[dev]"')


def test_the_readme_is_short_and_undated():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= MAX_LINES
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text)
    assert not re.search(r"\bissues?\s+#?\d+|(?<![\w&#])#\d{1,3}\b", text, re.I)
    assert "../shared" not in text
