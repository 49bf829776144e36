"""Structural counts of the package: what a maintainer checks before a change lands.

    python scripts/code_counts.py            # the table; exit status 1 when a rule is broken
    python scripts/code_counts.py --quiet    # the exit status alone

Rules: one function named ``identify`` in the package; no import cycle between its modules,
nor between its packages; every import down the layers (``LAYERS``: a package imports only
from its own layer or below), so that no library module imports the command line; at most
``MAX_TOP_LEVEL`` modules at the top of the package; no module over ``MAX_MODULE_LINES``
lines; no function over ``MAX_FUNCTION_LINES`` lines (its docstring not counted). Imports
inside functions count everywhere: they are still dependencies. Also
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
            subs = [f"{stem}.{a.name}" for a in node.names]
            # ``from pkg import module`` depends on the module; the package's own __init__
            # counts only where a name is not a module of it
            targets = subs if all(t in known for t in subs) else [stem, *subs]
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


#: the package's layers, bottom first: a package imports only from its own layer or below,
#: and the command line (``cli``) only from above (no library module imports it)
LAYERS = (
    ("_validation", "_util", "stats", "metrics", "robots"),
    ("data", "distributed"),
    ("estimators", "dynamics"),
    ("physical",),
    ("io",),
    ("report",),
    ("identification", "excitation", "sim", "learning"),
    ("cli",),
)
#: command-line entry points outside ``cli`` (``python -m torchjfa`` and the ``python -m``
#: aliases of sub-commands), which belong to the command line's layer wherever their file lies
ENTRY_POINTS = ("torchjfa.__main__", "torchjfa.sim.__main__", "torchjfa.learning.cli")
#: the most modules (``.py`` files) at the top of the package
MAX_TOP_LEVEL = 8


def package_of(name: str) -> str:
    """The first-level package (or top-level module) a dotted module name belongs to:
    ``torchjfa.sim._log`` -> ``sim``; an entry point (`ENTRY_POINTS`) -> ``cli``; the package's
    own ``__init__`` -> ``torchjfa``."""
    if name in ENTRY_POINTS:
        return "cli"
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def package_graph(graph: dict[str, set[str]]) -> dict[str, dict[str, list[str]]]:
    """Package -> imported package -> the ``"module -> module"`` imports that make the edge
    (imports inside functions count). The package's ``__init__`` (its public face, which
    imports every layer) is left out."""
    out: dict[str, dict[str, list[str]]] = {}
    for a, targets in graph.items():
        pa = package_of(a)
        if pa == a.split(".")[0]:
            continue
        for b in targets:
            pb = package_of(b)
            if pb != pa:
                out.setdefault(pa, {}).setdefault(pb, []).append(f"{a} -> {b}")
    return out


def layer_violations(packages: dict[str, dict[str, list[str]]]) -> list[str]:
    """Imports that go up the layers (`LAYERS`), and packages no layer names."""
    level = {p: i for i, layer in enumerate(LAYERS) for p in layer}
    out = [f"{p}: in no layer" for p in sorted(packages) if p not in level]
    for a, edges in sorted(packages.items()):
        for b, why in sorted(edges.items()):
            if b not in level:
                out.append(f"{a} imports {b}, which no layer names ({why[0]})")
            elif a in level and level[b] > level[a]:
                out.append(f"{a} imports {b}, a higher layer ({why[0]})")
    return out


def cli_importers(graph: dict[str, set[str]]) -> list[str]:
    """Modules outside the command line (``cli`` and `ENTRY_POINTS`) that import it."""
    return sorted(
        a
        for a, targets in graph.items()
        if package_of(a) != "cli" and any(package_of(b) == "cli" for b in targets)
    )


def top_level_modules(root: Path = PACKAGE) -> list[str]:
    """The ``.py`` files directly in the package."""
    return sorted(p.name for p in root.glob("*.py"))


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
    packages = package_graph(graph)
    found["package_cycles"] = cycles({a: set(b) for a, b in packages.items()})
    found["layer_violations"] = layer_violations(packages)
    found["top_level"] = top_level_modules(root)
    found["cli_importers"] = cli_importers(graph)
    found["ok"] = (
        len(found["identify"]) == 1
        and not found["cycles"]
        and not found["long_modules"]
        and not found["long_functions"]
        and not found["package_cycles"]
        and not found["layer_violations"]
        and not found["cli_importers"]
        and len(found["top_level"]) <= MAX_TOP_LEVEL
    )
    print(f"functions named identify: {len(found['identify'])} ({', '.join(found['identify'])})",
          file=out)  # fmt: skip
    print(f"import cycles: {len(found['cycles'])}", file=out)
    for comp in found["cycles"]:
        print("  " + " <-> ".join(comp), file=out)
    print(f"package cycles: {len(found['package_cycles'])}", file=out)
    for comp in found["package_cycles"]:
        print("  " + " <-> ".join(comp), file=out)
    print(f"imports up the layers: {len(found['layer_violations'])}", file=out)
    for line in found["layer_violations"]:
        print("  " + line, file=out)
    print(f"library modules importing the command line: {len(found['cli_importers'])}",
          file=out)  # fmt: skip
    for name in found["cli_importers"]:
        print("  " + name, file=out)
    print(f"top-level modules: {len(found['top_level'])} (at most {MAX_TOP_LEVEL}): "
          f"{', '.join(found['top_level'])}", file=out)  # fmt: skip
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
