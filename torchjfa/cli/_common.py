"""What every sub-command shares: the parser class that shows defaults, the one-line usage
error, the flags generated from `torchjfa.identification.Options`, the library's defaults read
from its signatures, small argument types, and the ``--out`` every writing command takes."""

from __future__ import annotations

import argparse
import inspect
import os
import shlex
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import MISSING, Field
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: ``torchjfa --help`` imports neither torch nor the flow
    from ..identification._options import IdentificationError as UsageError
    from ..identification._options import Options

__all__ = [
    "COMMANDS",
    "Parser",
    "UsageError",
    "add_option",
    "add_output",
    "claimed_output",
    "add_reading",
    "command_line",
    "default_of",
    "friction_terms",
    "load_model",
    "numbers",
    "reading",
    "usage",
    "written_as",
]


def __getattr__(name: str):
    """``UsageError``: bad input from the user, printed as one line with exit status 2 (the
    flow's own `torchjfa.identification.IdentificationError`), imported when first asked for."""
    if name == "UsageError":
        from ..identification._errors import IdentificationError

        return IdentificationError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: the sub-commands, in the order ``torchjfa --help`` lists them: name -> one-line help (each
#: sub-command's parser takes its help from here)
COMMANDS = {
    "identify": "identify a robot's parameters from its logs and write a report",
    "simulate": "simulate a robot tracking an excitation and write its log",
    "excite": "design an optimal excitation trajectory for identification",
    "evaluate": "evaluate an identified model on logs (or on a simulated robot)",
    "payload": "identify a payload fixed to a link from loaded logs",
    "refine": "refine friction loss, damping and armature on MuJoCo rollouts (mujoco.sysid)",
    "residual": "train residual dynamics with Lightning (fit, validate, test, predict)",
}


class HelpFormatter(argparse.HelpFormatter):
    """``--help`` with every option's default, ``(default: X)``, after its help text (flags,
    which are off unless given, and options without a default, say nothing)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (
            not action.option_strings
            or action.nargs == 0
            or default is None
            or default is argparse.SUPPRESS
            or "%(default)" in text
        ):
            return text
        if isinstance(default, (tuple, list)):
            shown = ",".join(map(str, default)) or "none"
        elif isinstance(default, float):
            shown = f"{default:g}"
        else:
            shown = str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class Parser(argparse.ArgumentParser):
    """An `argparse.ArgumentParser` whose help shows the defaults; its subcommands' parsers are
    of the same class (``add_subparsers`` makes them so), and so show theirs."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def default_of(function, name: str):
    """The default of ``function``'s keyword ``name``: the library declares it, the command
    line shows and passes the same value."""
    default = inspect.signature(function).parameters[name].default
    if default is inspect.Parameter.empty:
        raise TypeError(f"{function.__qualname__}'s {name} has no default")
    return default


def usage(exc: Exception) -> UsageError:
    """A library's ``ValueError`` as the command line's one-line error."""
    from ..identification._errors import IdentificationError

    return IdentificationError(" ".join(str(exc).split()))


def command_line(args) -> str:
    """The command as the user typed it (for reports)."""
    return "torchjfa " + " ".join(shlex.quote(a) for a in getattr(args, "argv", []))


def add_output(p: argparse.ArgumentParser, *, default: str, what: str) -> None:
    """``--out`` (a result folder, written whole: `torchjfa.io.output_folder`) and
    ``--overwrite``; `claimed_output` holds the folder for the command's whole run."""
    p.add_argument(
        "--out",
        default=default,
        help=f"output folder ({what}); written whole when the command ends, its earlier files "
        "replaced together",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace --out even where it holds files torchjfa did not write (they are deleted)",
    )
    p.set_defaults(output="folder")


def written_as(args, *inputs: str | None) -> dict[str, object]:
    """The keywords of a result's writer (`torchjfa.io.output_folder` and every ``write``):
    ``overwrite`` from ``--overwrite``, the command line, and of ``inputs`` those that name
    files or folders on disk (a shipped robot's name is not one), for the manifest."""
    return {
        "overwrite": args.overwrite,
        "inputs": [p for p in inputs if p and os.path.exists(p)],
        "command": command_line(args),
    }


@contextmanager
def claimed_output(args) -> Iterator[None]:
    """Check ``args.out`` before any work (a file where a folder belongs, a symbolic link, a
    folder of other files without ``--overwrite``) and, for a folder, hold its lock until the
    command ends, so that a second run into it is refused at once, not after its work."""
    from .._util import OutputError, check_output, output_lock
    from ..identification._errors import IdentificationError as UsageError

    kind = getattr(args, "output", None)
    with ExitStack() as stack:
        if kind is not None:
            try:
                check_output(
                    args.out, folder=kind == "folder", overwrite=getattr(args, "overwrite", False)
                )
                if kind == "folder":
                    stack.enter_context(output_lock(args.out))
            except OutputError as exc:
                raise UsageError(f"--out: {exc}") from None
        yield


def numbers(text: str) -> tuple[float, ...]:
    """An argument type: one number or comma-separated numbers."""
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a number or comma-separated numbers, got {text!r}"
        ) from None


def friction_terms(text: str) -> tuple[str, ...]:
    """``--friction``: `torchjfa.identification.joint_terms` of the text, as an argument type."""
    from ..identification._options import IdentificationError as UsageError
    from ..identification._options import joint_terms

    try:
        return joint_terms(text)
    except UsageError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _default(f: Field):
    return f.default_factory() if f.default is MISSING else f.default


def add_option(group, f: Field) -> None:
    """One `Options` field's flag: a bool's switch, else a value with its parser and choices
    (the field's metadata gives the flag, the help, the choices and the parser; the default
    is the field's)."""
    from ..identification._option_field import parser_type

    meta, default = f.metadata, _default(f)
    flag = meta["flag"] or "--" + f.name.replace("_", "-")
    if isinstance(default, bool):
        if default:
            flag = meta["flag"] or "--no-" + f.name.replace("_", "-")
            group.add_argument(flag, dest=f.name, action="store_false", help=meta["help"])
        else:
            group.add_argument(flag, dest=f.name, action="store_true", help=meta["help"])
        return
    if meta["action"] == "switch":
        group.add_argument(flag, dest=f.name, action=argparse.BooleanOptionalAction,
                           default=default, help=meta["help"])  # fmt: skip
        return
    choices = meta["choices"]
    choices = choices() if callable(choices) else choices
    group.add_argument(
        flag,
        dest=f.name,
        default=default,
        type=None if choices else parser_type(f),
        choices=choices,
        metavar=meta["metavar"],
        help=meta["help"],
    )


def add_reading(p: argparse.ArgumentParser, *more: str) -> None:
    """The reading options of `torchjfa.identification.Options` (columns, time scale, drive
    gains, ROS topic and effort), as ``identify`` has them, and the fields ``more`` names (in
    their own groups)."""
    from ..identification._options import GROUPS, cli_fields

    groups: dict[str, object] = {}
    for f in cli_fields():
        reads = f.metadata["group"] == "reading" and f.name != "max_seconds"
        if reads or f.name in more:
            key = f.metadata["group"]
            if key not in groups:
                groups[key] = p.add_argument_group(GROUPS[key])
            add_option(groups[key], f)


def reading(args, *more: str) -> Options:
    """The `torchjfa.identification.Options` of the flags ``add_reading(p, *more)`` added (the
    others at their defaults)."""
    from ..identification._options import Options, cli_fields

    fields = [f for f in cli_fields() if f.metadata["group"] == "reading" or f.name in more]
    return Options(**{f.name: getattr(args, f.name) for f in fields if hasattr(args, f.name)})


def load_model(robot: str, friction: tuple[str, ...] | None = None):
    """A `RigidBodyModel` from a URDF/MJCF path, a shipped robot or a simulated robot name
    (`torchjfa.identification.load_model`)."""
    from ..identification import load_model as load

    return load(robot, friction)
