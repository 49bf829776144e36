import pytest
import torch
from experiments.synthetic import make_problem


def test_shapes_and_reproducibility():
    p = make_problem(30, 60, seed=3, n_train=50, n_test=20)
    assert p.X_train.shape == (50, 100) and p.X_test_clean.shape == (20, 100)
    assert p.relevant.tolist() == list(range(10))
    assert len(p.redundant) == 30 and len(p.irrelevant) == 60
    q = make_problem(30, 60, seed=3, n_train=50, n_test=20)
    assert torch.equal(p.X_train, q.X_train) and torch.equal(p.y_test_noisy, q.y_test_noisy)
    assert not torch.equal(p.X_train, make_problem(30, 60, seed=4, n_train=50, n_test=20).X_train)


def test_clean_test_set_is_exact_and_redundant_inputs_are_convex_combinations():
    p = make_problem(5, 3, seed=0, n_train=200, n_test=200)
    # the true vector maps noiseless inputs to the noiseless output exactly
    torch.testing.assert_close(p.X_test_clean @ p.coef_true, p.y_test_clean)
    for X in (p.X_train, p.X_test_clean, p.X_test_noisy):
        rel, red = X[:, p.relevant], X[:, p.redundant]
        w = torch.linalg.lstsq(rel, red).solution  # (10, r)
        torch.testing.assert_close(rel @ w, red, atol=1e-10, rtol=0)
        assert bool((w > -1e-8).all())
        torch.testing.assert_close(w.sum(0), torch.ones(5, dtype=torch.float64))


@pytest.mark.parametrize("snr", [2.0, 5.0])
def test_signal_to_noise_ratios(snr):
    p = make_problem(4, 2, input_snr=snr, seed=1, n_train=40000, n_test=40000)
    ratio_in = p.X_train[:, p.relevant].var(0) / p.X_test_clean[:, p.relevant].var(0)
    torch.testing.assert_close(
        ratio_in, torch.full((10,), 1 + 1 / snr, dtype=torch.float64), rtol=0.05, atol=0
    )
    ratio_out = p.y_test_noisy.var() / p.y_test_clean.var()
    assert abs(float(ratio_out) - 1.2) < 0.05
    # the stated per-column noise is the excess variance over the noiseless inputs
    excess = p.X_train.var(0) - p.X_test_clean.var(0)
    torch.testing.assert_close(excess[:14], p.input_noise[:14], rtol=0.1, atol=0.02)
    assert bool((p.input_noise[p.irrelevant] == 0).all())
    # repeated measurements estimate the same noise from the data alone
    from_repeats = (p.X_train - p.X_train_repeat).var(0) / 2
    torch.testing.assert_close(from_repeats, p.input_noise, rtol=0.05, atol=1e-12)


def test_bad_arguments():
    with pytest.raises(ValueError, match="non-negative"):
        make_problem(-1, 3)
    with pytest.raises(ValueError, match="SNR"):
        make_problem(1, 1, input_snr=0)
