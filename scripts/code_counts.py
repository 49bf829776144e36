"""Structural counts of the package: what a maintainer checks before a change lands.

    python scripts/code_counts.py            # the table; exit status 1 when a rule is broken
    python scripts/code_counts.py --quiet    # the exit status alone

Rules: one function named ``identify`` in the package; no import cycle between its modules;
no module over ``MAX_MODULE_LINES`` lines; no function over ``MAX_FUNCTION_LINES`` lines (its
docstring not counted). Also
printed: the code lines (neither blank, nor comment, nor docstring) of the Bayesian JFA
implementation (``torchjfa/estimators/_jfa*.py``). Everything is read from the source with
`ast`; nothing is imported.
"""

from __future__ import annotations

import argparse
import ast
import io
import sys
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchjfa"
MAX_MODULE_LINES = 550
MAX_FUNCTION_LINES = 100
BAYES_JFA = "estimators/_jfa*.py"


def modules(root: Path = PACKAGE) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file under ``root``."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The package's modules that module ``name`` imports (absolute or relative), at any depth
    of its body (imports inside functions count: they are still a dependency)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            targets = [stem] + [f"{stem}.{a.name}" for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted.

    A package's ``__init__`` importing its own submodules, and those importing siblings through
    the package, is the usual re-export pattern, not a cycle: edges from a module to a package
    that contains it are dropped."""
    edges = {a: {b for b in bs if not a.startswith(b + ".")} for a, bs in graph.items()}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10_000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def long_functions(path: Path, limit: int = MAX_FUNCTION_LINES) -> list[tuple[str, int]]:
    """``(qualified name, lines)`` of the functions in ``path`` longer than ``limit`` lines:
    ``def`` line to last line, less the docstring (which may be as long as the reader needs)."""
    tree = ast.parse(path.read_text())
    out = []

    def walk(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    n = child.end_lineno - child.lineno + 1 - _docstring_lines(child)
                    if n > limit:
                        out.append((name, n))
                walk(child, name + ".")

    walk(tree, "")
    return out


def _docstring_lines(node) -> int:
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        if isinstance(body[0].value.value, str):
            return body[0].end_lineno - body[0].lineno + 1
    return 0


def identify_functions(files: dict[str, Path]) -> list[str]:
    """Every function definition named ``identify`` in the package, as ``module:line``."""
    out = []
    for name, path in files.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.name == "identify":
                out.append(f"{name}:{node.lineno}")
    return out


def code_lines(path: Path) -> int:
    """Lines holding code: not blank, not only a comment, not inside a docstring."""
    source = path.read_text()
    docstrings = set()
    for node in ast.walk(ast.parse(source)):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            value = body[0].value
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                docstrings.update(range(body[0].lineno, body[0].end_lineno + 1))
    lines = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT):
            continue
        if tok.type in (tokenize.DEDENT, tokenize.ENDMARKER):
            continue
        lines.update(range(tok.start[0], tok.end[0] + 1))
    return len(lines - docstrings)


def run(root: Path = PACKAGE, out=sys.stdout) -> dict[str, object]:
    """Print the counts; return them (``"ok"``: every rule holds)."""
    files = modules(root)
    known = set(files)
    graph = {name: imports(name, path, known) for name, path in files.items()}
    found = {
        "identify": identify_functions(files),
        "cycles": cycles(graph),
        "long_modules": sorted(
            (str(p.relative_to(root.parent)), n)
            for p in files.values()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES
        ),
        "long_functions": sorted(
            (f"{name}.{fn}", n) for name, p in files.items() for fn, n in long_functions(p)
        ),
        "bayes_jfa_code_lines": sum(code_lines(p) for p in sorted(root.glob(BAYES_JFA))),
    }
    found["ok"] = (
        len(found["identify"]) == 1
        and not found["cycles"]
        and not found["long_modules"]
        and not found["long_functions"]
    )
    print(f"functions named identify: {len(found['identify'])} ({', '.join(found['identify'])})",
          file=out)  # fmt: skip
    print(f"import cycles: {len(found['cycles'])}", file=out)
    for comp in found["cycles"]:
        print("  " + " <-> ".join(comp), file=out)
    print(f"modules over {MAX_MODULE_LINES} lines: {len(found['long_modules'])}", file=out)
    for path, n in found["long_modules"]:
        print(f"  {path}: {n}", file=out)
    print(f"functions over {MAX_FUNCTION_LINES} lines: {len(found['long_functions'])}", file=out)
    for fn, n in found["long_functions"]:
        print(f"  {fn}: {n}", file=out)
    print(f"Bayesian JFA code lines ({BAYES_JFA}): {found['bayes_jfa_code_lines']}", file=out)
    return found


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quiet", action="store_true", help="print nothing; exit status only")
    args = parser.parse_args(argv)
    found = run(out=io.StringIO() if args.quiet else sys.stdout)
    return 0 if found["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
