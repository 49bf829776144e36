"""`check_log`: logs that cannot identify anything are named before any fitting."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from torchjfa.data import JointLog, check_log

PANDA = Path(__file__).resolve().parents[3] / "shared" / "data" / "panda_gaz2019"
LIMITS = np.array([[-2.0, 2.0], [-1.5, 1.5], [-1.0, 1.0]])


def _log(n=3000, rate=500.0, q=None, t=None, source="log"):
    t = np.arange(n) / rate if t is None else t
    if q is None:
        q = np.stack([0.8 * np.sin(2 * np.pi * f * t) for f in (0.3, 0.7, 1.1)], axis=1)
    return JointLog(t=t, q=q, tau=np.zeros_like(q), joint_names=("a", "b", "c"), source=source)


def test_a_smooth_moving_log_inside_its_limits_passes():
    assert check_log(_log(), limits=LIMITS) == []


def test_a_gap_is_refused_not_bridged():
    t = np.arange(3000) / 500.0
    t[1500:] += 2.0
    (p,) = check_log(_log(t=t))
    assert p.fatal and "time jumps by 2 s" in p.message and "row 1500" in p.message
    # jitter of several median steps (the real Panda log has up to 8.8x) is not a gap
    jitter = np.cumsum(np.where(np.arange(3000) % 100 == 0, 9.0, 1.0)) / 500.0
    assert check_log(_log(t=jitter)) == []


def test_a_robot_standing_still_and_a_joint_that_does_not_move():
    log = _log()
    still = _log(
        q=np.tile(log.q[:1].numpy(), (3000, 1))
        + 1e-5 * np.random.default_rng(0).standard_normal((3000, 3))
    )
    (p,) = check_log(still)
    assert p.fatal and "does not move" in p.message
    q = log.q.numpy().copy()
    q[:, 1] = 0.3
    (p,) = check_log(_log(q=q))
    assert not p.fatal and "['b'] barely move" in p.message


def test_scrambled_columns_and_degrees():
    q = _log().q.numpy()
    scrambled = q.reshape(-1).reshape(3, -1).T.copy()  # a sample-major stream read joint-major
    problems = check_log(_log(q=scrambled), limits=LIMITS)
    assert problems[0].fatal and "not a smooth motion" in problems[0].message
    (p,) = check_log(_log(q=np.rad2deg(q)), limits=LIMITS)
    assert p.fatal and "look like degrees" in p.message
    shifted = q + np.array([0.0, 0.0, 0.9])  # radians, but outside joint c's limits
    (p,) = check_log(_log(q=shifted), limits=LIMITS)
    assert not p.fatal and "['c'] leave the description's limits" in p.message
    unknown = LIMITS.copy()
    unknown[2] = [np.inf, -np.inf]  # no limits known for c: nothing to check
    assert check_log(_log(q=shifted), limits=unknown) == []
    with pytest.raises(ValueError, match=r"\(n_dof, 2\)"):
        check_log(_log(), limits=LIMITS[:2])


@pytest.mark.skipif(not PANDA.is_dir(), reason="the real Panda log is not beside the project")
def test_the_real_panda_log_passes_and_its_mistakes_do_not():
    import torchjfa
    from torchjfa import RigidBodyModel

    t = np.loadtxt(PANDA / "time.txt")
    stream = np.loadtxt(PANDA / "positions.txt")
    tau = np.loadtxt(PANDA / "torques.txt").reshape(-1, 7)
    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    limits = np.array(model.chain.get_joint_limits()).T
    names = model.joint_names

    def log(q):
        return JointLog(t=t, q=q, tau=tau, joint_names=names, source="panda")

    assert check_log(log(stream.reshape(-1, 7)), limits=limits) == []
    assert check_log(log(stream.reshape(7, -1).T.copy()), limits=limits)[0].fatal
    (p,) = check_log(log(np.rad2deg(stream.reshape(-1, 7))), limits=limits)
    assert p.fatal and "degrees" in p.message
