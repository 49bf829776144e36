"""`torchjfa.identify` and its stages: the one flow behind ``torchjfa identify``.

The command, the one call and the stages run one by one in a notebook must be the same
computation: their reports agree to 1e-10 (the same arithmetic in the same order, so equal up
to nothing but the wall-clock entries)."""

import json
import math
import warnings

import pytest
import torch

import torchjfa
from torchjfa import identification as ident
from torchjfa.cli import main
from torchjfa.data import JointLog, read_log, write_log
from torchjfa.dynamics import RigidBodyModel
from torchjfa.sim import model_path

# a given cut-off (the choice is tested elsewhere); the bias correction with its fewest refits
FAST = {"jackknife": 2, "cutoff": 20.0, "bias_correction": 2}


def _numbers(x, prefix=""):
    """Every number of a report.json, by its path (the wall-clock entries left out)."""
    if isinstance(x, dict):
        for k, v in x.items():
            if k not in ("identify_seconds", "command"):
                yield from _numbers(v, f"{prefix}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _numbers(v, f"{prefix}[{i}]")
    elif isinstance(x, float):
        yield prefix, x


def _same_numbers(a: dict, b: dict, *, settings: bool = True) -> None:
    if not settings:  # the stages' report records no settings of its own
        a, b = ({k: v for k, v in r.items() if k != "settings"} for r in (a, b))
    na, nb = dict(_numbers(a)), dict(_numbers(b))
    assert na.keys() == nb.keys()
    for k, v in na.items():
        w = nb[k]
        assert (math.isnan(v) and math.isnan(w)) or abs(v - w) <= 1e-10 * max(abs(v), abs(w)), k


def _report(path) -> dict:
    return json.loads((path / "report.json").read_text())


def test_the_command_the_call_and_the_stages_give_one_report(head_csv, tmp_path, capsys):
    assert (
        main(
            ["identify", "head", str(head_csv), "--out", str(tmp_path / "cli"), "--quiet"]
            + ["--jackknife", "2", "--cutoff", "20", "--bias-correction", "2", "--no-plots"]
        )
        == 0
    )
    capsys.readouterr()
    options = torchjfa.Options(**FAST)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ident.IdentificationWarning)
        whole = torchjfa.identify("head", head_csv, options)
    whole.write(tmp_path / "call", plots=False)
    # stage by stage, public names only, as notebooks/real_robot.ipynb does
    model = ident.load_model("head", options.friction)
    raw = ident.read(head_csv, model, options)
    data = ident.prepare_data(model, raw, options)
    noise = ident.choose_noise(model, data, options)
    result = ident.fit(model, data, noise, options)
    result = ident.correct_bias(result, data, noise, options)
    result = ident.make_consistent(result, options)
    report = ident.validate(result, data, noise, {"warnings": data.warnings + noise.warnings})
    report.write(tmp_path / "stages", plots=False)
    cli = _report(tmp_path / "cli")
    _same_numbers(cli, _report(tmp_path / "call"))
    _same_numbers(cli, _report(tmp_path / "stages"), settings=False)
    assert cli["settings"]["validation"] == whole.report.settings["validation"]
    torch.testing.assert_close(whole.theta, result.theta, rtol=1e-10, atol=0)
    assert whole.identified_well and whole.problem() is None
    assert whole.headline()[1].startswith("held-out torque nMSE")


def test_a_joint_log_in_memory_is_read_like_its_file(head_csv, tmp_path):
    model = ident.load_model("head")
    from_file = ident.read(head_csv, model).log
    from_memory = ident.read(read_log(head_csv), model).log
    for k in ("t", "q", "qd", "tau"):
        torch.testing.assert_close(getattr(from_memory, k), getattr(from_file, k), rtol=0, atol=0)
    assert ident.load_model(model) is model


def test_a_log_worse_than_the_mean_warns_and_says_why(head_csv):
    log = read_log(head_csv)
    short = log.select(slice(0, 420))  # one second: the rows pass the count, not the hold-out
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = torchjfa.identify("head", short, torchjfa.Options(**FAST))
    ours = [str(w.message) for w in caught if w.category is ident.IdentificationWarning]
    assert not out.identified_well and "record a longer" in out.problem()
    assert ours[-1] == out.problem() and "worse than their mean" in ours[-1]
    assert ours[:-1] == out.warnings  # the stages' warnings, each issued once


def test_given_input_noise_reaches_the_estimator_and_the_metric(head_csv):
    model = ident.load_model("head")
    noise = torch.full((model.n_params,), 1e-12, dtype=torch.float64)
    options = torchjfa.Options(
        estimator="bayes-jfa",
        estimator_options={"max_iter": 50},
        input_noise=noise,
        jackknife=0,
        cutoff=20.0,
        project=False,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchjfa.identify(model, head_csv, options)
    assert out.noise.mode == "given"
    assert torch.equal(out.result.estimator.input_noise, noise)
    assert torch.equal(out.result.input_noise, noise)


def test_the_named_estimator_takes_the_period_noise_where_it_can():
    noise = torch.ones(3, dtype=torch.float64)
    bjfa = ident.make_estimator(torchjfa.Options(estimator="bayes-jfa"), noise)
    assert torch.equal(bjfa.input_noise, noise) and not bjfa.fit_intercept
    ols = ident.make_estimator(torchjfa.Options(estimator="ols"), noise)
    assert type(ols).__name__ == "OLS" and not ols.fit_intercept
    mine = torchjfa.estimators.Ridge(fit_intercept=False)
    assert ident.make_estimator(torchjfa.Options(estimator=mine), noise) is mine


def test_joint_terms_may_be_written_as_on_the_command_line():
    assert torchjfa.Options(friction="viscous, coulomb").friction == ("viscous", "coulomb")
    assert torchjfa.Options(friction=["offset"]).friction == ("offset",)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"estimator": "svm"}, "estimator must be one of"),
        ({"friction": ("viscous", "stiction")}, "unknown joint term"),
        ({"validation": 1.0}, "validation must be a fraction"),
        ({"cutoff": -3.0}, "cutoff must be"),
        ({"cutoff": "high"}, "cutoff must be"),
        ({"coulomb_velocity": -0.1}, "coulomb_velocity must be"),
        ({"coulomb_velocity": "wide"}, "coulomb_velocity must be"),
        ({"validation": None}, "validation must be a fraction"),
        ({"input_noise": "guess"}, "input_noise must be one of"),
        ({"description_prior": 1.0, "project": False}, "needs project=True"),
        ({"parametrization": "cholesky"}, "parametrization must be one of"),
    ],
)
def test_bad_options_are_refused_with_what_to_choose(changes, message):
    with pytest.raises(ident.IdentificationError, match=message):
        torchjfa.Options(**changes)


def test_a_missing_robot_file_and_input_noise_periods_without_periods_are_errors(
    head_csv, tmp_path
):
    with pytest.raises(ident.IdentificationError, match="no robot file"):
        ident.load_model(str(tmp_path / "nothing.urdf"))
    model = RigidBodyModel.from_mjcf(model_path("head"), friction=("viscous",))
    options = torchjfa.Options(input_noise="periods", period=None, cutoff=20.0)
    data = ident.prepare_data(model, ident.read(head_csv, model, options), options)
    with pytest.raises(ident.IdentificationError, match="needs a periodic excitation"):
        ident.choose_noise(model, data, options)


def test_a_validation_log_is_held_out_instead_of_the_end(head_csv, tmp_path):
    log = read_log(head_csv)
    half = log.n_samples // 2
    train, valid = tmp_path / "train.csv", tmp_path / "valid.csv"
    write_log(log.select(slice(0, half)), train)
    write_log(JointLog(**{**vars(log.select(slice(half, None))), "info": {}}), valid)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ident.IdentificationWarning)
        out = torchjfa.identify("head", train, torchjfa.Options(**FAST), validation_log=valid)
    assert out.report.settings["validation"] == f"separate log {valid}"
    assert out.data.validation.t[0] >= log.t[half] - 1e-12


def test_auto_input_noise_without_periods_is_propagated_where_the_estimator_takes_it(head_csv):
    """No periods: Bayesian JFA gets the sensor noise propagated through the flow (the same
    numbers as `propagated_noise` called on the stages' data), OLS none (as before), and
    ``"propagated"`` insists on it for any estimator; with periods, ``"auto"`` is periods."""
    from torchjfa.data import propagated_noise

    model = ident.load_model("head")
    options = torchjfa.Options(estimator="bayes-jfa", period=None, cutoff=20.0)
    data = ident.prepare_data(model, ident.read(head_csv, model, options), options)
    assert data.train.period_samples is None and data.raw.n_samples == read_log(head_csv).n_samples
    noise = ident.choose_noise(model, data, options)
    assert noise.mode == "propagated" and noise.period_noise is None and not noise.warnings
    direct = propagated_noise(
        data.model_for(model),  # the Coulomb term as the preparation chose it
        data.raw,
        data.preparation,
        joint_weights=noise.joint_weights,
        samples=data.train.n_samples,
    )
    assert torch.equal(noise.input_noise, direct.input_noise)
    assert noise.propagated.n_rows == data.train.n_samples * model.n_dof
    assert noise.how == direct.describe() and noise.how.startswith("propagated by Monte Carlo")
    ols = ident.choose_noise(model, data, options.replace(estimator="ols"))
    assert ols.mode == "learn" and ols.input_noise is None  # the default run is unchanged
    insisted = ident.choose_noise(
        model, data, options.replace(estimator="ols", input_noise="propagated")
    )
    assert insisted.mode == "propagated" and torch.equal(insisted.input_noise, direct.input_noise)
    periodic = options.replace(period="auto")
    data = ident.prepare_data(model, ident.read(head_csv, model, periodic), periodic)
    assert ident.choose_noise(model, data, periodic).mode == "periods"


def test_the_command_takes_input_noise_propagated_and_reports_how(head_csv, tmp_path, capsys):
    args = ["identify", "head", str(head_csv), "--out", str(tmp_path), "--quiet", "--no-plots"]
    args += ["--jackknife", "0", "--cutoff", "20", "--bias-correction", "0"]
    args += ["--input-noise", "propagated"]
    assert main(args) == 0
    capsys.readouterr()
    settings = _report(tmp_path)["settings"]
    assert settings["input_noise"] == "propagated"
    assert settings["input_noise_how"].startswith("propagated by Monte Carlo (8 draws")
    assert "white sensor noise from the spectrum's floor" in settings["input_noise_how"]
    text = (tmp_path / "report.md").read_text()
    assert "input noise (the log's sensor noise (from its spectrum) propagated" in text
