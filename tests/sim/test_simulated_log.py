"""`SimulatedLog` is a `JointLog`: the log methods work on it and keep the ground truth aligned."""

import numpy as np
import pytest
import torch

from torchjfa.data import JointLog, LogError, regressor_noise, write_log
from torchjfa.sim import SensorNoise, SimulatedLog, SinusoidTrajectory, generate_log, load_log

JOINTS = ("a", "b", "c")
TRUTH = ("q_true", "qd_true", "qdd_true", "tau_true")
ARRAYS = ("q", "qd", "qdd", "tau", *TRUTH)


def _log(n=120) -> SimulatedLog:
    g = torch.Generator().manual_seed(0)
    arrays = {k: torch.randn(n, 3, generator=g, dtype=torch.float64) for k in ARRAYS}
    rng = np.random.default_rng(0)
    return SimulatedLog(
        robot="toy",
        joint_names=JOINTS,
        t=torch.arange(n, dtype=torch.float64) / 40.0,
        **arrays,
        period_samples=40,
        control_rate=40.0,
        noise=SensorNoise(position_std=(1e-3, 2e-3, 3e-3)),
        seed=5,
        effects={"damping": np.array([0.1, 0.2, 0.3])},
        trajectory=SinusoidTrajectory(
            1.0,
            rng.standard_normal(3),
            rng.random((3, 2)),
            np.array([[1, 2]] * 3),
            rng.standard_normal((3, 2)),
        ),  # fmt: skip
    )


def test_a_generated_log_is_a_joint_log():
    log = generate_log("head", n_samples=200, seed=0)
    assert isinstance(log, JointLog) and isinstance(log, SimulatedLog)
    assert log.n_periods == 200 // log.period_samples
    head, tail = log.split(0.25, gap=10)
    assert isinstance(head, SimulatedLog) and (head.n_samples, tail.n_samples) == (140, 50)
    assert torch.equal(tail.tau_true, log.tau_true[150:])
    assert set(log.signals()) == {"q", "qd", "qdd", "tau"}


@pytest.mark.parametrize(
    "index", [slice(10, 90), slice(0, 120, 3), torch.arange(120) % 7 == 0, [5, 3, 100]]
)
def test_select_keeps_the_truth_aligned(index):
    log = _log()
    part = log.select(index)
    assert isinstance(part, SimulatedLog) and part.robot == "toy" and part.seed == 5
    assert torch.equal(part.t, log.t[index])
    for k in ARRAYS:
        assert torch.equal(getattr(part, k), getattr(log, k)[index]), k
    contiguous = isinstance(index, slice) and index.step is None
    assert part.period_samples == (40 if contiguous else None)


def test_reorder_keeps_the_truth_noise_effects_and_trajectory_aligned():
    log = _log()
    order = ("c", "a", "b")
    perm = [2, 0, 1]
    r = log.reorder(order)
    assert isinstance(r, SimulatedLog) and r.joint_names == order
    for k in ARRAYS:
        assert torch.equal(getattr(r, k), getattr(log, k)[:, perm]), k
    assert r.noise.position_std == (3e-3, 1e-3, 2e-3)
    assert r.noise.torque_std == log.noise.torque_std  # a float for every joint stays one
    assert np.array_equal(r.effects["damping"], [0.3, 0.1, 0.2])
    for k in ("offset", "amplitude", "harmonic", "phase"):
        assert np.array_equal(getattr(r.trajectory, k), getattr(log.trajectory, k)[perm]), k
    back = r.reorder(JOINTS)
    assert all(torch.equal(getattr(back, k), getattr(log, k)) for k in ARRAYS)
    with pytest.raises(LogError, match=r"joint\(s\) \['c'\] are in the log"):
        log.reorder(("a", "b", "d"))


def test_save_load_of_a_selection_and_load_log(tmp_path):
    part = _log().select([1, 2, 3, 50])  # no period any more
    part.save(tmp_path / "part.npz")
    back = load_log(tmp_path / "part.npz")
    assert isinstance(back, SimulatedLog) and back.period_samples is None
    assert all(torch.equal(getattr(back, k), getattr(part, k)) for k in ARRAYS)
    plain = JointLog(t=part.t, q=part.q, tau=part.tau, joint_names=JOINTS)
    write_log(plain, tmp_path / "plain.csv")
    other = load_log(tmp_path / "plain.csv")
    assert type(other) is JointLog and torch.equal(other.tau, part.tau)
    with pytest.raises(LogError, match="no period_samples"):
        back.n_periods


def test_constructor_checks():
    log = _log()
    with pytest.raises(ValueError, match="qd and qdd"):
        SimulatedLog(**{**_fields(log), "qdd": None})
    with pytest.raises(ValueError, match="tau_true must have shape"):
        SimulatedLog(**{**_fields(log), "tau_true": log.tau_true[:10]})
    with pytest.raises(ValueError, match="period_samples must be positive"):
        SimulatedLog(**{**_fields(log), "period_samples": 0})


def _fields(log):
    import dataclasses

    return {f.name: getattr(log, f.name) for f in dataclasses.fields(log)}


def test_period_noise_of_a_simulated_log_and_of_its_plain_joint_log(head_sim):
    """Two code paths, one answer: the noise does not need the ground truth."""
    from torchjfa.dynamics import RigidBodyModel
    from torchjfa.sim import model_path

    model = RigidBodyModel.from_mjcf(model_path("head"))
    log = head_sim  # three periods of 1680 samples
    plain = JointLog(
        t=log.t, q=log.q, qd=log.qd, qdd=log.qdd, tau=log.tau, joint_names=log.joint_names,
        period_samples=log.period_samples,
    )  # fmt: skip
    a = regressor_noise(model, log, max_periods=3)
    b = regressor_noise(model, plain.reorder(log.joint_names[::-1]), max_periods=3)
    assert torch.equal(a.input_noise, b.input_noise)
    assert torch.equal(a.output_noise_per_joint, b.output_noise_per_joint)
    with pytest.raises(ValueError, match="prepare it first"):
        regressor_noise(model, JointLog(t=log.t, q=log.q, tau=log.tau, joint_names=log.joint_names))
    with pytest.raises(ValueError, match="no period_samples"):
        regressor_noise(model, plain.select(torch.arange(plain.n_samples)))
