"""The filter's reach, declared once: what `prepare` drops at each end of a log."""

import math

import pytest
import torch

from torchjfa.data import EDGE_PERIODS, JointLog, edge_seconds, prepare


def test_the_reach_is_a_number_of_periods_of_the_cutoff():
    assert edge_seconds(20.0) == pytest.approx(EDGE_PERIODS / 20.0, rel=1e-15)
    assert edge_seconds(5.0) == 4 * edge_seconds(20.0)


@pytest.mark.parametrize("cutoff", [5.0, 12.5])
def test_prepare_drops_the_reach_at_each_end(cutoff):
    rate, n = 200.0, 3000
    t = torch.arange(n, dtype=torch.float64) / rate
    q = torch.stack([torch.sin(1.3 * t), torch.cos(0.7 * t)], 1)
    log = JointLog(t=t, q=q, tau=q.clone(), joint_names=("a", "b"))
    out = prepare(log, cutoff_hz=cutoff, period_s=None, skip_start_s=0.0)
    edge = math.ceil(edge_seconds(cutoff) * log.rate_hz)  # the log's rate, as prepare has it
    assert out.n_samples == n - 2 * edge
    assert float(out.t[0]) == pytest.approx(edge / rate, abs=1e-9)
    assert out.info["dropped_end_s"] == pytest.approx(edge / rate, abs=1e-9)
