"""Delimited text logs (``.csv``, ``.tsv``, ``.txt``): the delimiter found from the first lines.

The delimiter is the first of tab, semicolon, comma and runs of spaces that splits the header
and each of the first `SNIFF_LINES` rows into the same number (more than one) of fields; the
file's suffix does not decide it (a tab-separated ``.csv`` is read as such). Values written with
decimal commas (``1,25``) are read in a file whose delimiter is not the comma; a comma-separated
file whose values hold decimal commas splits each value in two, and is refused by name.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from ._schema import LogError

__all__ = ["DELIMITER_NAMES", "SNIFF_LINES", "read_table", "sniff_delimiter"]

SNIFF_BYTES = 1 << 16  # the first 64 KiB of the file ...
SNIFF_LINES = 50  # ... and at most this many rows after the header decide the delimiter
SPACES = " "  # stands for runs of spaces and tabs
DELIMITER_NAMES = {"\t": "tab", ";": "semicolon ';'", ",": "comma ','", SPACES: "spaces"}


def _field_counts(lines: list[str], delimiter: str) -> list[int]:
    if delimiter == SPACES:
        return [len(line.split()) for line in lines]
    return [len(row) for row in csv.reader(lines, delimiter=delimiter)]


def _head_lines(path: Path) -> list[str]:
    with open(path, "rb") as fh:
        head = fh.read(SNIFF_BYTES)
    lines = head.decode("utf-8", errors="replace").lstrip("\ufeff").splitlines()
    if len(head) == SNIFF_BYTES and len(lines) > 1:
        lines = lines[:-1]  # the last line may be cut
    return [line for line in lines if line.strip()][: SNIFF_LINES + 1]


def sniff_delimiter(path: Path) -> str:
    """The delimiter of a text log: ``"\\t"``, ``";"``, ``","`` or `SPACES` (runs of blanks).

    Raises:
        LogError: when no candidate splits the header and the first rows alike; the message
            names what the comma gives and, when the rows have more comma-separated fields
            than the header, says that decimal commas need another delimiter.
    """
    lines = _head_lines(path)
    if len(lines) < 2:
        return ","  # a header alone (or nothing): the reader says what is missing
    counts = {d: _field_counts(lines, d) for d in DELIMITER_NAMES}
    for d, c in counts.items():
        if c[0] > 1 and len(set(c)) == 1:
            return d
    if counts[","][0] == 1 and counts[SPACES][0] == 1:
        return ","  # one column: the reader says which columns are missing
    comma = counts[","]
    row = next((i for i, c in enumerate(comma) if c != comma[0]), 1)
    hint = ""
    if comma[row] > comma[0]:
        hint = (
            "; if its values have decimal commas (1,25), the delimiter must be a semicolon or "
            "a tab (or write the values with decimal points)"
        )
    raise LogError(
        f"{path}: cannot tell the delimiter: none of tab, semicolon, comma or spaces splits the "
        f"header and the first {len(lines) - 1} rows into equally many fields (with commas the "
        f"header has {comma[0]} fields and line {row + 1} has {comma[row]}){hint}"
    )


def read_table(path: Path, *, drop_cut_line: bool = False, notes: list | None = None):
    """The text log at ``path`` as a pyarrow table, and its delimiter (a key of
    `DELIMITER_NAMES`). Column names are stripped of surrounding blanks; empty fields are null.

    With ``drop_cut_line``, a last line with fewer or more fields than the header (a log cut
    while it was written) is left out, and a line saying so is appended to ``notes``.

    Raises:
        LogError: when the delimiter cannot be told, or the file does not parse with it (the
            message names the delimiter tried, or the line whose fields do not match the
            header's).
    """
    import pyarrow as pa
    from pyarrow import csv as pa_csv

    delimiter = sniff_delimiter(path)
    convert = pa_csv.ConvertOptions(strings_can_be_null=True)
    cut = None
    try:
        if drop_cut_line:
            cut = _ragged_line(path, delimiter)
            if cut is not None and not cut[3]:
                cut = None  # a ragged line before the last: not a cut write; refused below
        if delimiter == SPACES or cut is not None:
            source, parse = _text_source(path, delimiter, None if cut is None else cut[0])
        else:
            source, parse = path, pa_csv.ParseOptions(delimiter=delimiter)
        table = pa_csv.read_csv(source, parse_options=parse, convert_options=convert)
    except (pa.ArrowInvalid, OSError, UnicodeError) as exc:
        ragged = _ragged_line(path, delimiter)
        if ragged is not None:
            line, got, want, last = ragged
            fix = (
                "drop it with drop_cut_line=True (--drop-cut-line), or fix it"
                if last
                else "only a last line may be dropped; fix that line"
            )
            raise LogError(
                f"{path}: line {line}{' (the last)' if last else ''} has {got} fields where the "
                f"header has {want} with the delimiter {DELIMITER_NAMES[delimiter]} (a log cut "
                f"while it was written ends so): {fix}"
            ) from None
        raise LogError(
            f"{path}: cannot read it as delimited text with the delimiter "
            f"{DELIMITER_NAMES[delimiter]} (found from its first lines): {exc}"
        ) from None
    if cut is not None and notes is not None:
        notes.append(f"dropped its last line {cut[0]}, cut while it was written ({cut[1]} of "
                     f"{cut[2]} fields)")  # fmt: skip
    names = [str(n).strip() for n in table.column_names]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise LogError(
            f"{path}: the columns {twice} are named more than once; rename or drop the copies "
            "(which of them is the signal cannot be told)"
        )
    return table.rename_columns(names), delimiter


def _ragged_line(path: Path, delimiter: str) -> tuple[int, int, int, bool] | None:
    """The first line (1-based) whose number of fields differs from the header's, both
    numbers, and whether it is the file's last non-blank line; None when every line has the
    header's (the parse failed for another reason). Fields are counted by splitting at the
    delimiter (quoted delimiters are not expected in numeric logs)."""

    def fields(line: str) -> int:
        return len(line.split()) if delimiter == SPACES else line.count(delimiter) + 1

    want, found = None, None
    with open(path, encoding="utf-8", errors="replace") as fh:
        for k, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            if found is not None:
                return (*found, False)  # another line follows the ragged one
            if want is None:
                want = fields(line)
            elif fields(line) != want:
                found = (k, fields(line), want)
    return None if found is None else (*found, True)


def _text_source(path: Path, delimiter: str, skip: int | None):
    """The file as bytes for pyarrow, blank lines left out, without line ``skip`` (1-based);
    runs of blanks become one tab (read as TSV) for `SPACES`."""
    from pyarrow import csv as pa_csv

    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = [ln for k, ln in enumerate(fh, start=1) if ln.strip() and k != skip]
    if delimiter == SPACES:
        text, parse = "\n".join("\t".join(ln.split()) for ln in lines), "\t"
    else:
        text, parse = "".join(ln if ln.endswith("\n") else ln + "\n" for ln in lines), delimiter
    return io.BytesIO(text.lstrip("\ufeff").encode()), pa_csv.ParseOptions(delimiter=parse)
