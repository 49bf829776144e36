"""The package's words describe what it does now: no dates, issue numbers or the paper called
"the seed" in its docstrings, strings (help texts, messages) and comments, nor in the README."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "torchjfa"
README = ROOT / "README.md"

#: what must not appear, name -> pattern (``\s+``: a phrase may be wrapped over lines)
FORBIDDEN = {
    "a date": re.compile(r"\b20\d\d-\d\d-\d\d\b"),
    "an issue number": re.compile(r"\bissues?\s+#?\d+", re.I),
    "an issue reference": re.compile(r"(?<![\w&#'\"=])#\d{1,3}\b(?!-)"),
    "the paper called the seed": re.compile(r"\bthe\s+seed(?:\s+paper|'s)", re.I),
}
#: a colour written as hex digits (``"#333"``, ``"#1f77b4"``), which is no issue number
COLOUR = re.compile(r"#(?:[0-9a-fA-F]{3}|[0-9a-fA-F]{6}|[0-9a-fA-F]{8})")


def texts(path: Path) -> list[tuple[int, str]]:
    """``(line, text)`` of every string literal (docstrings included) and comment of a module;
    f-strings give their literal parts."""
    source = path.read_text(encoding="utf-8")
    out = [
        (node.lineno, node.value)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
    ]
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            out.append((tok.start[0], tok.string.lstrip("#")))
    return out


def found_in(text: str) -> list[tuple[int, str]]:
    """`FORBIDDEN` patterns found in ``text``: the line of each within ``text`` (0 the first)
    and its name, with what matched."""
    if COLOUR.fullmatch(text.strip()):
        return []
    return [
        (text[: m.start()].count("\n"), f"{name} ({' '.join(m.group(0).split())!r})")
        for name, p in FORBIDDEN.items()
        for m in p.finditer(text)
    ]


def offences(text: str) -> list[str]:
    """`FORBIDDEN` patterns found in ``text``: their names, with what matched."""
    return [what for _, what in found_in(text)]


def test_the_patterns_find_what_they_should_and_nothing_else():
    assert offences("fixed on 2026-12-02 (issue 19, #41)") == [
        "a date ('2026-12-02')",
        "an issue number ('issue 19')",
        "an issue reference ('#41')",
    ]
    assert offences("the seed paper's eq. 5; the seed's estimator") == [
        "the paper called the seed ('the seed paper')",
        'the paper called the seed ("the seed\'s")',
    ]
    for fine in ("#1f77b4", "color='#333'", "  # noqa: E501", "seed: the random seed", "a #-b",
                 "&#39;", "#333", "`--seed 3`", "Issue the command", "10 #"):  # fmt: skip
        assert offences(fine) == [], fine


def test_no_dates_issue_numbers_or_seed_paper_in_the_package():
    found = [
        f"{path.relative_to(ROOT)}:{line + offset}: {what}"
        for path in sorted(PACKAGE.rglob("*.py"))
        for line, text in texts(path)
        for offset, what in found_in(text)
    ]
    assert found == [], "\n".join(found)


def test_no_dates_issue_numbers_or_seed_paper_in_the_readme():
    found = [f"README.md:{1 + i}: {what}" for i, what in found_in(README.read_text("utf-8"))]
    assert found == [], "\n".join(found)
