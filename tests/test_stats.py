import pytest
import torch

from torchjfa import Moments, kfold_moments


def _data(n=200, d=5, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    X = torch.randn(n, d, generator=g, dtype=dtype) + 0.3
    y = X @ torch.arange(1.0, d + 1, dtype=dtype) + torch.randn(n, generator=g, dtype=dtype)
    return X, y


def test_from_data_matches_definitions():
    X, y = _data()
    m = Moments.from_data(X, y)
    assert m.n == 200 and m.n_rows == 200
    torch.testing.assert_close(m.xtx, X.T @ X)
    torch.testing.assert_close(m.xty, X.T @ y)
    torch.testing.assert_close(m.yty, y @ y)
    torch.testing.assert_close(m.sum_x, X.sum(0))
    torch.testing.assert_close(m.sum_y, y.sum())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_chunks_and_addition_equal_one_pass(dtype):
    X, y = _data(dtype=dtype)
    whole = Moments.from_data(X, y)
    assert whole.xtx.dtype == torch.float64
    streamed = Moments.zeros(5)
    for a in range(0, 200, 37):
        streamed.update(X[a : a + 37], y[a : a + 37])
    added = Moments.from_data(X[:50], y[:50]) + Moments.from_data(X[50:], y[50:])
    summed = sum(kfold_moments(X, y, 4))
    for m in (streamed, added, summed):
        for key in ("n", "sum_x", "sum_y", "xtx", "xty", "yty"):
            torch.testing.assert_close(getattr(m, key), getattr(whole, key), rtol=1e-12, atol=1e-9)
        assert m.n_rows == 200


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rows_over_several_blocks_weighted(dtype):
    # update() works through a chunk in blocks of rows; 5,000 rows span three, the last partial
    X, y = _data(n=5000, d=4, seed=3, dtype=dtype)
    w = torch.rand(5000, generator=torch.Generator().manual_seed(4), dtype=dtype)
    m = Moments.from_data(X, y, weights=w)
    X, y, w = X.double(), y.double(), w.double()
    torch.testing.assert_close(m.xtx, (X * w[:, None]).T @ X, rtol=1e-12, atol=0)
    torch.testing.assert_close(m.xty, X.T @ (w * y), rtol=1e-12, atol=0)
    torch.testing.assert_close(m.sum_x, w @ X, rtol=1e-12, atol=0)
    torch.testing.assert_close(m.yty, w @ (y * y), rtol=1e-12, atol=0)
    torch.testing.assert_close(m.n, w.sum(), rtol=1e-12, atol=0)
    assert m.n_rows == 5000


def test_weights_equal_repeated_rows():
    X, y = _data(n=30)
    w = torch.randint(0, 4, (30,)).to(torch.float64)
    rep = w.to(torch.long)
    weighted = Moments.from_data(X, y, weights=w)
    repeated = Moments.from_data(X.repeat_interleave(rep, 0), y.repeat_interleave(rep, 0))
    for key in ("n", "sum_x", "sum_y", "xtx", "xty", "yty"):
        torch.testing.assert_close(getattr(weighted, key), getattr(repeated, key))


def test_rss_and_centering_from_moments():
    X, y = _data()
    m = Moments.from_data(X, y)
    b, c = torch.randn(5, dtype=torch.float64), 0.7
    torch.testing.assert_close(m.rss(b, c), ((y - X @ b - c) ** 2).sum())
    sxx, sxy, syy = m.second_moments(center=True)
    Xc, yc = X - X.mean(0), y - y.mean()
    torch.testing.assert_close(sxx, Xc.T @ Xc)
    torch.testing.assert_close(sxy, Xc.T @ yc)
    torch.testing.assert_close(syy, yc @ yc)


def test_subtract_and_select():
    X, y = _data()
    a, b = Moments.from_data(X[:80], y[:80]), Moments.from_data(X[80:], y[80:])
    torch.testing.assert_close(((a + b) - a).xtx, b.xtx)
    sel = Moments.from_data(X, y).select([0, 3])
    torch.testing.assert_close(sel.xtx, X[:, [0, 3]].T @ X[:, [0, 3]])


def test_all_reduce_without_process_group_is_identity():
    X, y = _data()
    m = Moments.from_data(X, y)
    before = m.xtx.clone()
    assert m.all_reduce() is m
    torch.testing.assert_close(m.xtx, before)


def test_flat_round_trip_layout_and_linearity():
    X, y = _data()
    w = torch.rand(X.shape[0], generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    a, b = Moments.from_data(X[:70], y[:70], w[:70]), Moments.from_data(X[70:], y[70:])
    d = a.n_features
    flat = a.to_flat()
    assert flat.dtype == torch.float64 and flat.shape == (Moments.flat_size(d),)
    assert Moments.flat_size(d) == d * d + 2 * d + 4
    # the documented layout, written out
    ref = torch.cat(
        [a.n[None], a.sum_x, a.sum_y[None], a.xtx.flatten(), a.xty, a.yty[None]]
        + [torch.tensor([70.0], dtype=torch.float64)]
    )
    assert torch.equal(flat, ref)
    back = Moments.from_flat(flat, d)
    assert back.n_rows == a.n_rows == 70
    for k in ("n", "sum_x", "sum_y", "xtx", "xty", "yty"):
        assert torch.equal(getattr(back, k), getattr(a, k)), k
    flat.zero_()  # no storage shared with the vector
    assert torch.equal(back.xtx, a.xtx)
    # a sum of flat vectors is the flat vector of the sum (what an all-reduce relies on)
    summed = Moments.from_flat(a.to_flat() + b.to_flat(), d)
    both = a + b
    assert summed.n_rows == both.n_rows
    for k in ("n", "sum_x", "sum_y", "xtx", "xty", "yty"):
        torch.testing.assert_close(getattr(summed, k), getattr(both, k), rtol=1e-15, atol=0)


def test_from_flat_bad_input():
    flat = Moments.zeros(3).to_flat()
    with pytest.raises(ValueError, match="1-D tensor of 19 values"):
        Moments.from_flat(flat[:-1], 3)
    with pytest.raises(ValueError, match="of 4 features"):
        Moments.from_flat(flat, 4)
    with pytest.raises(ValueError, match="1-D"):
        Moments.from_flat(flat[None], 3)
    with pytest.raises(ValueError, match="list"):
        Moments.from_flat(flat.tolist(), 3)


@pytest.mark.parametrize(
    "X, y, match",
    [
        (torch.full((3, 2), float("nan")), torch.zeros(3), "NaN"),
        (torch.zeros(3, 2), torch.tensor([0.0, float("inf"), 0.0]), "infinite"),
        (torch.zeros(3, 2), torch.zeros(4), "different numbers of samples"),
        (torch.zeros(3), torch.zeros(3), "2-D"),
        (torch.zeros(0, 2), torch.zeros(0), "no rows"),
        (torch.zeros(3, 2), torch.zeros(3, 2), "1-D"),
    ],
)
def test_bad_input(X, y, match):
    with pytest.raises(ValueError, match=match):
        Moments.from_data(X, y)


def test_negative_weights_and_feature_mismatch():
    X, y = _data(n=10)
    with pytest.raises(ValueError, match="non-negative"):
        Moments.from_data(X, y, weights=-torch.ones(10))
    with pytest.raises(ValueError, match="features"):
        Moments.zeros(3).update(X, y)
