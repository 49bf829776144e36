"""``torchjfa identify``'s options are `Options`' fields: the same defaults, choices and groups,
and an option that does not apply is refused instead of ignored."""

import argparse
from dataclasses import MISSING, fields

import pytest

import torchjfa
from torchjfa.cli import build_parser, identify_options, main
from torchjfa.identification import Compute, IdentificationError, Options, load_model
from torchjfa.identification._options import GROUPS, cli_fields


def _identify_parser() -> argparse.ArgumentParser:
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices["identify"]


def _default(f):
    return f.default_factory() if f.default is MISSING else f.default


def test_every_field_says_where_it_belongs_on_the_command_line():
    for cls in (Options, Compute):
        for f in fields(cls):
            assert f.metadata["group"] in GROUPS, f.name
            assert f.metadata["help"] or not f.metadata["cli"], f.name


def test_every_command_default_is_its_fields():
    parser = _identify_parser()
    actions = {a.dest: a for a in parser._actions}
    listed = cli_fields()
    assert {f.name for f in listed} >= {"cutoff", "estimator", "friction", "jackknife", "compiled"}
    for f in listed:
        assert actions[f.name].default == _default(f), f.name
    # and the whole: the command's options without flags are the library's defaults (progress
    # bars on, as a terminal wants them: --quiet turns them off)
    args = parser.parse_args(["robot.urdf", "log.csv"])
    assert identify_options(args) == Options(compute=Compute(progress=True))


def test_choices_come_from_the_fields():
    actions = {a.dest: a for a in _identify_parser()._actions}
    assert tuple(actions["estimator"].choices) == torchjfa.estimators.available()
    assert tuple(actions["parametrization"].choices) == ("log-cholesky", "virtual")
    assert tuple(actions["input_noise"].choices) == ("auto", "learn", "periods", "propagated")


def test_the_help_groups_the_options():
    text = _identify_parser().format_help()
    positions = [text.index(title + ":") for title in GROUPS.values()]
    assert positions == sorted(positions)


def test_flags_parse_into_the_fields():
    parser = _identify_parser()
    args = parser.parse_args(
        ["r.urdf", "l.csv", "--estimator", "bayes-jfa", "--max-iter", "50", "--ard", "output",
         "--period", "none", "--cutoff", "12", "--description-prior", "0", "--no-project",
         "--friction", "viscous", "--columns", "t=time", "--chunk-size", "100", "--quiet"]
    )  # fmt: skip
    options = identify_options(args)
    assert options.estimator_options == {"max_iter": 50, "ard": "output"}
    assert options.period is None and options.cutoff == 12.0
    assert options.description_prior is None and not options.project
    assert options.friction == ("viscous",) and options.columns == {"t": "time"}
    assert options.compute == Compute(chunk_size=100, progress=False)
    args = parser.parse_args(["r", "l", "--estimator-options", "max_iter=7", "--max-iter", "8",
                              "--estimator", "jfa"])  # fmt: skip
    with pytest.raises(IdentificationError, match="both set max_iter"):
        identify_options(args)


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--max-iter", "50"], "estimator 'ols' takes no option max_iter"),
        (["--ard", "output", "--estimator", "ridge"], "estimator 'ridge' takes no option ard"),
        (["--estimator-options", "alpha=1"], "estimator 'ols' takes no option alpha"),
        (["--friction", "viscous", "--coulomb-velocity", "0.1"], "smooths the Coulomb term"),
        (["--skip-start", "auto", "--period", "none"], "needs a period"),
        (["--no-project", "--description-prior", "auto"], "drop --no-project"),
    ],
)
def test_an_option_that_does_not_apply_is_an_error(flags, message, tmp_path, capsys):
    code = main(["identify", "panda_arm", str(tmp_path / "log.csv"), *flags])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err


def test_options_that_do_not_apply_are_refused_from_python():
    mine = torchjfa.estimators.Ridge(fit_intercept=False)
    with pytest.raises(IdentificationError, match="used as it is"):
        Options(estimator=mine, estimator_options={"alpha": 1.0})
    with pytest.raises(IdentificationError, match="takes no option"):
        Options(estimator="lasso", estimator_options={"ard": "output"})
    model = load_model("panda_arm", ("viscous",))
    assert load_model(model) is model and load_model(model, ["viscous"]) is model
    with pytest.raises(IdentificationError, match="joint terms"):
        load_model(model, ("viscous", "coulomb"))


def test_only_the_simulation_and_the_mjcf_reader_import_mujoco():
    """The command and the flow import MuJoCo only where they simulate, read or write MJCF, or
    check an excitation against the description's collision meshes (the
    ``pytorch_kinematics`` package imports it on its own when a chain is built)."""
    import ast
    import subprocess
    import sys
    from pathlib import Path

    package = Path(torchjfa.__file__).parent
    importers = set()
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""]
            if any(n.split(".")[0] == "mujoco" for n in names):
                importers.add(path.relative_to(package).as_posix())
    allowed = ("dynamics/_mjcf.py", "excitation/_meshes.py")
    assert importers and all(p.startswith("sim/") or p in allowed for p in importers)
    code = "import sys, torchjfa.cli, torchjfa.identification; assert 'mujoco' not in sys.modules"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_the_commands_help_imports_neither_torch_nor_the_flow():
    """``torchjfa --help`` answers at once: the package's top level, the command line's entry
    and its list of sub-commands import torch only when a command needs it."""
    import subprocess
    import sys

    code = (
        "import sys, contextlib, io\n"
        "from torchjfa.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    try:\n"
        "        main(['--help'])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "assert 'identify' in out.getvalue(), out.getvalue()\n"
        "heavy = sorted(m for m in ('torch', 'numpy', 'scipy', 'mujoco') if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    import torchjfa

    assert torchjfa.identify is torchjfa.identification.identify  # the top level, when used
    assert "Options" in dir(torchjfa) and "Options" in torchjfa.__all__
    assert torchjfa.io.read_identified and torchjfa.dynamics.FloatingBaseModel  # subpackages
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        torchjfa.nothing  # noqa: B018
