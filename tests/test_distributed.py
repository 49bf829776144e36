"""Multi-process moments: shares of the samples, one all-reduce, the single-process answer.

The two-process test starts real processes (``torch.multiprocessing`` spawn, gloo over a free
loopback port, the environment ``torchrun`` would set) and compares what they compute with one
process. Each run has a deadline; processes still alive at it are killed, so a hang fails the
test instead of blocking the suite.
"""

import os
import socket
import time

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp
from _flow import fit_logs

from torchjfa.distributed import (
    all_reduce_moments,
    process_group,
    rank_and_world_size,
    shard,
    shard_range,
)
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import OLS, BayesianJFA
from torchjfa.identification import stream_moments
from torchjfa.sim import generate_log, model_path
from torchjfa.stats import Moments

FIELDS = ("n", "sum_x", "sum_y", "xtx", "xty", "yty")
LENGTHS = (300, 240)  # the two ranks' shares (270 samples each) cross the file boundary
BJFA = {"fit_intercept": False, "method": "em", "max_iter": 100}
DEADLINE_S = 240.0


def rel(a, b) -> float:
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-300))


# ---------------------------------------------------------------------------------- units
@pytest.mark.parametrize("n", [0, 1, 5, 7, 100])
@pytest.mark.parametrize("world", [1, 2, 3, 8])
def test_shard_range_tiles_and_balances(n, world):
    ranges = [shard_range(n, r, world) for r in range(world)]
    assert ranges[0][0] == 0 and ranges[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(ranges[:-1], ranges[1:], strict=True))
    sizes = [b - a for a, b in ranges]
    assert max(sizes) - min(sizes) <= 1
    items = [f"file{i}" for i in range(n)]
    assert sum((shard(items, r, world) for r in range(world)), []) == items


def test_shard_bad_input():
    with pytest.raises(ValueError, match="rank"):
        shard_range(10, 2, 2)
    with pytest.raises(ValueError, match="world_size"):
        shard_range(10, 0, 0)
    with pytest.raises(TypeError, match="rank"):
        shard_range(10, 0.0, 2)
    with pytest.raises(ValueError, match="n must"):
        shard_range(-1, 0, 2)
    with pytest.raises(TypeError, match="sequence"):
        shard({1, 2}, 0, 1)


def test_single_process_defaults():
    assert rank_and_world_size() == (0, 1)
    g = torch.Generator().manual_seed(0)
    X = torch.randn(20, 3, generator=g, dtype=torch.float64)
    y = torch.randn(20, generator=g, dtype=torch.float64)
    m = Moments.from_data(X, y)
    out = all_reduce_moments([m, m])
    assert len(out) == 2 and out[0] is not m
    for k in FIELDS:
        assert torch.equal(getattr(out[1], k), getattr(m, k))
    with process_group():  # no torchrun environment: a plain single process, nothing to set up
        assert rank_and_world_size() == (0, 1)
    with pytest.raises(ValueError, match="features"):
        all_reduce_moments([m, Moments.zeros(2)])
    with pytest.raises(TypeError, match="Moments"):
        all_reduce_moments([m, 1])
    with pytest.raises(ValueError, match="rank= and world_size="):
        with process_group(init_method="tcp://127.0.0.1:1"):
            pass


# ---------------------------------------------------------------------------------- 2 processes
def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(rank: int, world_size: int, port: int, paths: list[str], out_dir: str) -> None:
    """One process, started as torchrun would start it: the rendezvous comes from the env."""
    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world_size)
    )
    torch.set_num_threads(1)
    model = RigidBodyModel.from_mjcf(model_path("head"))
    original, seen = model.regressor, []

    def counting(q, qd, qdd, **kw):
        seen.append(q.shape[0])
        return original(q, qd, qdd, **kw)

    model.regressor = counting
    with process_group("gloo", timeout_s=120):
        assert rank_and_world_size() == (rank, world_size)
        moments = stream_moments(model, paths, chunk_size=200, distributed=True)
        n_read = sum(seen)
        folds = stream_moments(model, paths, n_folds=3, distributed=True)
        ols = fit_logs(
            model, paths, estimator=OLS(fit_intercept=False), project=False, distributed=True
        )
        bjfa = fit_logs(
            model, paths, estimator=BayesianJFA(**BJFA), project=False, distributed=True
        )
    torch.save(
        {
            "moments": [getattr(moments, k) for k in FIELDS] + [moments.n_rows],
            "folds": [[getattr(f, k) for k in FIELDS] for f in folds],
            "ols": ols.theta,
            "bjfa": bjfa.theta,
            "world_size": bjfa.world_size,
            "n_read": n_read,
        },
        os.path.join(out_dir, f"rank{rank}.pt"),
    )


def _run_processes(fn, nprocs: int, args: tuple) -> None:
    ctx = mp.start_processes(fn, args=args, nprocs=nprocs, join=False, start_method="spawn")
    deadline = time.monotonic() + DEADLINE_S
    try:
        while not ctx.join(timeout=max(1.0, deadline - time.monotonic())):
            if time.monotonic() > deadline:
                pytest.fail(f"the {nprocs} processes did not finish within {DEADLINE_S} s")
    finally:
        for p in ctx.processes:
            if p.is_alive():
                p.kill()
                p.join(5)


def _moments_worker(rank: int, world_size: int, port: int, out_dir: str) -> None:
    """Each rank's own rows, reduced in place (`Moments.all_reduce`) and as a pair in one
    message (`all_reduce_moments`)."""
    torch.set_num_threads(1)
    X, y = _rows(rank)
    with process_group(
        "gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=world_size
    ):
        mine = Moments.from_data(X, y)
        pair = all_reduce_moments([mine, Moments.from_data(2 * X, y)])
        assert mine.all_reduce() is mine
    torch.save(
        {"single": mine.to_flat(), "pair": [m.to_flat() for m in pair]},
        os.path.join(out_dir, f"moments{rank}.pt"),
    )


def _rows(rank: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(10 + rank)
    n = 30 + 7 * rank  # shares of different lengths
    X = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return X, torch.randn(n, generator=g, dtype=torch.float64)


def test_two_processes_all_reduce_moments_in_place_and_in_one_message(tmp_path):
    _run_processes(_moments_worker, 2, (2, _free_port(), str(tmp_path)))
    X, y = (torch.cat(v) for v in zip(_rows(0), _rows(1), strict=True))
    whole, doubled = Moments.from_data(X, y), Moments.from_data(2 * X, y)
    for r in range(2):
        res = torch.load(tmp_path / f"moments{r}.pt", weights_only=True)
        for got, ref in ((res["single"], whole), *zip(res["pair"], (whole, doubled), strict=True)):
            m = Moments.from_flat(got, 4)
            assert m.n_rows == ref.n_rows == 67
            for k in FIELDS:
                assert rel(getattr(m, k), getattr(ref, k)) <= 1e-12, k


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("dist_logs")
    log = generate_log("head", n_samples=sum(LENGTHS), seed=5)
    paths, start = [], 0
    for i, n in enumerate(LENGTHS):
        path = d / f"part{i}.npz"
        arrays = {k: getattr(log, k)[start : start + n].numpy() for k in ("q", "qd", "qdd", "tau")}
        np.savez(path, joint_names=np.array(log.joint_names), **arrays)
        paths.append(str(path))
        start += n
    return paths, log


def test_two_processes_equal_one(logs, tmp_path):
    paths, log = logs
    _run_processes(_worker, 2, (2, _free_port(), paths, str(tmp_path)))
    out = [torch.load(tmp_path / f"rank{r}.pt", weights_only=True) for r in range(2)]
    # the single-process references: the whole regressor in memory
    model = RigidBodyModel.from_mjcf(model_path("head"))
    Y = model.regressor(log.q, log.qd, log.qdd)
    p = model.n_params
    whole = Moments.from_data(Y.reshape(-1, p), log.tau.reshape(-1))
    total = sum(LENGTHS)
    bounds = [round(k * total / 3) for k in range(4)]
    folds = [
        Moments.from_data(Y[a:b].reshape(-1, p), log.tau[a:b].reshape(-1))
        for a, b in zip(bounds[:-1], bounds[1:], strict=True)
    ]
    theta_ols = OLS(fit_intercept=False).fit_moments(whole).coef_
    theta_bjfa = BayesianJFA(**BJFA).fit_moments(whole).coef_
    for r, res in enumerate(out):
        assert res["n_read"] == total // 2, f"rank {r} read {res['n_read']} samples"
        assert res["world_size"] == 2
        assert res["moments"][-1] == whole.n_rows
        for k, v in zip(FIELDS, res["moments"][:-1], strict=True):
            assert rel(v, getattr(whole, k)) <= 1e-12, k
        for got, ref in zip(res["folds"], folds, strict=True):
            for k, v in zip(FIELDS, got, strict=True):
                assert rel(v, getattr(ref, k)) <= 1e-12, k
        assert rel(res["ols"], theta_ols) <= 1e-10
        assert rel(res["bjfa"], theta_bjfa) <= 1e-10
    # every process holds the same statistics after the all-reduce, so the same estimate
    assert torch.equal(out[0]["bjfa"], out[1]["bjfa"])
