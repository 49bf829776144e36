"""Every notebook in notebooks/ runs top to bottom in smoke mode (SMOKE_TEST=1), and reads the
SMOKE_TEST switch as a person means it (``0`` is off)."""

import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))
SCRIPTS = Path(__file__).parents[1] / "scripts"  # the paper's experiments, for two notebooks


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs_in_smoke_mode(path, tmp_path, monkeypatch):
    monkeypatch.setenv("SMOKE_TEST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    path_now = os.environ.get("PYTHONPATH")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(SCRIPTS), path_now])))
    monkeypatch.chdir(tmp_path)
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb, kernel_name="python3", timeout=300, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    errors = [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.get("output_type") == "error"
    ]
    assert not errors
    assert any(c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
        "the notebook printed nothing"
    )


def test_there_are_notebooks():
    assert NOTEBOOKS, "notebooks/ has no notebook"


SMOKE_ON = ("1", "true", "True", "YES", "yes", "on", " 1 ")
SMOKE_OFF = ("0", "false", "False", "no", "off", "")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_reads_the_smoke_switch(path, monkeypatch):
    """The notebook's one ``SMOKE = ...`` line, run alone under each value of SMOKE_TEST (the
    whole notebook is not run: its smoke run is the test above)."""
    nb = nbformat.read(path, as_version=4)
    lines = [
        line
        for c in nb.cells
        if c.cell_type == "code"
        for line in c.source.splitlines()
        if line.startswith("SMOKE =")
    ]
    assert len(lines) == 1, lines
    for value, expected in [(v, True) for v in SMOKE_ON] + [(v, False) for v in SMOKE_OFF]:
        monkeypatch.setenv("SMOKE_TEST", value)
        scope = {"os": os}
        exec(lines[0], scope)
        assert scope["SMOKE"] is expected, (value, lines[0])
    monkeypatch.delenv("SMOKE_TEST")
    scope = {"os": os}
    exec(lines[0], scope)
    assert scope["SMOKE"] is False
