"""The package's runtime helpers: torch's threads around small-matrix work, progress bars, and
one-line notes to the user.

- `single_thread`: torch (and its BLAS) on one thread inside a block.
- `progress_bar`: a tqdm bar, off by default in the library, on in scripts.
- `note`: a note (a kernel being compiled, a fast path falling back) to the ``"torchjfa"``
  logger at INFO level, each distinct note once per process. When nobody has configured
  logging (the root logger has no handler), that logger prints them to stderr as ``torchjfa:
  <note>``, as Lightning does for its own messages; silence them with
  ``logging.getLogger("torchjfa").setLevel(logging.WARNING)`` or route them with any handler.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import torch
from tqdm import tqdm

__all__ = ["note", "progress_bar", "single_thread"]


@contextmanager
def single_thread() -> Iterator[None]:
    """Run torch (and its BLAS) on one thread inside the block, then restore the setting.

    For work made of many small ops: the projection's ~100 x 100 matrices, the eager
    regressor's ops on one chunk of samples. Threads cannot speed such ops up, and where other
    work shares the cores each op waits for its slowest thread, so that a 100 x 100
    matrix-vector product can become many times slower (scikit-learn limits BLAS threads
    around such work for the same reason). The setting is process-wide,
    so other Python threads running torch meanwhile get one thread too.
    """
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def progress_bar(*, total: int | None, desc: str, enabled: bool, unit: str = "it"):
    """A tqdm bar, or a do-nothing bar when ``enabled`` is False.

    Use as a context manager and call ``bar.update(k)``; ``bar.set_postfix(...)`` works too.
    """
    return tqdm(
        total=total, desc=desc, disable=not enabled, unit=unit, leave=False, dynamic_ncols=True
    )


_logger = logging.getLogger("torchjfa")
_seen: set[str] = set()
_lock = threading.Lock()


def _ensure_handler() -> None:
    if _logger.handlers or logging.getLogger().handlers:
        return
    handler = logging.StreamHandler()  # stderr, resolved at emit time
    handler.setFormatter(logging.Formatter("torchjfa: %(message)s"))
    _logger.addHandler(handler)
    _logger.propagate = False
    if _logger.level == logging.NOTSET:
        _logger.setLevel(logging.INFO)


def note(message: str, *, key: str | None = None) -> None:
    """Tell the user ``message`` once per process (per ``key``, default the message)."""
    with _lock:
        k = message if key is None else key
        if k in _seen:
            return
        _seen.add(k)
        _ensure_handler()
    _logger.info(message)
