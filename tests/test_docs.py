"""The documentation site: it builds without a warning, the getting-started examples run as
written, the pages describe the library as it is now, their links lead somewhere, and the API
reference renders every public name."""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: pages written and measured elsewhere: the dated measurements live there
DATED = {DOCS / "benchmarks.md"}

#: what the pages must not say, name -> pattern (``\s+``: a phrase may be wrapped over lines)
FORBIDDEN = {
    "a date": re.compile(r"\b20\d\d-\d\d-\d\d\b"),
    "an issue number": re.compile(r"\bissues?\s+#?\d+", re.I),
    "an issue reference": re.compile(r"(?<![\w&#'\"=/])#\d+\b"),
    "a session": re.compile(r"\bsessions?\b", re.I),
    "a path outside the repository": re.compile(r"\.\./shared"),
    "the paper called the seed": re.compile(r"\bthe\s+seed(?:\s+paper|'s)", re.I),
}
#: a markdown link or image: ``[text](target)``, ``![alt](target "title")``
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
#: a mkdocstrings directive: ``::: torchjfa.module.name``, with its indented options
DIRECTIVE = re.compile(r"^::: *(\S+)\n((?:[ \t]+\S.*\n?)*)", re.M)


def pages() -> list[Path]:
    return sorted(DOCS.rglob("*.md"))


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```$", path.read_text(encoding="utf-8"), re.S | re.M)


def test_the_site_builds_without_warnings(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra (pip install -e '.[docs]') builds it")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's banner about MkDocs 2
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
         str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    output = run.stdout + run.stderr
    assert run.returncode == 0, output
    assert "WARNING" not in output, output
    assert (tmp_path / "site" / "api" / "identification" / "index.html").is_file()


def test_the_getting_started_examples_run_as_written(tmp_path, monkeypatch, capsys):
    page = DOCS / "getting-started.md"
    blocks = python_blocks(page)
    assert len(blocks) >= 3, "getting-started.md lost its python examples"
    monkeypatch.chdir(tmp_path)  # the examples write a log and a report folder
    namespace: dict = {"__name__": "__docs__"}
    for k, code in enumerate(blocks):
        exec(compile(code, f"{page}, python block {k + 1}", "exec"), namespace)
    assert (tmp_path / "result" / "report.md").is_file()
    assert (tmp_path / "result" / "model.npz").is_file()
    # the identification ends with a model that predicts the held-out torques, and the
    # building blocks with one that predicts the log's torques to well under their spread
    assert namespace["ident"].identified_well
    rms = float(capsys.readouterr().out.split(" N m RMS")[0].split()[-1])
    assert rms < 0.2 * float(namespace["tau"].std())


def test_the_report_pages_own_folder_example_runs_as_written(tmp_path, monkeypatch):
    (block,) = python_blocks(DOCS / "report.md")
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "report.md", "exec"), {"__name__": "__docs__"})
    manifest = json.loads((tmp_path / "my_result" / "manifest.json").read_text())
    assert manifest["command"] == "my_script.py" and set(manifest["files"]) == {"notes.txt"}


def test_the_floating_base_pages_examples_run_as_written(capsys):
    try:
        importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    page = DOCS / "floating-base.md"
    namespace: dict = {"__name__": "__docs__"}
    for k, code in enumerate(python_blocks(page)):
        exec(compile(code, f"{page}, python block {k + 1}", "exec"), namespace)
    out = capsys.readouterr().out
    standing = float(out.split("the ground carries ")[1].split()[0])
    identified = float(out.split("from the base rows: ")[1].split()[0])
    # the URDF's masses summed here, independently of the library
    import xml.etree.ElementTree as ET

    urdf = ET.parse(namespace["path"]).getroot()
    total = sum(float(m.get("value")) for m in urdf.iter("mass"))
    assert standing == pytest.approx(total, abs=1e-3)  # printed to 3 decimals
    assert identified == pytest.approx(total, abs=1e-3)
    simulated, found = (float(x) for x in re.findall(r"(?:simulated|identified) ([\d.]+) kg", out))
    assert found == pytest.approx(simulated, abs=1e-4)  # printed to 4 decimals
    assert abs(simulated - total) > 1e-3  # the simulated robot is not the description


def test_the_pages_describe_the_library_as_it_is_now():
    found = []
    for path in pages():
        if path in DATED:
            continue
        text = path.read_text(encoding="utf-8")
        for name, pattern in FORBIDDEN.items():
            for m in pattern.finditer(text):
                line = text[: m.start()].count("\n") + 1
                found.append(f"{path.relative_to(ROOT)}:{line}: {name} ({m.group(0)!r})")
    assert not found, "\n".join(found)


def test_every_relative_link_leads_to_a_file_of_the_site():
    broken = []
    for path in pages():
        text = re.sub(r"^```.*?^```$", "", path.read_text(encoding="utf-8"), flags=re.S | re.M)
        for m in LINK.finditer(text):
            target = m.group(1)
            if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
                continue  # a web address, or a place on the same page
            file = (path.parent / target.split("#")[0]).resolve()
            if not file.is_file() or DOCS.resolve() not in file.parents:
                broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "links to nothing, or out of docs/:\n" + "\n".join(broken)


def _exported(module) -> list[str]:
    """The public names of a package: ``__all__``, else its ``import x as x`` re-exports."""
    if hasattr(module, "__all__"):
        return list(module.__all__)
    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    return [
        alias.asname
        for node in tree.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
        if alias.asname is not None and alias.asname == alias.name
    ]


def _resolve(identifier: str):
    parts = identifier.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for part in parts[k:]:
            obj = getattr(obj, part)
        return obj
    raise ImportError(identifier)


def test_the_api_reference_renders_every_public_name():
    import types

    rendered: dict[str, object] = {}  # identifier -> object, for every rendered name
    for path in sorted((DOCS / "api").glob("*.md")):
        for m in DIRECTIVE.finditer(path.read_text(encoding="utf-8")):
            identifier, options = m.group(1), m.group(2)
            obj = _resolve(identifier)
            rendered[identifier] = obj
            if isinstance(obj, types.ModuleType) and "members: false" not in options:
                for name in _exported(obj):
                    rendered[f"{identifier}.{name}"] = getattr(obj, name)
    ids = {id(obj) for obj in rendered.values()}
    missing = []
    for name in ("torchjfa", *sorted(f"torchjfa.{p.parent.name}" for p in
                                     (ROOT / "torchjfa").glob("[!_]*/__init__.py"))):  # fmt: skip
        package = importlib.import_module(name)
        for public in _exported(package):
            obj = getattr(package, public)
            if isinstance(obj, types.ModuleType):
                continue  # a subpackage: its own page
            if f"{name}.{public}" not in rendered and id(obj) not in ids:
                missing.append(f"{name}.{public}")
    assert not missing, "not in docs/api/ (add a '::: NAME' line): " + ", ".join(missing)
