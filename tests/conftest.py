"""Fixtures shared across the test folders."""

from __future__ import annotations

import logging

import pytest

import torchjfa._util as notes_module


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
