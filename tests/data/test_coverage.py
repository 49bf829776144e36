"""`coverage`: where another log's motion goes beyond the identification log's."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchjfa.data import coverage


def _log(n=2000, seed=0, scale=(1.0, 1.0, 1.0)):
    t = np.linspace(0.0, 10.0, n)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, 3)
    q = np.stack([np.sin(t + p) for p in phase], axis=1)
    qd = np.stack([np.cos(t + p) for p in phase], axis=1)
    qdd = -q.copy()
    s = np.asarray(scale)
    return q, qd * s, qdd * s


def test_the_same_log_covers_itself():
    ref = _log()
    c = coverage(ref, ref, joint_names=["a", "b", "c"])
    for s in ("q", "qd", "qdd"):
        np.testing.assert_allclose(c.ratio[s], 1.0, rtol=1e-12)
    assert c.warnings() == []


def test_faster_motion_is_the_ratio_of_the_peaks():
    ref = _log()
    q, qd, qdd = ref
    other = (q, qd * np.array([1.0, 4.0, 1.0]), qdd * np.array([1.0, 1.0, 2.5]))
    c = coverage(ref, other, joint_names=["a", "b", "c"])
    # percentiles scale exactly with the signal: the ratios are the factors (round-off only)
    np.testing.assert_allclose(c.ratio["qd"], [1.0, 4.0, 1.0], rtol=1e-12)
    np.testing.assert_allclose(c.ratio["qdd"], [1.0, 1.0, 2.5], rtol=1e-12)
    lines = c.warnings(limit=1.5)
    assert len(lines) == 2
    assert lines[0].startswith("b: qd up to") and "(4.0x)" in lines[0]
    assert lines[1].startswith("c: qdd up to") and "(2.5x)" in lines[1]
    assert c.worst() == ("b", "qd", pytest.approx(4.0, rel=1e-12))
    assert coverage(ref, other).warnings(limit=5.0) == []


def test_positions_outside_the_range_as_a_fraction_of_its_width():
    ref = _log()
    q, qd, qdd = ref
    width = np.percentile(q, 99, axis=0) - np.percentile(q, 1, axis=0)
    shifted = q + np.array([0.0, 0.5, -0.25]) * width  # percentiles shift with the signal
    c = coverage(ref, (shifted, qd, qdd))
    np.testing.assert_allclose(c.ratio["q"], [1.0, 1.5, 1.25], rtol=1e-9)
    assert c.warnings(limit=1.3) == [
        "joint 2: positions 50% of its range outside it",
    ]


def test_a_joint_that_never_moved_and_tensors():
    q, qd, qdd = _log()
    qd_still = qd.copy()
    qd_still[:, 0] = 0.0
    c = coverage(
        tuple(torch.as_tensor(v) for v in (q, qd_still, qdd)), (q, qd, qdd), joint_names="xyz"
    )
    assert math.isinf(c.ratio["qd"][0]) and c.warnings()[0].startswith("x: qd up to")


@pytest.mark.parametrize(
    "other, match",
    [
        ((np.zeros((5, 2)),) * 3, "reference has 3 joints, other 2"),
        ((np.zeros((1, 3)),) * 3, "n_samples >= 2"),
        ((np.full((5, 3), np.nan),) * 3, "NaN"),
        ((np.zeros((5, 3)),) * 2, r"must be \(q, qd, qdd\)"),
    ],
)
def test_bad_input(other, match):
    with pytest.raises(ValueError, match=match):
        coverage(_log(), other)
