"""Projection after identification on poorly exciting data of the 7-DoF Panda arm (its two finger
joints included): the consistent model predicts held-out torques better than the unconstrained
least-squares one."""

import math

import pytest
import torch

import torchjfa.robots
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import OLS
from torchjfa.physical import check, project


def _sines(g, q0, amplitude, freqs, duration, n):
    """Sum of sines around ``q0`` with analytic velocities and accelerations."""
    t = torch.linspace(0, duration, n, dtype=torch.float64)[:, None]
    dof = q0.shape[0]
    q = q0.expand(n, dof).clone()
    qd = torch.zeros(n, dof, dtype=torch.float64)
    qdd = torch.zeros(n, dof, dtype=torch.float64)
    for f in freqs:
        a = amplitude * torch.rand(dof, generator=g, dtype=torch.float64)
        phase = 2 * math.pi * torch.rand(dof, generator=g, dtype=torch.float64)
        w = 2 * math.pi * f
        q += a * torch.sin(w * t + phase)
        qd += a * w * torch.cos(w * t + phase)
        qdd -= a * w * w * torch.sin(w * t + phase)
    return q, qd, qdd


@pytest.fixture(scope="module")
def panda_fit():
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda"))
    n = model.n_dof
    theta_true = model.nominal_theta.clone()
    theta_true.reshape(n, -1)[:, 10] = 0.3  # viscous friction, N m s/rad
    assert check(theta_true, model).ok
    g = torch.Generator().manual_seed(0)
    fingers = torch.tensor([1.0] * 7 + [0.01, 0.01], dtype=torch.float64)
    # poorly exciting: 0.1 rad, 0.1 and 0.25 Hz around one posture, 0.5 N m torque noise
    q0 = torch.tensor([0, -0.3, 0, -2.0, 0, 1.8, 0.8, 0.02, 0.02], dtype=torch.float64)
    q, qd, qdd = _sines(g, q0, 0.1 * fingers, (0.1, 0.25), 10.0, 400)
    tau = model.inverse_dynamics(q, qd, qdd, theta_true)
    tau = tau + 0.5 * torch.randn(tau.shape, generator=g, dtype=torch.float64)
    moments = model.moments(q, qd, qdd, tau)
    theta_ols = OLS(fit_intercept=False).fit_moments(moments).coef_
    # held out: a richer trajectory around another posture, noise-free torques
    q1 = torch.tensor([0.3, 0.2, -0.2, -1.5, 0.3, 1.5, 0.0, 0.02, 0.02], dtype=torch.float64)
    qt, qdt, qddt = _sines(g, q1, 0.6 * fingers, (0.2, 0.5, 0.9), 10.0, 400)
    Y = model.regressor(qt, qdt, qddt)
    tau_test = Y @ theta_true

    def rmse(theta):
        return float(((Y @ theta - tau_test) ** 2).mean().sqrt())

    return model, moments, theta_ols, rmse


@pytest.mark.parametrize("parametrization", ["virtual", "log-cholesky"])
def test_projected_model_predicts_held_out_torques_better(panda_fit, parametrization):
    model, moments, theta_ols, rmse = panda_fit
    assert not check(theta_ols, model).weakly_ok  # poorly exciting data: OLS is inconsistent
    result = project(theta_ols, layout=model, moments=moments, parametrization=parametrization)
    report = check(result.theta, model)
    assert report.weakly_ok if parametrization == "virtual" else report.ok
    assert result.cost <= result.initial_cost
    assert rmse(result.theta) <= rmse(theta_ols)
