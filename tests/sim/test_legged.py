"""A simulated legged robot: MuJoCo's contact dynamics against the floating-base regressor.

MuJoCo integrates the Go2 standing on its four feet; its recorded state, joint torques and
foot wrenches must satisfy ``Y(q, v, a) theta_true = [0; tau] + sum J^T w`` (the regressor is
an independent implementation of the same mechanics), and regression on them must find the
simulated robot, not the description it was perturbed from.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import consistent_floating, contact_equations, contact_moments
from torchjfa.sim import simulate_legged
from torchjfa.stats import Moments

FEET = GO2_FEET
STANCE = GO2_STANCE


@pytest.fixture(scope="module")
def go2():
    path = erd_path("go2_description/urdf/go2.urdf")
    model = FloatingBaseModel.from_urdf(path, friction=())
    logs = [
        simulate_legged(path, FEET, STANCE, seconds=3.0, rate=100.0, perturb=0.2, seed=seed)
        for seed in (1, 1, 2)  # one robot (truth_seed 0), the same motion twice, then another
    ]
    return path, model, logs


def _rows(model, log, **kw):
    if kw.get("rows") == "projected":
        return contact_equations(model, log.q, log.v, log.a, log.tau, contacts=log.contact, **kw)
    return contact_equations(model, log.q, log.v, log.a, log.tau, wrenches=log.wrench, **kw)


def test_the_simulated_log_obeys_the_floating_base_equations(go2):
    _, model, (log, again, _) = go2
    assert log.q.shape == (300, 7 + model.n_dof)
    assert list(log.wrench) == list(FEET) and log.wrench["FL_foot"].shape == (300, 6)
    np.testing.assert_array_equal(log.q, again.q)  # one seed, one log
    assert np.mean(list(log.contact.values())) > 0.95  # standing: the feet stay down
    np.testing.assert_allclose(np.linalg.norm(log.q[:, 3:7], axis=1), 1.0, atol=1e-12)
    Y, y = _rows(model, log, rows="all")
    scale = float(np.abs(y.numpy()).max())
    # MuJoCo's contact forces are solved to a tolerance of 1e-14: the equations hold to
    # round-off of the recorded forces; the description (the robot before perturbation)
    # misses them by percents
    assert np.abs(Y.numpy() @ log.theta - y.numpy()).max() < 1e-7 * scale
    assert np.abs(Y.numpy() @ model.nominal_theta.numpy() - y.numpy()).max() > 1e-2 * scale


def _total_mass(theta: np.ndarray) -> float:
    return float(theta.reshape(-1, 10)[:, 0].sum())


def test_regression_on_the_log_finds_the_simulated_robot(go2):
    _, model, (log, *_) = go2
    truth, described = _total_mass(log.theta), _total_mass(model.nominal_theta.numpy())
    assert abs(truth - described) > 1e-3  # the perturbation changed the mass (by 19 g)
    for rows in ("all", "base"):
        Y, y = (x.numpy() for x in _rows(model, log, rows=rows))
        theta = np.linalg.lstsq(Y.reshape(-1, model.n_params), y.reshape(-1), rcond=None)[0]
        assert _total_mass(theta) == pytest.approx(truth, rel=1e-6)


def test_contact_flags_alone_project_mujocos_contact_forces_out(go2):
    """The ground pushes on a spherical foot at the sphere's bottom, not at the foot frame
    (its centre): the wrench about the centre has a moment (radius x tangential force), so
    the feet are projected as `flat` (six directions) and then the forces vanish exactly."""
    _, model, (log, _, other) = go2
    Y, y = (x.numpy() for x in _rows(model, log, rows="projected", flat=FEET))
    scale = float(np.abs(y).max())
    assert np.abs(Y @ log.theta - y).max() < 1e-9 * scale
    Yp, yp = (x.numpy() for x in _rows(model, log, rows="projected"))
    assert np.abs(Yp @ log.theta - yp).max() > 1e-3 * scale  # as points they do not
    # a standing robot's flags leave much undetermined: the smallest change from the
    # description that fits one log predicts another log of the same robot better
    described = model.nominal_theta.numpy()
    A, b = Y.reshape(-1, model.n_params), y.reshape(-1)
    theta = described + np.linalg.lstsq(A, b - A @ described, rcond=None)[0]
    Y2, y2 = (x.numpy() for x in _rows(model, other, rows="projected", flat=FEET))
    assert np.abs(Y2 @ other.theta - y2).max() < 1e-9 * scale  # the same robot
    rms = lambda th: float(np.sqrt(np.mean((Y2 @ th - y2) ** 2)))  # noqa: E731
    assert rms(theta) < 0.5 * rms(described)


def test_stepping_lifts_each_foot_in_turn_and_lets_contact_flags_weigh_the_robot(go2):
    """With every foot on the ground, the total mass lies in the null space of the rows with
    the contact forces projected out; stepping in place (a foot in the air at a time) brings it
    back, so that flags alone weigh the robot (noise-free rows, MuJoCo's accelerations)."""
    path, model, _ = go2
    steps = simulate_legged(path, FEET, STANCE, seconds=8.0, rate=100.0, perturb=0.2, seed=1,
                            step=0.05)  # fmt: skip
    on = np.stack([steps.contact[f] for f in FEET], 1)
    assert (on.sum(1) >= 3).mean() > 0.98  # one foot at a time (another may unload briefly)
    assert ((1 - on).mean(0) > 0.02).all()  # each foot in the air for a while
    standing = simulate_legged(path, FEET, STANCE, seconds=8.0, rate=100.0, perturb=0.2, seed=1,
                               amplitude=0.05)  # fmt: skip
    assert (np.stack([standing.contact[f] for f in FEET], 1) == 1).mean() > 0.99
    mass = torch.zeros(model.n_params, dtype=torch.float64)
    mass[[0, *range(10, model.n_params, 10)]] = 1.0  # the bodies' masses (no joint terms)
    truth = float(mass @ torch.as_tensor(steps.theta))

    def mass_spread(log):
        """The total mass's standard deviation per unit noise on every row, and its least-
        squares value."""
        Y, y = _rows(model, log, rows="projected")
        A, b = Y.reshape(-1, model.n_params), y.reshape(-1)
        _, S, Vh = torch.linalg.svd(A, full_matrices=False)
        keep = S > 1e-13 * S[0]
        spread = float((((Vh[keep] @ mass) / S[keep]) ** 2).sum().sqrt())
        null = float(mass @ mass - (Vh[keep] @ mass).pow(2).sum())  # its share outside the rows
        theta = torch.linalg.lstsq(A, b[:, None], driver="gelsd").solution[:, 0]
        return spread, null, float(mass @ theta)

    spread, null, got = mass_spread(steps)
    assert null < 1e-12 and spread < 1.0  # kg per N m of row noise
    # the point feet stand for spheres of 2 cm (the moment of their tangential force about the
    # centre is left out): a bias well under 2 %
    assert got == pytest.approx(truth, rel=0.02)
    _, null_standing, _ = mass_spread(standing)
    assert null_standing > 1e-3  # the total mass is partly in the rows' null space


def test_measured_forces_predict_another_log_of_the_robot(go2):
    _, model, (log, _, other) = go2
    Y, y = (x.numpy() for x in _rows(model, log, rows="all"))
    theta = np.linalg.lstsq(Y.reshape(-1, model.n_params), y.reshape(-1), rcond=None)[0]
    Y2, y2 = (x.numpy() for x in _rows(model, other, rows="all"))
    assert np.abs(Y2 @ theta - y2).max() < 1e-6 * float(np.abs(y2).max())


def test_the_log_writes_its_columns_as_csv_and_npz(go2, tmp_path):
    _, model, (log, *_) = go2
    log.save(tmp_path / "go2.csv")
    log.save(tmp_path / "go2.npz")
    header = (tmp_path / "go2.csv").read_text().splitlines()[0].split(",")
    assert header[:8] == ["t", "base_x", "base_y", "base_z", "base_qx", "base_qy", "base_qz",
                          "base_qw"]  # fmt: skip
    assert {"qd_FL_hip_joint", "tau_RR_calf_joint", "contact_RL_foot", "f_FR_foot_z",
            "m_FL_foot_x", "base_wz"} <= set(header)  # fmt: skip
    table = np.loadtxt(tmp_path / "go2.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(
        table[:, header.index("f_FR_foot_z")], log.wrench["FR_foot"][:, 2]
    )
    with np.load(tmp_path / "go2.npz") as npz:
        np.testing.assert_array_equal(npz["q_FL_calf_joint"], log.q[:, 7 + 2])
        assert sorted(npz.files) == sorted(header)
    with pytest.raises(ValueError, match=r"\.csv or \.npz"):
        log.save(tmp_path / "go2.txt")


def test_bad_legged_simulations_are_refused(go2):
    path, _, _ = go2
    with pytest.raises(ValueError, match=r"no link named \['paw'\]"):
        simulate_legged(path, ("paw",), STANCE, seconds=0.1)
    with pytest.raises(ValueError, match=r"stance names \['knee'\], which are not joints"):
        simulate_legged(path, FEET, {"knee": 1.0}, seconds=0.1)
    with pytest.raises(ValueError, match="seconds must be > 0"):
        simulate_legged(path, FEET, STANCE, seconds=0.0)
    with pytest.raises(ValueError, match="the robot fell"):
        simulate_legged(path, FEET, {}, seconds=3.0, amplitude=1.5)


def test_streamed_moments_equal_the_stacked_rows(go2):
    _, model, (log, *_) = go2
    for rows, flat in (("all", ()), ("projected", FEET), ("base", ())):
        m = contact_moments(model, log, rows=rows, flat=flat, chunk_size=70)  # 300 = 4x70 + 20
        Y, y = _rows(model, log, rows=rows, flat=flat)
        whole = Moments.from_data(Y.reshape(-1, model.n_params), y.reshape(-1))
        scale = float(whole.xtx.abs().max())
        torch.testing.assert_close(m.xtx, whole.xtx, rtol=0, atol=1e-12 * scale)
        torch.testing.assert_close(
            m.xty, whole.xty, rtol=0, atol=1e-12 * float(whole.xty.abs().max())
        )
        assert m.n_rows == whole.n_rows
    with pytest.raises(ValueError, match="prepare it first"):
        contact_moments(model, replace(log, a=None))


def test_the_consistent_fit_keeps_every_body_physical_and_predicts_another_log(go2):
    _, model, (log, _, other) = go2
    m = contact_moments(model, log, rows="all")
    hat = torch.linalg.lstsq(m.xtx, m.xty, driver="gelsd").solution
    theta, projection, report = consistent_floating(model, m, hat, prior_weight=1.0)
    assert theta.shape == (model.n_params,)
    assert report.joint_names[0] == model.base_name and bool(report.body_ok.all())
    Y2, y2 = (x.numpy() for x in _rows(model, other, rows="all"))
    scale = float(np.abs(y2).max())
    # noise-free data: a consistent theta (the truth) fits exactly, so the projection's
    # answer fits the log to the optimiser's tolerance; on another log, the directions this
    # log barely excites (moved freely to reach the consistent set) cost a little
    rms = lambda th: float(np.sqrt(np.mean((Y2 @ th - y2) ** 2)))  # noqa: E731
    assert rms(theta.numpy()) < 1e-3 * scale
    assert rms(theta.numpy()) < 0.05 * rms(model.nominal_theta.numpy())
