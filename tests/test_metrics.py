"""`torchjfa.metrics`: nMSE against scikit-learn's R^2 and a written-out formula, RMS against
NumPy, the population variance, dtypes, and bad input; the report's copy gives the same
numbers (until it calls this one)."""

import math

import numpy as np
import pytest
import torch

from torchjfa import learning
from torchjfa.metrics import nmse, rms
from torchjfa.report import torque_errors


def _pair(n=50, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    scale = torch.tensor([1.0, 10.0, 0.1, 100.0], dtype=dtype)  # joints of very different size
    y = torch.randn(n, 4, generator=g, dtype=dtype) * scale + 3.0
    p = y + 0.3 * scale * torch.randn(n, 4, generator=g, dtype=dtype)
    return p, y


@pytest.mark.parametrize("dtype, rtol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_nmse_is_one_minus_sklearn_r2_per_joint(dtype, rtol):
    metrics = pytest.importorskip("sklearn.metrics")
    p, y = _pair(dtype=dtype)
    r2 = metrics.r2_score(y.double().numpy(), p.double().numpy(), multioutput="raw_values")
    per = nmse(p, y, per_joint=True)
    assert per.dtype == dtype and per.shape == (4,)
    np.testing.assert_allclose(per.double().numpy(), 1 - r2, rtol=rtol)
    np.testing.assert_allclose(float(nmse(p, y)), (1 - r2).mean(), rtol=rtol)
    # one column (a 1-D target) is that column's value
    np.testing.assert_allclose(float(nmse(p[:, 1], y[:, 1])), 1 - r2[1], rtol=rtol)


def test_nmse_uses_the_population_variance_of_each_joint():
    # joint 0: target 0, 2 (mean 1, population variance 1, sample variance 2), error 1 each;
    # joint 1: target 0, 20 (variance 100), errors 1 and 3 (mean squared error 5)
    y = torch.tensor([[0.0, 0.0], [2.0, 20.0]], dtype=torch.float64)
    p = torch.tensor([[1.0, 1.0], [1.0, 17.0]], dtype=torch.float64)
    assert nmse(p, y, per_joint=True).tolist() == [1.0, 0.05]
    assert float(nmse(p, y)) == pytest.approx(0.525, rel=1e-15)
    # pooled over joints (the demo's old measure) it would be 3 / var([0, 0, 2, 20]) = 0.0469
    assert rms(p, y, per_joint=True).tolist() == [1.0, 5.0**0.5]
    assert float(rms(p, y)) == pytest.approx(3.0**0.5, rel=1e-15)


def test_rms_against_numpy_and_a_constant_target():
    p, y = _pair(n=30, seed=1)
    err = (p - y).numpy()
    np.testing.assert_allclose(rms(p, y, per_joint=True).numpy(), np.sqrt((err**2).mean(0)))
    np.testing.assert_allclose(float(rms(p, y)), np.sqrt((err**2).mean()), rtol=1e-14)
    const = torch.ones_like(y)
    np.testing.assert_allclose(float(rms(p, const)), np.sqrt(((p - 1).numpy() ** 2).mean()))


def test_same_numbers_as_the_reports_copy_and_learnings_name():
    assert learning.nmse is nmse
    p, y = _pair(n=200, seed=2)
    n_ref, r_ref = torque_errors(y, p)
    assert torch.equal(nmse(p, y, per_joint=True), n_ref)
    assert torch.equal(rms(p, y, per_joint=True), r_ref)


def test_prediction_takes_the_targets_dtype():
    p, y = _pair()
    got = nmse(p.float(), y)
    assert got.dtype == torch.float64
    assert float(got) == pytest.approx(float(nmse(p.float().double(), y)), rel=1e-15)


@pytest.mark.parametrize(
    "p, y, error, match",
    [
        (torch.zeros(5, 2), torch.zeros(5, 3), ValueError, "same shape"),
        (torch.zeros(1, 2), torch.zeros(1, 2), ValueError, "n >= 2"),
        (torch.zeros(5, 2, 2), torch.zeros(5, 2, 2), ValueError, r"\(n, n_dof\)"),
        (np.zeros((5, 2)), torch.zeros(5, 2), TypeError, "prediction must be a torch.Tensor"),
        (torch.zeros(5, 2), torch.zeros(5, 2, dtype=torch.int64), TypeError, "floating"),
        (torch.randn(5, 2), torch.ones(5, 2), ValueError, "constant"),
    ],
)
def test_bad_input(p, y, error, match):
    with pytest.raises(error, match=match):
        nmse(p, y)
    if match != "constant":
        with pytest.raises(error, match=match):
            rms(p, y)


def test_a_constant_target_column_has_an_infinite_normalised_error():
    # a joint whose logged torque never changes (no sensor, a locked joint): any error is
    # infinitely large against its variance, and a report must still be written
    y = torch.stack([torch.linspace(0.0, 1.0, 5), torch.ones(5)], 1)
    per = nmse(y + 0.1, y, per_joint=True, allow_constant=True)
    assert math.isfinite(float(per[0])) and float(per[1]) == math.inf
    assert torch.isnan(nmse(y, y, per_joint=True, allow_constant=True)[1])
