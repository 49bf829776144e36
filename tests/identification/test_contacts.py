"""Floating-base regression with contacts, on samples Pinocchio computes from a hidden truth.

The truth is the Go2's description with every body's mass, centre of mass and inertia
perturbed (in Pinocchio, so the data come from an independent implementation). Each sample
has three or four feet on the ground; the feet's forces are the ones that make the base's
equation hold (the minimum-norm solution), and the joint torques follow from the full
equation of motion ``M a + h = S^T tau + J_c^T f``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _robots import GO2_FEET, PinocchioFreeFlyer, erd_path

from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import contact_equations

FEET = GO2_FEET


@pytest.fixture(scope="module")
def go2():
    pin = pytest.importorskip("pinocchio")
    path = erd_path("go2_description/urdf/go2.urdf")
    model = FloatingBaseModel.from_urdf(path, friction=())
    ref = PinocchioFreeFlyer(pin, path, model)
    pm = ref.pm
    rng = np.random.default_rng(11)
    for j in range(1, pm.njoints):  # the hidden truth: every body perturbed, still physical
        old = pm.inertias[j]
        pm.inertias[j] = pin.Inertia(
            old.mass * rng.uniform(0.8, 1.2),
            old.lever + rng.normal(scale=0.01, size=3),
            old.inertia * rng.uniform(0.7, 1.3),
        )
    ref.pd = pm.createData()
    truth = ref.theta()[ref.cols]

    def samples(count: int, seed: int):
        rng = np.random.default_rng(seed)
        q = rng.normal(scale=0.5, size=(count, 7 + model.n_dof))
        q[:, 3:7] = rng.normal(size=(count, 4))
        q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
        v, a = rng.normal(size=(2, count, 6 + model.n_dof))
        on = np.ones((count, 4))
        # half the samples with a foot in the air (two point contacts cannot balance a
        # moment about the line through them, so random accelerations need three)
        on[np.arange(count // 2), np.arange(count // 2) % 4] = 0.0
        tau = np.zeros((count, model.n_dof))
        forces = np.zeros((count, 4, 3))
        for b in range(count):
            gen = ref.rnea(q[b], v[b], a[b])
            down = [k for k in range(4) if on[b, k]]
            J = np.concatenate(
                [Jk[:3] for Jk in ref.frame_jacobians(q[b], [FEET[k] for k in down])]
            )
            f = np.linalg.lstsq(J[:, :6].T, gen[:6], rcond=None)[0]
            assert np.allclose(J[:, :6].T @ f, gen[:6], atol=1e-9 * np.abs(gen).max())
            forces[b, down] = f.reshape(-1, 3)
            tau[b] = gen[6:] - J[:, 6:].T @ f
        flags = {name: on[:, k] for k, name in enumerate(FEET)}
        wrenches = {name: forces[:, k] for k, name in enumerate(FEET)}
        return q, v, a, tau, flags, wrenches

    return model, truth, samples


def _fit(Y: torch.Tensor, y: torch.Tensor) -> np.ndarray:
    A, b = Y.reshape(-1, Y.shape[-1]).numpy(), y.reshape(-1).numpy()
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _total_mass(theta: np.ndarray) -> float:
    return float(theta.reshape(-1, 10)[:, 0].sum())  # friction=(): 10 per body


def test_measured_forces_identify_the_truth(go2):
    model, truth, samples = go2
    q, v, a, tau, _, wrenches = samples(60, seed=1)
    theta = _fit(*contact_equations(model, q, v, a, tau, wrenches=wrenches))
    # noise-free data: the identifiable part of theta is the truth's to round-off
    assert _total_mass(theta) == pytest.approx(_total_mass(truth), rel=1e-9)
    q, v, a, tau, _, wrenches = samples(20, seed=2)
    Y, y = contact_equations(model, q, v, a, tau, wrenches=wrenches, rows="all")
    np.testing.assert_allclose(Y.numpy() @ theta, y.numpy(), atol=1e-8 * np.abs(y.numpy()).max())


def test_base_rows_alone_give_total_mass_without_joint_torques(go2):
    model, truth, samples = go2
    q, v, a, _, _, wrenches = samples(60, seed=3)
    Y, y = contact_equations(model, q, v, a, None, wrenches=wrenches, rows="base")
    assert Y.shape == (60, 6, model.n_params)
    theta = _fit(Y, y)
    assert _total_mass(theta) == pytest.approx(_total_mass(truth), rel=1e-9)
    # the centre of mass of the whole robot at a held-out configuration
    q2, v2, a2, _, _, w2 = samples(10, seed=4)
    Y2, y2 = contact_equations(model, q2, v2, a2, None, wrenches=w2, rows="base")
    np.testing.assert_allclose(Y2.numpy() @ theta, y2.numpy(), atol=1e-8 * np.abs(y2.numpy()).max())


def test_contact_flags_alone_project_the_forces_out(go2):
    model, truth, samples = go2
    q, v, a, tau, flags, _ = samples(80, seed=5)
    Y, y = contact_equations(model, q, v, a, tau, contacts=flags)
    theta = _fit(Y, y)
    q2, v2, a2, tau2, flags2, _ = samples(20, seed=6)
    Y2, y2 = contact_equations(model, q2, v2, a2, tau2, contacts=flags2, rows="projected")
    scale = np.abs(y2.numpy()).max()
    np.testing.assert_allclose(Y2.numpy() @ theta, y2.numpy(), atol=1e-7 * scale)
    np.testing.assert_allclose(Y2.numpy() @ truth, y2.numpy(), atol=1e-9 * scale)
    # without the projection the unknown forces leave the fit far off: the rows are needed
    Yn = model.regressor(q, v, a)
    yn = torch.cat([torch.zeros(q.shape[0], 6, dtype=torch.float64), torch.as_tensor(tau)], 1)
    naive = _fit(Yn, yn)
    assert np.abs(Y2.numpy() @ naive - y2.numpy()).max() > 1e-2 * scale


def test_bad_contact_inputs_are_refused(go2):
    model, _, samples = go2
    q, v, a, tau, flags, wrenches = samples(4, seed=7)
    with pytest.raises(ValueError, match="rows must be one of"):
        contact_equations(model, q, v, a, tau, contacts=flags, rows="some")
    with pytest.raises(ValueError, match="needs the measured contact wrenches"):
        contact_equations(model, q, v, a, tau, contacts=flags, rows="base")
    with pytest.raises(ValueError, match="needs contact flags"):
        contact_equations(model, q, v, a, tau, rows="projected")
    with pytest.raises(ValueError, match="0 \\(no contact\\) or 1"):
        contact_equations(model, q, v, a, tau, contacts={"FL_foot": np.full(4, 0.5)})
    with pytest.raises(ValueError, match="no frame named"):
        contact_equations(model, q, v, a, tau, contacts={"hand": np.ones(4)})
    with pytest.raises(ValueError, match=r"must have shape \(4, 3\)"):
        contact_equations(model, q, v, a, tau, wrenches={"FL_foot": np.ones((4, 2))})
    with pytest.raises(ValueError, match="not among the contacts"):
        contact_equations(model, q, v, a, tau, contacts=flags, flat=("base",))
