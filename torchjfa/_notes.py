"""One-line notes to the user: a kernel being compiled, a fast path falling back.

Notes go to the ``"torchjfa"`` logger at INFO level, each distinct note once per process. When
nobody has configured logging (the root logger has no handler), that logger prints them to
stderr as ``torchjfa: <note>``, as Lightning does for its own messages; silence them with
``logging.getLogger("torchjfa").setLevel(logging.WARNING)`` or route them with any handler.
"""

from __future__ import annotations

import logging
import threading

__all__ = ["note"]

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
