"""The command line's parsers of `Options`' values (``--cutoff auto``, ``--columns t=time``, ...):
each turns a flag's text into the field's value or raises `IdentificationError` with what was
expected; `typed` makes one an argparse ``type``."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from pathlib import Path

from ._errors import IdentificationError

__all__ = ["auto_or", "columns", "drive_gains", "estimator_options", "names", "number",
           "positive", "prior", "refits", "typed"]  # fmt: skip


def typed(parse: Callable[[str], object]) -> Callable[[str], object]:
    """``parse`` with its `IdentificationError` turned into argparse's error."""

    def wrapped(text: str):
        try:
            return parse(text)
        except IdentificationError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    wrapped.__name__ = getattr(parse, "__name__", "value")
    return wrapped


def number(value) -> float:
    """``value`` as a float, NaN where it is not a number (so that the range checks refuse it)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def auto_or(what: str, *, zero: bool, none: bool = False):
    """A parser: ``"auto"``, a finite number > 0 (>= 0 with ``zero``), or with ``none``
    ``"none"`` (None)."""

    def parse(text: str):
        if text == "auto" or (none and text == "none"):
            return None if text == "none" else text
        value = number(text)
        if not ((value >= 0) if zero else (value > 0)) or value == float("inf"):
            expected = "'auto'" + (", 'none'" if none else "") + f" or {what}"
            raise IdentificationError(f"expected {expected}, got {text!r}")
        return value

    parse.__name__ = what
    return parse


def positive(text: str) -> float:
    """A finite number > 0."""
    value = number(text)
    if not 0 < value < float("inf"):
        raise IdentificationError(f"expected a positive number, got {text!r}")
    return value


def prior(text: str):
    """``--description-prior``: ``auto``, a weight >= 0, ``0``/``none`` for none (None)."""
    if text in ("none", "off"):
        return None
    value = auto_or("a weight >= 0", zero=True)(text)
    return None if value == 0 else value


def refits(text: str):
    """``--bias-correction``: ``auto`` or a whole number of refits."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise IdentificationError(f"expected 'auto' or a whole number, got {text!r}") from None


def _mapping(text: str, what: str) -> dict[str, object]:
    """``key=value,...`` or a JSON object (or a file holding one); values parsed as JSON where
    they are JSON (``max_iter=500`` gives 500), else kept as strings."""
    if os.path.isfile(text):
        text = Path(text).read_text()
    text = text.strip()
    if text.startswith("{"):
        try:
            mapping = json.loads(text)
        except json.JSONDecodeError as exc:
            raise IdentificationError(f"{what}: not valid JSON: {exc}") from None
        if not isinstance(mapping, dict):
            raise IdentificationError(f"{what}: expected a JSON object")
        return {str(k): v for k, v in mapping.items()}
    out: dict[str, object] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise IdentificationError(f"{what}: expected key=value pairs, got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def columns(text: str) -> dict[str, str] | None:
    """``ours=theirs,...`` or a JSON object or file mapping the library's names to the log's."""
    if not text.strip():
        return None
    return {k: str(v) for k, v in _mapping(text, "--columns").items()}


def estimator_options(text: str) -> dict[str, object]:
    return _mapping(text, "--estimator-options")


def drive_gains(text: str) -> tuple[float, ...] | dict[str, float]:
    """``--drive-gains``: ``G1,G2,...`` (N m/A in the robot's joint order) or
    ``joint=G,...`` (by joint name), each a finite number > 0."""
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items:
        raise IdentificationError("--drive-gains: expected G1,G2,... or joint=G,...")
    named = ["=" in s for s in items]
    if any(named) and not all(named):
        raise IdentificationError(
            f"--drive-gains: give every gain by position (G1,G2,...) or every one by joint "
            f"name (joint=G,...), not both: {text!r}"
        )
    pairs = [s.split("=", 1) if "=" in s else (None, s) for s in items]
    values = {}
    for k, v in pairs:
        g = number(v)
        if not 0 < g < float("inf"):
            raise IdentificationError(f"--drive-gains: a gain must be a number > 0, got {v!r}")
        values[k.strip() if k is not None else len(values)] = g
    if all(named):
        return {str(k): g for k, g in values.items()}
    return tuple(values.values())


def names(text: str) -> tuple[str, ...]:
    """A comma-separated list of names (``--fixed-joints a,b``); empty or ``none``: none."""
    text = text.strip()
    if text.lower() in ("", "none"):
        return ()
    return tuple(s.strip() for s in text.split(",") if s.strip())
