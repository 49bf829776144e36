"""The note before Numba compiles the (Bayesian) JFA loop for the first time on a machine."""

from __future__ import annotations

import os
from types import SimpleNamespace

import torch

import torchjfa.estimators._bayes_jfa as em
from torchjfa.estimators import BayesianJFA


def _fake_run(index_path: str, signatures=()):
    cache = SimpleNamespace(_cache_file=SimpleNamespace(_index_path=index_path))
    return SimpleNamespace(signatures=list(signatures), _cache=cache)


def test_note_when_the_loop_is_not_cached(tmp_path, monkeypatch, notes):
    monkeypatch.setattr(em, "run", _fake_run(str(tmp_path / "absent.nbi")))
    em.note_first_compile()
    em.note_first_compile()  # once per process
    messages = [r.getMessage() for r in notes.records]
    assert len(messages) == 1 and "compiling the (Bayesian) JFA EM loop" in messages[0]
    assert str(tmp_path) in messages[0]


def test_no_note_when_cached_or_loaded(tmp_path, monkeypatch, notes):
    index = tmp_path / "run.nbi"
    index.write_bytes(b"")
    monkeypatch.setattr(em, "run", _fake_run(str(index)))
    em.note_first_compile()
    monkeypatch.setattr(em, "run", _fake_run(str(tmp_path / "absent.nbi"), signatures=["sig"]))
    em.note_first_compile()
    assert notes.records == []


def test_the_index_path_is_numbas_own():
    # after a fit the loop is compiled and cached: the path the note looks at exists
    X = torch.randn(200, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    BayesianJFA(max_iter=5).fit(X, X @ torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64))
    assert em.run.signatures
    assert os.path.exists(em.run._cache._cache_file._index_path)
