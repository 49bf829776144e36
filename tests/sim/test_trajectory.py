"""`random_trajectory`: the harmonic band, the draws, the bounds."""

from __future__ import annotations

import numpy as np
import pytest

from torchjfa.sim import load_robot, random_trajectory
from torchjfa.sim._robots import joint_ranges


def test_default_draws_are_the_documented_ones():
    # written out from the docstring: n_terms distinct harmonics in 1..max, U(0.5, 1) / n weights
    model = load_robot("head")
    tr = random_trajectory(model, n_terms=3, max_harmonic=8, seed=5)
    rng = np.random.default_rng(5)
    n = model.njnt
    harmonic = np.stack([rng.choice(8, 3, replace=False) + 1 for _ in range(n)])
    np.testing.assert_array_equal(tr.harmonic, harmonic)


def test_min_harmonic_sets_the_band_and_evens_the_speeds():
    model = load_robot("head")
    wide = [
        random_trajectory(model, base_frequency=0.02, n_terms=5, max_harmonic=100, seed=s)
        for s in range(5)
    ]
    band = [
        random_trajectory(
            model, base_frequency=0.02, n_terms=5, max_harmonic=100, min_harmonic=10, seed=s
        )
        for s in range(5)
    ]
    for tr in band:
        assert tr.harmonic.min() >= 10 and tr.harmonic.max() <= 100
        assert all(len(set(row)) == 5 for row in tr.harmonic)  # distinct per joint

    # peak speed over position reach, sum |a| w / sum |a|, is 2 pi f0 times the |a|-weighted
    # mean harmonic: at least 2 pi f0 min_harmonic; the wide band lets a joint fall below it
    def speed(tr):
        w = 2 * np.pi * tr.base_frequency * tr.harmonic
        return (np.abs(tr.amplitude) * w).sum(1) / np.abs(tr.amplitude).sum(1)

    floor = 2 * np.pi * 0.02 * 10
    assert min(speed(tr).min() for tr in band) >= floor * (1 - 1e-12)
    assert min(speed(tr).min() for tr in wide) < floor
    for tr in band:
        lo, hi = tr.bounds()
        ranges = joint_ranges(model)
        assert np.all(lo >= ranges[:, 0]) and np.all(hi <= ranges[:, 1])


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"min_harmonic": 0}, "min_harmonic must be a positive int"),
        ({"min_harmonic": 7, "max_harmonic": 8}, "at least n_terms"),
        ({"min_harmonic": 2.0}, "min_harmonic must be a positive int"),
    ],
)
def test_bad_band(kw, match):
    with pytest.raises(ValueError, match=match):
        random_trajectory(load_robot("head"), n_terms=3, **kw)
