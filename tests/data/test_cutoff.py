"""`choose_cutoff`: the filter cut-off from held-out torque prediction, against the raw torque."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchjfa.data import COULOMB_GRID, JointLog, LogError, choose_cutoff, cutoff_grid

RATE = 500.0


class _Linear:
    """A one-joint 'robot' whose torque is linear in the motion: tau = 2 qdd + 0.5 qd."""

    joint_names = ("j",)

    def regressor(self, q, qd, qdd, *, compiled=None):
        return torch.stack([qdd, qd], dim=-1)  # (n, 1, 2)


def _log(seconds=24.0, q_noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE)) / RATE
    w = 2 * np.pi * np.array([0.4, 0.9, 1.3])
    q = (np.sin(w[None] * t[:, None]) / w).sum(1)
    qd = np.cos(w[None] * t[:, None]).sum(1)
    qdd = (-w * np.sin(w[None] * t[:, None])).sum(1)
    tau = 2.0 * qdd + 0.5 * qd
    q = q + q_noise * rng.standard_normal(q.shape)
    return JointLog(t=t, q=q[:, None], tau=tau[:, None], joint_names=("j",), source="sim")


def test_the_grid_is_log_spaced_between_its_ends():
    g = cutoff_grid(2.0, 30.0, 8)
    assert len(g) == 8 and g[0] == 2.0 and g[-1] == 30.0
    # rounded to 3 significant digits: each value within 0.5 % of the exact one (5e-3 in log)
    exact = np.linspace(np.log(2.0), np.log(30.0), 8)
    np.testing.assert_allclose(np.log(g), exact, atol=5e-3)
    with pytest.raises(ValueError, match="low_hz < high_hz"):
        cutoff_grid(30.0, 2.0)


def test_without_noise_the_largest_cut_off_is_chosen():
    # a linear model commutes with the zero-phase filter, so every cut-off above the motion's
    # 1.3 Hz predicts the raw torque to the filter's pass-band ripple: the data cannot tell
    # them apart, and the largest (the least distortion) is chosen
    choice = choose_cutoff(
        _Linear(), _log(), grid_hz=(0.5, 4.0, 8.0, 16.0), velocity="differentiate"
    )
    assert choice.cutoff_hz == 16.0
    assert choice.grid_hz == (0.5, 4.0, 8.0, 16.0)
    # 0.5 Hz filters most of the motion away: its score is far worse than the others'
    assert choice.scores[0] > 100 * max(choice.scores[1:])
    assert "chosen by held-out torque prediction over 0.5..16 Hz" in choice.how


def test_noisy_positions_push_the_choice_below_the_top_of_the_grid():
    # 1 mrad of white noise on q: twice differentiated at 60 Hz it swamps qdd (~ sigma w^2
    # sqrt(2 fc / rate) ~ 0.001 * 377^2 * 0.5 = 70 rad/s^2 against a signal of ~10), while 4 Hz
    # keeps the 1.3 Hz motion and removes most of the noise; the raw torque (noise-free here)
    # is the target, so only the prediction decides
    choice = choose_cutoff(
        _Linear(),
        _log(q_noise=1e-3),
        grid_hz=cutoff_grid(0.5, 60.0, 8),
        velocity="differentiate",
    )
    assert 1.3 < choice.cutoff_hz < 20.0
    assert choice.scores[-1] > 10 * min(choice.scores)
    assert choice.best_hz <= choice.cutoff_hz


def test_bad_inputs_are_named():
    log = _log(seconds=6.0)
    with pytest.raises(ValueError, match="n_folds"):
        choose_cutoff(_Linear(), log, n_folds=1)
    with pytest.raises(ValueError, match="positive cut-offs"):
        choose_cutoff(_Linear(), log, grid_hz=(0.0, 4.0))
    other = JointLog(t=log.t, q=log.q, tau=log.tau, joint_names=("k",), source="sim")
    with pytest.raises(ValueError, match="reorder"):
        choose_cutoff(_Linear(), other)
    with pytest.raises(LogError, match="too short to choose a cut-off"):
        choose_cutoff(_Linear(), _log(seconds=3.0), grid_hz=(0.5, 4.0))
    with pytest.raises(LogError, match="below"):
        choose_cutoff(_Linear(), log, grid_hz=(300.0,))


class _Dry(_Linear):
    """`_Linear` plus viscous and Coulomb columns, the Coulomb one ``tanh(qd / v)`` (sign at 0),
    with the `RigidBodyModel` interface `choose_cutoff` uses for it."""

    friction = ("viscous", "coulomb")

    def __init__(self, coulomb_velocity=0.0):
        self.coulomb_velocity = coulomb_velocity

    def with_coulomb_velocity(self, v):
        return _Dry(v)

    def regressor(self, q, qd, qdd, *, compiled=None):
        v = self.coulomb_velocity
        dry = torch.tanh(qd / v) if v else torch.sign(qd)
        return torch.stack([qdd, qd, dry], dim=-1)  # (n, 1, 3)


def _dry_log(v_true):
    """`_log`'s motion with 0.3 N m of dry friction of smoothing velocity ``v_true`` added to
    its torque (the motion's exact velocity, so the truth is the model with ``v_true``)."""
    log = _log()
    w = 2 * np.pi * np.array([0.4, 0.9, 1.3])
    qd = np.cos(w[None] * log.t.numpy()[:, None]).sum(1)
    dry = np.tanh(qd / v_true) if v_true else np.sign(qd)
    tau = log.tau[:, 0].numpy() + 0.3 * dry
    return JointLog(t=log.t, q=log.q, tau=tau[:, None], joint_names=("j",), source="sim")


@pytest.mark.parametrize("v_true", [0.0, 0.02, 0.05, 0.1, 0.2])
def test_the_coulomb_smoothing_velocity_of_the_data_is_chosen(v_true):
    # noise-free torques: the model with the true smoothing velocity predicts the raw torque up
    # to the filter's distortion of the states; every other one misses the friction's shape at
    # each reversal, so the grid point of the truth scores best
    choice = choose_cutoff(_Dry(), _dry_log(v_true), grid_hz=(4.0, 16.0), velocity="differentiate")
    assert choice.coulomb_grid == COULOMB_GRID and v_true in COULOMB_GRID
    assert choice.coulomb_velocity == v_true
    best = COULOMB_GRID.index(v_true)
    assert all(
        s > choice.coulomb_scores[best] for i, s in enumerate(choice.coulomb_scores) if i != best
    )
    assert f"v_c = {v_true:g} rad/s" in choice.how


def test_the_coulomb_velocity_is_kept_where_there_is_none_to_choose():
    log = _dry_log(0.05)
    kept = choose_cutoff(_Dry(0.1), log, grid_hz=(16.0,), velocity="differentiate", coulomb_grid=())
    assert kept.coulomb_velocity is None and kept.coulomb_grid == () and "v_c" not in kept.how
    plain = choose_cutoff(_Linear(), _log(), grid_hz=(16.0,), velocity="differentiate")
    assert plain.coulomb_velocity is None
    with pytest.raises(ValueError, match="coulomb_velocity"):
        choose_cutoff(_Dry(), log, grid_hz=(16.0,), coulomb_grid=(0.05, -1.0))


def test_a_tie_among_every_cutoff_is_said_so_and_the_rule_breaks_it():
    """Where every cut-off scores within one standard error of the best, the text says the log
    cannot tell them apart (no story of a winner); otherwise it names the best."""
    from torchjfa.data._cutoff import _verdict

    grid = (2.0, 5.0, 10.0)
    tied = _verdict(grid, torch.tensor([0.393, 0.3931, 0.3932]), torch.full((3,), 1e-3), 0, 2)
    assert "cannot tell" in tied and "the largest, 10 Hz" in tied
    clear = _verdict(grid, torch.tensor([0.3, 0.5, 0.9]), torch.tensor([0.0, 0.01, 0.01]), 0, 0)
    assert "cannot tell" not in clear and clear == "best 2 Hz"


def test_a_tie_among_the_prior_weights_is_said_so():
    from types import SimpleNamespace

    from torchjfa.report._markdown import _prior_note

    tied = SimpleNamespace(prior_weight=1e5, prior_choice={0.0: 0.1283, 100.0: 0.1283, 1e5: 0.1283})
    text = " ".join(_prior_note(tied))
    assert "cannot tell the weights apart" in text and "prefer the description" not in text
    clear = SimpleNamespace(prior_weight=1e5, prior_choice={0.0: 0.2, 100.0: 0.15, 1e5: 0.1})
    assert "cannot tell" not in " ".join(_prior_note(clear))
