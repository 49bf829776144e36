"""The package's structure rules (`scripts/code_counts.py`): one function named ``identify``, no
import cycle between its modules nor between its packages (imports inside functions counted),
imports only down the layers, no library module importing the command line, a small top level,
no module over 550 lines, no function over 100 (its docstring not counted)."""

import io

import code_counts

import torchjfa.cli

#: the first-level packages of the layout, and the only modules at the top
PACKAGES = {
    "cli", "data", "dynamics", "estimators", "excitation", "identification", "learning",
    "physical", "report", "robots", "sim",
}  # fmt: skip
TOP_LEVEL = {
    "__init__.py", "__main__.py", "_util.py", "_validation.py", "distributed.py", "io.py",
    "metrics.py", "stats.py",
}  # fmt: skip


def test_the_structure_rules_hold():
    found = code_counts.run(out=io.StringIO())
    (where,) = found["identify"]
    assert where.startswith("torchjfa.identification._identify:")
    assert found["cycles"] == []
    assert found["package_cycles"] == []
    assert found["layer_violations"] == []
    assert found["cli_importers"] == []
    assert found["long_modules"] == []
    assert found["long_functions"] == []
    assert set(found["top_level"]) <= TOP_LEVEL
    assert len(found["top_level"]) <= code_counts.MAX_TOP_LEVEL == 8
    assert found["ok"]


def test_the_layout_has_its_packages_and_every_command_line_in_cli():
    root = code_counts.PACKAGE
    found = {p.name for p in root.iterdir() if (p / "__init__.py").is_file()}
    assert found == PACKAGES
    # the command line's modules: one per sub-command, and no parser elsewhere
    commands = {p.stem for p in (root / "cli").glob("_*.py")} - {"__init__", "_common", "_main"}
    assert commands == {f"_{c}" for c in torchjfa.cli.COMMANDS}
    for path in root.rglob("*.py"):
        name = ".".join(path.relative_to(root.parent).with_suffix("").parts)
        text = path.read_text()
        parser = "add_argument(" in text or "ArgumentParser(" in text
        if parser and not name.startswith("torchjfa.cli."):
            assert name in code_counts.ENTRY_POINTS, name


def test_a_cycle_and_a_long_function_are_found(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from . import b\n")
    (package / "b.py").write_text("def f():\n    from .a import g\n" + "    x = 1\n" * 101)
    found = code_counts.run(root=package, out=io.StringIO())
    assert found["cycles"] == [["pkg.a", "pkg.b"]]
    assert found["long_functions"] == [("pkg.b.f", 103)]
    assert found["identify"] == [] and not found["ok"]


def test_a_package_cycle_through_a_function_and_an_upward_import_are_found():
    graph = {
        "torchjfa.dynamics._model": {"torchjfa.physical._project"},  # inside a function, say
        "torchjfa.physical._project": {"torchjfa.dynamics._model"},
        "torchjfa.sim._log": {"torchjfa.cli._main"},
        "torchjfa.cli._main": {"torchjfa.sim._log"},
        "torchjfa.data._log": {"torchjfa"},
    }
    packages = code_counts.package_graph(graph)
    assert sorted(map(sorted, code_counts.cycles(packages))) == [
        ["cli", "sim"],
        ["dynamics", "physical"],
    ]
    up = code_counts.layer_violations(packages)
    assert any(v.startswith("dynamics imports physical, a higher layer") for v in up)
    assert any(v.startswith("sim imports cli, a higher layer") for v in up)
    assert any(v.startswith("data imports torchjfa, which no layer names") for v in up)
    assert code_counts.cli_importers(graph) == ["torchjfa.sim._log"]
