"""Legged robots' logs: written, read back, checked, and differentiated.

The log comes from `simulate_legged` (MuJoCo's own velocities and accelerations), so the
derivatives `prepare_legged` computes from the pose alone have an independent reference.
"""

from __future__ import annotations

import numpy as np
import pytest
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.data import LogError, differentiate, prepare_legged, read_legged_log
from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import contact_equations
from torchjfa.sim import simulate_legged

FEET = GO2_FEET
STANCE = GO2_STANCE


@pytest.fixture(scope="module")
def sim():
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, FEET, STANCE, seconds=4.0, rate=200.0, perturb=0.2, seed=3)
    return path, log


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_written_log_reads_back_as_it_was(sim, tmp_path, suffix):
    _, log = sim
    log.save(tmp_path / f"go2{suffix}")
    back = read_legged_log(tmp_path / f"go2{suffix}")
    assert back.joint_names == log.joint_names and back.a is None
    # CSV keeps every digit (%.17g); the quaternion is renormalised (a few ulps: a norm and a division)
    np.testing.assert_allclose(back.q, log.q, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(back.v, log.v)
    np.testing.assert_array_equal(back.tau, log.tau)
    assert set(back.contact) == set(FEET) and set(back.wrench) == set(FEET)
    np.testing.assert_array_equal(back.wrench["RL_foot"], log.wrench["RL_foot"])
    np.testing.assert_array_equal(back.contact["FR_foot"], log.contact["FR_foot"])


def test_derivatives_from_the_pose_alone_match_the_simulators(sim, tmp_path):
    path, log = sim
    cols = log.columns()
    for name in [*(c for c in cols if c.startswith(("base_v", "base_w", "qd_")))]:
        del cols[name]
    np.savez(tmp_path / "pose_only.npz", **cols)
    raw = read_legged_log(tmp_path / "pose_only.npz")
    assert raw.v is None
    prepared = prepare_legged(raw, cutoff_hz=20.0)
    inner = slice(100, -100)  # away from the filter's edges (0.5 s at 200 Hz)
    # the simulator's own velocities through the same filter: the derivatives of the
    # filtered pose (the base's from its quaternion) equal them up to the central
    # differences' error, well under 5 % of each signal's spread. (Its accelerations hold
    # the feet's impacts, which 200 Hz samples alias: they are checked through the
    # identification below.)
    smooth = differentiate(log.t, log.v, cutoff_hz=20.0).value.numpy()
    err = np.sqrt(np.mean((prepared.v[inner] - smooth[inner]) ** 2, axis=0))
    spread = np.sqrt(np.mean(smooth[inner] ** 2, axis=0))
    assert np.all(err < 0.05 * spread), err / spread
    # identification on the prepared log finds the simulated robot's total mass
    model = FloatingBaseModel.from_urdf(path, friction=())
    p = prepared
    Y, y = contact_equations(
        model, p.q[inner], p.v[inner], p.a[inner], None,
        wrenches={k: w[inner] for k, w in p.wrench.items()}, rows="base",
    )  # fmt: skip
    theta = np.linalg.lstsq(Y.reshape(-1, model.n_params).numpy(), y.reshape(-1).numpy(),
                            rcond=None)[0]  # fmt: skip
    mass = theta.reshape(-1, 10)[:, 0].sum()
    assert mass == pytest.approx(log.theta.reshape(-1, 10)[:, 0].sum(), rel=0.02)


def test_every_missing_or_contradictory_column_is_named_at_once(sim, tmp_path):
    _, log = sim
    cols = log.columns()
    for name in ("base_qw", "qd_FL_hip_joint", "tau_RR_calf_joint", "f_FL_foot_z"):
        del cols[name]
    np.savez(tmp_path / "bad.npz", **cols)
    with pytest.raises(LogError) as info:
        read_legged_log(tmp_path / "bad.npz")
    msg = str(info.value)
    for part in ("the base pose: 6 of 7 columns, missing ['base_qw']",
                 "joint velocities: 11 of 12 columns, missing ['qd_FL_hip_joint']",
                 "joint torques: 11 of 12", "the force on FL_foot: 2 of 3"):  # fmt: skip
        assert part in msg, msg
    np.savez(tmp_path / "none.npz", x=np.arange(3.0))
    with pytest.raises(LogError, match="no time column 't'; no base pose.*no joint positions"):
        read_legged_log(tmp_path / "none.npz")


def test_bad_values_in_a_legged_log_are_refused(sim, tmp_path):
    _, log = sim
    for change, pattern in (
        ({"base_qw": lambda x: 2 * x}, "not unit in"),
        ({"contact_FL_foot": lambda x: 0.5 + 0 * x}, "contact_FL_foot must hold 0 or 1"),
        ({"tau_FL_hip_joint": lambda x: np.where(np.arange(len(x)) == 7, np.nan, x)},
         r"1 rows hold NaN or inf \(rows \[7\]"),
        ({"t": lambda x: x[::-1].copy()}, "must increase strictly"),
    ):  # fmt: skip
        cols = log.columns()
        for name, f in change.items():
            cols[name] = f(cols[name])
        np.savez(tmp_path / "bad.npz", **cols)
        with pytest.raises(LogError, match=pattern):
            read_legged_log(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match=r"\.csv or \.npz"):
        log.save(tmp_path / "go2.txt")
    with pytest.raises(FileNotFoundError):
        read_legged_log(tmp_path / "absent.csv")
