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


def read_table(path: Path):
    """The text log at ``path`` as a pyarrow table, and its delimiter (a key of
    `DELIMITER_NAMES`). Column names are stripped of surrounding blanks; empty fields are null.

    Raises:
        LogError: when the delimiter cannot be told, or the file does not parse with it (the
            message names the delimiter tried).
    """
    import pyarrow as pa
    from pyarrow import csv as pa_csv

    delimiter = sniff_delimiter(path)
    convert = pa_csv.ConvertOptions(strings_can_be_null=True)
    try:
        if delimiter == SPACES:  # runs of blanks: one tab between fields, then read as TSV
            with open(path, encoding="utf-8", errors="replace") as fh:
                text = "\n".join("\t".join(line.split()) for line in fh if line.strip())
            source = io.BytesIO(text.lstrip("\ufeff").encode())
            parse = pa_csv.ParseOptions(delimiter="\t")
        else:
            source, parse = path, pa_csv.ParseOptions(delimiter=delimiter)
        table = pa_csv.read_csv(source, parse_options=parse, convert_options=convert)
    except (pa.ArrowInvalid, OSError, UnicodeError) as exc:
        ragged = _ragged_line(path, delimiter)
        if ragged is not None:
            line, got, want = ragged
            raise LogError(
                f"{path}: line {line} has {got} fields where the header has {want} with the "
                f"delimiter {DELIMITER_NAMES[delimiter]} (a log cut while it was written ends "
                "so): delete that line, or fix it"
            ) from None
        raise LogError(
            f"{path}: cannot read it as delimited text with the delimiter "
            f"{DELIMITER_NAMES[delimiter]} (found from its first lines): {exc}"
        ) from None
    names = [str(n).strip() for n in table.column_names]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise LogError(
            f"{path}: the columns {twice} are named more than once; rename or drop the copies "
            "(which of them is the signal cannot be told)"
        )
    return table.rename_columns(names), delimiter


def _ragged_line(path: Path, delimiter: str) -> tuple[int, int, int] | None:
    """The first line (1-based) whose number of fields differs from the header's, with both
    numbers; None when every line has the header's (the parse failed for another reason).
    Fields are counted by splitting at the delimiter (quoted delimiters are not expected in
    numeric logs)."""

    def fields(line: str) -> int:
        return len(line.split()) if delimiter == SPACES else line.count(delimiter) + 1

    want = None
    with open(path, encoding="utf-8", errors="replace") as fh:
        for k, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            if want is None:
                want = fields(line)
            elif fields(line) != want:
                return k, fields(line), want
    return None
