"""The dataclass field of `torchjfa.identification.Options` and `Compute` that carries its
command-line flag (`option`), and the groups the command lists them in (`GROUPS`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import MISSING, Field, field

from . import _parse as parse

__all__ = ["GROUPS", "option", "parser_type"]

#: the groups of options, in the order the command's help lists them: name -> title
GROUPS = {
    "reading": "reading the log",
    "preparation": "filtering, differentiating and splitting",
    "model": "the model's joint terms",
    "estimator": "estimation",
    "projection": "physical consistency",
    "floating": "floating-base robots (legged robots, humanoids)",
    "compute": "computation",
}


def option(
    default=MISSING,
    *,
    group: str,
    help: str,
    parse: Callable[[str], object] | None = None,
    choices: Sequence[str] | Callable[[], Sequence[str]] | None = None,
    flag: str | None = None,
    metavar: str | None = None,
    cli: bool = True,
    action: str | None = None,
    default_factory=MISSING,
) -> Field:
    """A dataclass field of `Options` or `Compute` with its command-line metadata.

    Args:
        default, default_factory: as for `dataclasses.field`.
        group: a key of `GROUPS`.
        help: the flag's help text (the default is appended by the command).
        parse: turns the flag's text into the field's value (raises
            ``argparse.ArgumentTypeError`` with what was expected); default: the default's type.
        choices: the values allowed on the command line (or a function giving them).
        flag: the flag (default ``--`` + the name with dashes; a bool that defaults to True
            gets ``--no-<name>``).
        metavar: the value's name in the help.
        cli: False for a field the command does not set (a Python object, say).
        action: ``"switch"`` for a ``bool | None`` field: ``--name`` / ``--no-name``, neither
            given the default.
    """
    if group not in GROUPS:
        raise ValueError(f"unknown option group {group!r}; choose from {tuple(GROUPS)}")
    meta = {"group": group, "help": help, "parse": parse, "choices": choices, "flag": flag,
            "metavar": metavar, "cli": cli, "action": action}  # fmt: skip
    return field(default=default, default_factory=default_factory, metadata=meta)


def parser_type(f: Field) -> Callable[[str], object]:
    """The argparse ``type`` of a field: its ``parse`` (errors turned into argparse's)."""
    fn = f.metadata.get("parse")
    if fn is None:
        default = f.default
        fn = type(default) if default is not MISSING and default is not None else str
    return parse.typed(fn)
