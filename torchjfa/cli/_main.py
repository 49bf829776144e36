"""The ``torchjfa`` parser and its entry point: one sub-command per module of this package."""

from __future__ import annotations

import argparse
import contextlib
import sys
from importlib import import_module
from typing import TYPE_CHECKING

from ._common import COMMANDS, Parser

__all__ = ["COMMANDS", "ESTIMATORS", "build_parser", "main"]

if TYPE_CHECKING:
    #: the library's estimators' names (`torchjfa.estimators.available`), read when first used
    ESTIMATORS: tuple[str, ...]


def __getattr__(name: str):
    """``ESTIMATORS``: the library's estimators' names (a registered one is taken by
    ``torchjfa identify`` too), imported when first asked for: ``torchjfa --help`` imports
    neither torch nor the flow."""
    if name == "ESTIMATORS":
        from ..estimators import available

        return available()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _add_residual(sub) -> argparse.ArgumentParser:
    """The ``residual`` sub-command: everything after it goes to the Lightning trainer's own
    command line (`torchjfa.cli._residual`), which has its own ``--help``."""
    p = sub.add_parser(
        "residual",
        help=COMMANDS["residual"],
        description="Train a residual model on top of an identified one with Lightning: "
        "torchjfa residual fit --config torchjfa/learning/configs/head_residual.yaml "
        "(torchjfa residual --help lists every option).",
        add_help=False,
    )
    p.add_argument("rest", nargs=argparse.REMAINDER, help="the trainer's arguments")
    p.set_defaults(func=_cmd_residual)
    return p


def _cmd_residual(args) -> int:
    from ._residual import main as residual

    residual(args.rest)
    return 0


#: sub-command -> (module, function) adding its parser, imported only when needed: the
#: parsers read the library's defaults, and ``excite``'s and ``simulate``'s import MuJoCo
_PARSERS = {name: (f"torchjfa.cli._{name}", f"add_{name}") for name in COMMANDS}
_PARSERS["residual"] = (__name__, "_add_residual")  # its module imports Lightning


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``torchjfa`` parser, each sub-command's parser set to run its command.

    Args:
        command: build only this sub-command's options (the others are listed by name and
            help); default every sub-command's.
    """
    parser = Parser(
        prog="torchjfa",
        description="Probabilistic identification of robot dynamics (Bayesian joint factor "
        "analysis, physically consistent parameters).",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, text in COMMANDS.items():
        if command is None or name == command:
            module, function = _PARSERS[name]
            getattr(import_module(module), function)(sub)
        else:
            sub.add_parser(name, help=text)
    return parser


def _command(argv: list[str]) -> str | None:
    """The sub-command ``argv`` names (its first argument that is not an option)."""
    for a in argv:
        if not a.startswith("-"):
            return a if a in COMMANDS else None
    return None


def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 bad input, 130 interrupted).

    Bad input (a missing column, an unknown joint, NaN rows, time going backwards, too few
    samples, a robot file that does not parse) ends with one line on stderr and exit status 2,
    not a traceback; ``--debug`` shows the traceback. So does an ``--out`` the command will not
    write (checked before any work), and Ctrl-C ends with one line, leaving ``--out`` as it was.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(_command(argv) or "")
    args = parser.parse_args(argv)
    args.argv = argv
    from .._util import OutputError
    from ..data import LogError
    from ..identification._errors import IdentificationError as UsageError
    from ._common import claimed_output

    interrupted: list[int] = []
    try:
        with claimed_output(args), _noting_interrupts(interrupted):
            return int(args.func(args) or 0)
    except (UsageError, LogError, OutputError, FileNotFoundError) as exc:
        if args.debug:
            raise
        if interrupted:  # Ctrl-C inside an import or a library that turned it into an error
            return _interrupted(args)
        print(f"torchjfa {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if args.debug:
            raise
        return _interrupted(args)
    except Exception:
        if interrupted and not args.debug:
            return _interrupted(args)
        raise


def _interrupted(args) -> int:
    left = f"; {args.out} is as it was" if getattr(args, "output", None) else ""
    print(f"torchjfa {args.command}: interrupted{left}", file=sys.stderr)
    return 130


@contextlib.contextmanager
def _noting_interrupts(interrupted: list[int]):
    """Ctrl-C raises KeyboardInterrupt as usual and is also noted in ``interrupted``: one that
    lands inside a module's import (which Python reports as an ``ImportError``) or inside a
    library that wraps it in its own error still ends as an interrupt, not as bad input. Only
    in the main thread (elsewhere signal handlers cannot be set)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def note(signum, frame):
        interrupted.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, note)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def entry() -> None:
    """The ``torchjfa`` console script."""
    sys.exit(main())
