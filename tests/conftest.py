"""Fixtures shared across the test folders."""

from __future__ import annotations

import contextlib
import io
import logging
import os
from types import SimpleNamespace

import pytest

import torchjfa._util as notes_module
from torchjfa.cli import main


class _Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.INFO)
        self.records: list[logging.LogRecord] = []

    def emit(self, record):
        self.records.append(record)


@pytest.fixture
def notes(monkeypatch):
    """The "torchjfa" logger's notes, each note fresh (none seen yet in this process)."""
    monkeypatch.setattr(notes_module, "_seen", set())
    logger, handler = logging.getLogger("torchjfa"), _Records()
    logger.addHandler(handler)
    level = logger.level
    logger.setLevel(logging.INFO)
    yield handler
    logger.removeHandler(handler)
    logger.setLevel(level)


@pytest.fixture(scope="session")
def head_csv(tmp_path_factory):
    """``torchjfa simulate head --n-samples 5040`` (the default seed): the simulated log of the
    command-line tests, written once. Read only: a test that changes the log writes a copy."""
    path = tmp_path_factory.mktemp("head") / "head.csv"
    assert main(["simulate", "head", "--out", str(path), "--n-samples", "5040", "--quiet"]) == 0
    return path


@pytest.fixture(scope="session")
def default_run(head_csv, tmp_path_factory):
    """``torchjfa identify head head.csv --out rep --quiet``, every default (figures included:
    the report as users get it), on `head_csv`, once. Its ``folder`` (read only), ``stdout``,
    and ``seen``: the last time (s) of the training data each cut-off choice was given."""
    import torchjfa.identification._prepare as stages

    choose, seen = stages.choose_cutoff, []

    def spy(model, log, **kwargs):
        seen.append(float(log.t[-1]))
        return choose(model, log, **kwargs)

    folder, stdout = tmp_path_factory.mktemp("default") / "rep", io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(stdout):
        patch.setattr(stages, "choose_cutoff", spy)
        assert main(["identify", "head", str(head_csv), "--out", str(folder), "--quiet"]) == 0
    return SimpleNamespace(folder=folder, stdout=stdout.getvalue(), seen=tuple(seen))


@pytest.fixture(scope="session")
def head_sim():
    """``generate_log("head", n_samples=5040, seed=0)``: the simulated head with its ground
    truth, three 4 s periods (the log `head_csv` holds), once. Read only: clone to change it."""
    from torchjfa.sim import generate_log

    return generate_log("head", n_samples=5040, seed=0)


def pytest_configure(config):
    """Under ``pytest -n N`` (the default: one worker per core), each worker runs torch on one
    thread, and so do the processes its tests start: N workers with torch's default threads each
    would put N times the cores' worth of spinning threads on the machine."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        os.environ["OMP_NUM_THREADS"] = "1"
        torch.set_num_threads(1)
