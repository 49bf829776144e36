"""The report's numbers and files, without the command line."""

import matplotlib
import numpy as np
import pytest
import torch

from torchjfa.data import JointLog
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import BayesianJFA
from torchjfa.pipeline import identify
from torchjfa.report import make_report, torque_errors
from torchjfa.sim import generate_log, model_path


def test_torque_errors_by_hand():
    rng = np.random.default_rng(0)
    tau = rng.standard_normal((200, 3)) * [1.0, 2.0, 0.1]
    pred = tau + rng.standard_normal((200, 3)) * 0.1
    nmse, rms = torque_errors(torch.from_numpy(tau), torch.from_numpy(pred))
    err = pred - tau
    np.testing.assert_allclose(rms.numpy(), np.sqrt((err**2).mean(0)))
    np.testing.assert_allclose(nmse.numpy(), (err**2).mean(0) / tau.var(0))


@pytest.fixture(scope="module")
def report():
    model = RigidBodyModel.from_mjcf(model_path("head"))
    sim = generate_log("head", n_samples=3000, seed=5)
    log = JointLog(
        t=sim.t, q=sim.q, qd=sim.qd, qdd=sim.qdd, tau=sim.tau, joint_names=sim.joint_names
    )
    train, valid = log.split(0.25)
    est = BayesianJFA(fit_intercept=False, max_iter=2000)
    result = identify(model, train, estimator=est, jackknife=3)
    return make_report(result, valid.reorder(tuple(reversed(model.joint_names))))


def test_fits_are_on_the_models_joint_order(report):
    v = report.validation
    assert v.joint_names == report.model.joint_names
    Y = report.model.regressor(v.q, v.qd, v.qdd)
    nmse, _ = torque_errors(v.tau, Y @ report.result.theta)
    torch.testing.assert_close(report.fits["identified"].nmse, nmse)
    assert set(report.fits) == {"identified", "unconstrained", "description"}


def test_parameter_rows_and_markdown_without_settings(report):
    rows = report.parameter_rows()
    assert len(rows) == report.model.n_params
    assert any(r["relevance"] is not None for r in rows)
    assert all(r["jackknife_std"] is not None for r in rows)
    md = report.markdown()
    assert "report: None" not in md and "(None)" not in md and "data: None" not in md
    assert md.startswith("# Identification report: sarcos_head.xml")
    assert md.count("\n| ") >= report.model.n_dof + report.model.n_params


def test_write_leaves_the_pyplot_backend_alone(report, tmp_path):
    before = matplotlib.get_backend()
    paths = report.write(tmp_path)
    assert matplotlib.get_backend() == before
    assert paths["torques"].read_bytes()[:4] == b"\x89PNG"
    assert "parameters.png" in paths["markdown"].read_text()
