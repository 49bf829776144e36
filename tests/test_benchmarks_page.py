"""docs/benchmarks.md is written by the benchmark scripts (`scripts/_benchmarks_page.py`): one
block per script, replaced in place by ``--write-docs``."""

from __future__ import annotations

import importlib
import re

import _benchmarks_page as page
import pytest

#: every benchmark script; each has ``--write-docs`` and a block of its own on the page
SCRIPTS = (
    "bench_estimators",
    "bench_excitation",
    "bench_gradients",
    "bench_projection",
    "bench_regressor",
    "bench_scale",
    "real_panda",
    "real_ur10e",
    "real_rollouts",
    "sim_payload",
    "spread_coverage",
    "sim_bjfa_vs_ols",
    "real_ur10e_gains",
    "sim_payload_excitation",
    "real_refine",
)
STAMP = {"machine": "a test machine", "date": "today"}


def _blocks(text: str) -> dict[str, str]:
    found = re.findall(r"^<!-- begin (\S+) -->\n(.*?)^<!-- end \1 -->$", text, re.S | re.M)
    return dict(found)


def test_write_section_replaces_one_block_and_leaves_the_rest(tmp_path):
    path = tmp_path / "page.md"
    path.write_text("# Benchmarks\n\nprose before\n")
    page.write_section("one", "| a |\n| 1 |", "python scripts/one.py", path, **STAMP)
    page.write_section("two", "second", "python scripts/two.py --x 2", path, **STAMP)
    path.write_text(
        path.read_text().replace("\n\n<!-- begin two", "\n\nprose between\n\n<!-- begin two")
    )
    before = path.read_text()
    page.write_section("one", "| a |\n| 2 |", "python scripts/one.py --n 3", path, date="later",
                       machine="another machine")  # fmt: skip
    after = path.read_text()
    blocks = _blocks(after)
    assert list(blocks) == ["one", "two"]
    assert blocks["one"] == (
        "Command: `python scripts/one.py --n 3`  \nMachine: another machine  \nDate: later\n\n"
        "| a |\n| 2 |\n"
    )
    assert blocks["two"] == _blocks(before)["two"]
    for prose in ("# Benchmarks\n\nprose before\n\n", "\n\nprose between\n\n"):
        assert prose in after
    assert after.replace(blocks["one"], "") == before.replace(_blocks(before)["one"], "")


def test_write_section_appends_a_new_block_and_creates_a_missing_page(tmp_path):
    path = tmp_path / "new.md"
    page.write_section("one", "text", "python scripts/one.py", path, **STAMP)
    assert path.read_text().startswith("# Benchmarks\n\n<!-- begin one -->\n")
    page.write_section("one-more", "more", "python scripts/one.py --more", path, **STAMP)
    assert list(_blocks(path.read_text())) == ["one", "one-more"]


def test_write_section_refuses_repeated_markers_and_odd_names(tmp_path):
    path = tmp_path / "page.md"
    path.write_text("<!-- begin x -->\na\n<!-- end x -->\n<!-- begin x -->\nb\n<!-- end x -->\n")
    with pytest.raises(ValueError, match="repeated or unpaired"):
        page.write_section("x", "c", "cmd", path, **STAMP)
    with pytest.raises(ValueError, match="section name"):
        page.write_section("a b", "c", "cmd", tmp_path / "other.md", **STAMP)


def test_the_stamp_names_this_machine_and_today():
    machine = page.this_machine()
    assert "cores" in machine and "torch" in machine
    assert re.fullmatch(r"\d{4}-\d\d-\d\d", page.today())


def test_the_command_leaves_write_docs_out():
    line = page.command_line
    assert line("x", ["--seeds", "3", "--write-docs"]) == "python scripts/x.py --seeds 3"
    assert line("x", ["--write-docs", "/tmp/p.md", "--quick"]) == "python scripts/x.py --quick"
    assert line("x", ["--write-docs=/tmp/p.md", "a b"]) == "python scripts/x.py 'a b'"


def test_recording_writes_what_the_block_printed(tmp_path, capsys):
    path = tmp_path / "page.md"
    with page.recording("demo", "demo", path, ["--n", "2", "--write-docs", str(path)]):
        print("a table")
    assert "a table" in capsys.readouterr().out
    (block,) = _blocks(path.read_text()).values()
    assert block.startswith("Command: `python scripts/demo.py --n 2`  \nMachine: ")
    assert block.endswith("\n```text\na table\n```\n")
    with page.recording("demo", "demo", None):  # no --write-docs: nothing written
        print("another table")
    assert "another table" not in path.read_text()


def test_a_smoke_run_does_not_write_the_real_page():
    with pytest.raises(SystemExit, match="smoke"):
        with page.recording("x", "x", page.PAGE, [], smoke=True):
            raise AssertionError("the run must not start")


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_benchmark_script_has_write_docs(script):
    parser = importlib.import_module(script).parser()
    flags = {s for action in parser._actions for s in action.option_strings}
    assert "--write-docs" in flags
    assert parser.parse_args(["--write-docs"]).write_docs == str(page.PAGE)


def test_the_page_has_a_block_of_every_script():
    text = page.PAGE.read_text(encoding="utf-8")
    blocks = _blocks(text)
    begins, ends = (re.findall(rf"^<!-- {m} ", text, re.M) for m in ("begin", "end"))
    assert len(begins) == len(ends) == len(blocks)
    for script in SCRIPTS:
        assert script in blocks, f"docs/benchmarks.md has no block of {script}"
    for name, block in blocks.items():
        assert re.match(
            r"Command: `python scripts/\w+\.py[^`]*`  \nMachine: .+  \nDate: ", block
        ), name
    for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (page.PAGE.parent / image).is_file(), image
