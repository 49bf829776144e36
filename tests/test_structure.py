"""The package's structure rules (`scripts/code_counts.py`): one function named ``identify``, no
import cycle between its modules, no module over 550 lines, no function over 100 (its docstring
not counted)."""

import io

import code_counts


def test_the_structure_rules_hold():
    found = code_counts.run(out=io.StringIO())
    (where,) = found["identify"]
    assert where.startswith("torchjfa.identification._identify:")
    assert found["cycles"] == []
    assert found["long_modules"] == []
    assert found["long_functions"] == []


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
