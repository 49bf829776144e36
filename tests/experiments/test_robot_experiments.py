"""The robot experiments (Tables I and II) end to end in smoke sizes, and their exactness."""

import math

import matplotlib
import pytest
import torch
from experiments import robots

from torchjfa.dynamics import RigidBodyModel
from torchjfa.physical import check
from torchjfa.sim import SensorNoise, generate_log, load_robot, model_path, random_trajectory

matplotlib.use("Agg")


@pytest.fixture(scope="module")
def head_smoke(tmp_path_factory):
    # MuJoCo writes its warnings to MUJOCO_LOG.TXT in the working directory
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(tmp_path_factory.mktemp("mujoco"))
        return robots.run(("head",), smoke=True)["head"]


def test_smoke_pipeline_has_every_row(head_smoke):
    res = head_smoke
    assert [r["method"] for r in res.rows] == [*robots.METHODS, robots.REFERENCE]
    assert set(res.identified) == set(robots.METHODS)
    assert set(res.control) == {*robots.METHODS, robots.REFERENCE}
    for r in res.rows:
        assert isinstance(r["success"], bool)
        assert math.isfinite(r["nmse_clean"]) and math.isfinite(r["nmse_measured"])
        if r["success"]:
            assert r["reason"] is None
            assert all(r[k] > 0 for k in ("rms_position", "rms_velocity", "rms_feedback"))
        else:
            assert r["reason"] and math.isnan(r["rms_feedback"])
    reference = res.rows[-1]
    assert reference["success"] and reference["consistent_after"]
    table = robots.format_table(res)
    for label in (robots.LABELS[m] for m in (*robots.METHODS, robots.REFERENCE)):
        assert label in table
    assert table.count("FAILURE") >= 3 * sum(not r["success"] for r in res.rows)


def test_projected_estimates_are_consistent(head_smoke):
    model = RigidBodyModel.from_mjcf(model_path("head"))
    for method, ident in head_smoke.identified.items():
        assert ident.theta.shape == (model.n_params,), method
        report = check(ident.theta, model)
        # eq. 5's guarantees: positive mass, PSD inertia at the centre of mass, friction >= 0
        assert report.weakly_ok, (method, str(report))
        assert ident.consistent_after


def test_plot_writes_png(head_smoke, tmp_path):
    fig = robots.plot_tracking(head_smoke, tmp_path / "head.png")
    assert (tmp_path / "head.png").stat().st_size > 1000
    assert len(fig.axes) == 3


def test_true_parameters_track_better_than_a_wrong_model(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    model = RigidBodyModel.from_mjcf(model_path("head"))
    theta = robots.true_theta(model, "head")
    # independent check of true_theta: the MJCF's masses and MuJoCo's dof_damping
    mj = load_robot("head")
    masses = theta[[model.layout.index(j, "m") for j in range(model.n_dof)]]
    assert float(masses.sum()) == pytest.approx(float(mj.body_mass.sum()), rel=1e-12)
    wrong = theta.clone()
    per = model.layout.params_per_joint
    for j in range(model.n_dof):  # every body 60 % too heavy: consistent but wrong
        wrong[j * per : j * per + 10] *= 1.6
    traj = random_trajectory(mj, seed=1000)
    out = robots.evaluate_control(
        "head", model, {"true": theta, "wrong": wrong}, traj, duration=0.3
    )
    assert out["true"].success
    if out["wrong"].success:
        assert out["true"].mean_rms_position < out["wrong"].mean_rms_position
        assert out["true"].mean_rms_feedback < out["wrong"].mean_rms_feedback


def test_noiseless_rigid_body_data_are_identified_exactly(tmp_path, monkeypatch):
    """Zero noise, unmodeled effects off, the simulator's signals: ridge and noise-informed
    Bayesian JFA predict held-out MuJoCo torques to 1e-6 relative."""
    monkeypatch.chdir(tmp_path)
    exact_bjfa = {"noise_y_floor": 1e-12, "noise_floor": 1e-12, "tol": 1e-15, "coef_tol": 1e-12}
    exact_bjfa["max_iter"] = 60000  # the Newton optimiser converges after about 850 iterations
    res = robots.run_robot(
        "head",
        n_samples=1680,
        methods=("ridge", "bjfa-noise"),
        noise=SensorNoise.zero(),
        unmodeled=False,
        signals="true",
        base_frequency=1.0,
        test_duration=0.5,
        control=False,
        noise_periods=None,
        options={"bjfa": exact_bjfa, "project": {"max_iter": 5, "warm_start": False}},
    )
    assert float(res.noise.input_noise.abs().max()) < 1e-8  # exactly periodic motion
    model = RigidBodyModel.from_mjcf(model_path("head"))
    mj = load_robot("head", unmodeled=False)
    held_out = generate_log(
        "head",
        n_samples=400,
        unmodeled=False,
        noise=SensorNoise.zero(),
        trajectory=random_trajectory(mj, base_frequency=0.5, seed=77),
    )
    perm = [held_out.joint_names.index(j) for j in model.joint_names]
    q, qd, qdd, tau = (
        getattr(held_out, k)[:, perm] for k in ("q_true", "qd_true", "qdd_true", "tau_true")
    )
    Y = model.regressor(q, qd, qdd)
    for method in ("ridge", "bjfa-noise"):
        theta_hat = res.identified[method].theta_hat
        rel = float(torch.linalg.norm(Y @ theta_hat - tau) / torch.linalg.norm(tau))
        assert rel < 1e-6, (method, rel)
        assert check(res.identified[method].theta, model).weakly_ok
    assert res.rows[-1]["nmse_clean"] < 1e-20  # the reference row: the true parameters


def test_goal_check_formula():
    def fake(feedback: dict[str, float | None]) -> robots.RobotResult:
        rows = [
            {"method": m, "success": v is not None, "rms_feedback": math.nan if v is None else v}
            for m, v in feedback.items()
        ]
        return robots.RobotResult("x", rows, {}, {}, None)

    out = robots.goal_check(
        {
            "a": fake({"ridge": 1.0, "bjfa": 0.95, "bjfa-noise": 0.85}),
            "b": fake({"ridge": None, "bjfa": None, "bjfa-noise": 2.0}),
        }
    )
    assert out["robots"]["a"]["best_bayes"] == "bjfa-noise"
    assert out["robots"]["a"]["reduction"] == pytest.approx(0.15)
    assert out["robots"]["b"]["reduction"] == math.inf and out["met"]
    out = robots.goal_check({"a": fake({"ridge": 1.0, "bjfa": 0.95, "bjfa-noise": None})})
    assert out["robots"]["a"]["reduction"] == pytest.approx(0.05) and not out["met"]
    out = robots.goal_check({"a": fake({"ridge": 1.0, "bjfa": None, "bjfa-noise": None})})
    assert out["robots"]["a"]["bayes_failed"] and not out["met"]


def test_bad_arguments_raise():
    model = RigidBodyModel.from_mjcf(model_path("head"))
    x = torch.zeros(4, model.n_dof, dtype=torch.float64)
    with pytest.raises(ValueError, match="signals"):
        robots.run_robot("head", signals="clean")
    with pytest.raises(ValueError, match="n_blocks"):
        robots.block_moments(model, x, x, x, x, n_blocks=1)
    folds = robots.block_moments(model, x + 0.1, x, x, x + 1.0, n_blocks=2)
    with pytest.raises(ValueError, match="unknown method"):
        robots.fit_methods(model, folds, methods=("ols",))
    with pytest.raises(ValueError, match="input_noise"):
        robots.fit_methods(model, folds, methods=("bjfa-noise",))
    with pytest.raises(TypeError, match="folds"):
        robots.fit_methods(model, folds[:1])


def test_weighted_run_uses_weighted_fold_moments(tmp_path, monkeypatch):
    """weighting='residual': the folds are the weighted moments of contiguous blocks."""
    monkeypatch.chdir(tmp_path)
    kw = {"n_samples": 1260, "methods": ("ridge",), "base_frequency": 1.0, "test_duration": 0.25,
          "control": False, "noise_periods": None, "n_blocks": 3}  # fmt: skip
    res = robots.run_robot("head", weighting="residual", **kw)
    w = torch.tensor(res.settings["joint_weights"], dtype=torch.float64)
    assert w.shape == (7,) and float(w.mean()) == pytest.approx(1.0)
    assert float(w.max() / w.min()) > 2.0  # the joints' residuals differ
    plain = robots.run_robot("head", **kw)
    assert plain.settings["joint_weights"] is None
    # same data, same estimator: only the weights differ, and they change the estimate
    est_w = res.identified["ridge"].theta_hat
    est_p = plain.identified["ridge"].theta_hat
    assert not torch.allclose(est_w, est_p)
    with pytest.raises(ValueError, match="weighting"):
        robots.run_robot("head", weighting="gautier", **kw)
