"""The benchmarks page, ``docs/benchmarks.md``, written by the benchmark scripts themselves.

Each benchmark script takes ``--write-docs``: what the run prints also goes into the script's
block of the page, between ``<!-- begin NAME -->`` and ``<!-- end NAME -->`` (appended at the
end of the page where it has none), stamped with the command, the machine and the date. The
rest of the page (what each benchmark measures, its targets) is prose the scripts leave alone.

    python scripts/bench_projection.py --write-docs              # docs/benchmarks.md
    python scripts/bench_projection.py --write-docs /tmp/page.md # another page (a check)

A smoke run (``--smoke``, ``--quick``) may write another page but not ``docs/benchmarks.md``:
its figures are no result.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import os
import platform
import re
import shlex
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the page the scripts write by default
PAGE = ROOT / "docs" / "benchmarks.md"
_NAME = re.compile(r"[A-Za-z0-9_.-]+")


def this_machine() -> str:
    """This machine in words: the CPU model and core count, the OS, Python's and torch's
    versions."""
    cpu = ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.partition(":")[2].strip()
                break
    cpu = cpu or platform.processor() or platform.machine() or "unknown CPU"
    torch = sys.modules.get("torch")
    if torch is None:
        try:
            import torch
        except ImportError:  # a page written without torch says so
            torch = None
    version = torch.__version__ if torch is not None else "not installed"
    return (
        f"{cpu}, {os.cpu_count()} cores; {platform.system()}, Python "
        f"{platform.python_version()}, torch {version}"
    )


def today() -> str:
    """The date of the run, UTC, ``YYYY-MM-DD``."""
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d")


def block(
    name: str, markdown: str, command: str, *, machine: str | None = None, date: str | None = None
) -> str:
    """The block of section ``name``: its markers, the stamp (command, machine, date) and
    ``markdown``."""
    if not _NAME.fullmatch(name):
        raise ValueError(f"a section name is letters, digits, '_', '.' and '-', got {name!r}")
    machine = this_machine() if machine is None else machine
    date = today() if date is None else date
    return (
        f"<!-- begin {name} -->\n"
        f"Command: `{command}`  \nMachine: {machine}  \nDate: {date}\n\n"
        f"{markdown.strip()}\n"
        f"<!-- end {name} -->"
    )


def write_section(
    name: str,
    markdown: str,
    command: str,
    path: str | Path | None = None,
    *,
    machine: str | None = None,
    date: str | None = None,
) -> Path:
    """Replace the block of section ``name`` in the page at ``path`` (default `PAGE`) with
    ``markdown``, stamped with ``command``, the machine and the date (this machine and today,
    UTC, unless given); a page without that block gets it appended, a missing page is created.
    The rest of the page is left as it is. Returns the page's path.

    Raises:
        ValueError: on a name with other characters than letters, digits, ``_``, ``.`` and
            ``-``, or a page holding the section's markers more than once or unpaired.
    """
    page = Path(PAGE if path is None else path)
    new = block(name, markdown, command, machine=machine, date=date)
    text = page.read_text(encoding="utf-8") if page.exists() else "# Benchmarks\n"
    begin, end = f"<!-- begin {name} -->", f"<!-- end {name} -->"
    found = re.findall(rf"^{re.escape(begin)}\n.*?^{re.escape(end)}$", text, re.S | re.M)
    markers = [len(re.findall(rf"^{re.escape(m)}$", text, re.M)) for m in (begin, end)]
    if len(found) > 1 or markers != [len(found)] * 2:
        raise ValueError(f"{page}: the markers of section {name!r} are repeated or unpaired")
    if found:
        text = text.replace(found[0], new)
    else:
        text = text.rstrip("\n") + "\n\n" + new + "\n"
    page.write_text(text, encoding="utf-8")
    return page


def fenced(text: str) -> str:
    """``text`` as a fenced block of plain text (as a terminal shows it)."""
    fence = "```"
    while fence in text:
        fence += "`"
    return f"{fence}text\n{text.strip(chr(10))}\n{fence}"


class _Tee(io.TextIOBase):
    """A text stream writing to ``stream`` and keeping a copy."""

    def __init__(self, stream):
        self.stream, self.copy = stream, io.StringIO()

    def write(self, s: str) -> int:
        self.copy.write(s)
        return self.stream.write(s)

    def flush(self) -> None:
        self.stream.flush()


@contextlib.contextmanager
def capture() -> Iterator[io.StringIO]:
    """Inside the block, what is printed to ``sys.stdout`` still goes there and is also kept
    in the yielded buffer."""
    tee = _Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield tee.copy


def add_option(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``--write-docs [PAGE]`` to a script's ``parser``."""
    parser.add_argument(
        "--write-docs",
        nargs="?",
        const=str(PAGE),
        default=None,
        metavar="PAGE",
        help="also write what this run prints into its section of docs/benchmarks.md (or of "
        "the page PAGE), stamped with the command, the machine and the date",
    )
    return parser


def command_line(script: str, argv: Sequence[str]) -> str:
    """The command a run stands for: ``python scripts/SCRIPT.py ARGS``, ``--write-docs`` and
    its page left out."""
    args, skip = [], False
    for i, arg in enumerate(argv):
        if skip:
            skip = False
        elif arg == "--write-docs":
            nxt = argv[i + 1] if i + 1 < len(argv) else "-"
            skip = not nxt.startswith("-")
        elif not arg.startswith("--write-docs="):
            args.append(arg)
    return " ".join(["python", f"scripts/{script}.py", *map(shlex.quote, args)])


@contextlib.contextmanager
def recording(
    name: str,
    script: str,
    page: str | Path | None,
    argv: Sequence[str] | None = None,
    *,
    smoke: bool = False,
    markdown: Callable[[str], str] = fenced,
) -> Iterator[None]:
    """Run the block and, where ``page`` is given (``--write-docs``), write what it printed
    (through ``markdown``, default a fenced block) into section ``name`` of ``page``, stamped
    with the command (``script`` and ``argv``, default ``sys.argv[1:]``).

    Raises:
        SystemExit: when a smoke run would write `PAGE`.
    """
    if page is None:
        yield
        return
    if smoke and Path(page).resolve() == PAGE.resolve():
        raise SystemExit(
            f"--write-docs: a smoke run's figures are no result; not written to {PAGE} "
            "(give another page: --write-docs PATH)"
        )
    argv = sys.argv[1:] if argv is None else argv
    with capture() as printed:
        yield
    written = write_section(name, markdown(printed.getvalue()), command_line(script, argv), page)
    print(f"wrote section {name} of {written}")
