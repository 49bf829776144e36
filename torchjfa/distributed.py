"""Several processes (or machines) building one set of `Moments`, over ``torch.distributed``.

Identification needs only the sufficient statistics of the regression (`torchjfa.Moments`), and
the statistics of disjoint parts of the data add up. So each process reduces its share of the
logs (`shard`, `shard_range`) to `Moments`, and one ``all_reduce`` (`all_reduce_moments`, or
`Moments.all_reduce` for a single one) gives every process the statistics of all the data; the
estimators and the projection then run on them in each process, at a cost independent of the
data size. Nothing here is home-made communication: the processes are started by ``torchrun``,
by Lightning (``Fabric(strategy="ddp")`` or a DDP ``Trainer``) or by
``torch.multiprocessing.spawn``, and talk through ``torch.distributed`` (``"gloo"`` on CPU).

`torchjfa.identification.fit` with ``Compute(distributed=True)`` does all of this; use this
module directly to share out other work, or to set up a process group from ``torchrun``'s
environment (`process_group`).

Example (``torchrun --nproc_per_node 4 identify_logs.py``)::

    from torchjfa.distributed import process_group
    from torchjfa.identification import Compute, Options, fit

    with process_group("gloo"):
        options = Options(compute=Compute(distributed=True))
        result = fit(model, log_paths, options=options)
"""

from __future__ import annotations

import contextlib
import datetime
import os
from collections.abc import Iterator, Sequence

import torch

from .stats import Moments

__all__ = [
    "all_reduce_moments",
    "process_group",
    "rank_and_world_size",
    "shard",
    "shard_range",
]


def _check_rank(rank, world_size) -> tuple[int, int]:
    for name, v in (("rank", rank), ("world_size", world_size)):
        if isinstance(v, bool) or not isinstance(v, int):
            raise TypeError(f"{name} must be an int, got {type(v).__name__}")
    if world_size < 1:
        raise ValueError(f"world_size must be at least 1, got {world_size}")
    if not 0 <= rank < world_size:
        raise ValueError(f"rank must be in [0, {world_size}), got {rank}")
    return rank, world_size


def shard_range(n: int, rank: int, world_size: int) -> tuple[int, int]:
    """The contiguous share ``[start, stop)`` of ``range(n)`` that process ``rank`` takes.

    Shares differ in length by at most one and, in rank order, tile ``range(n)`` exactly:
    share ``r`` is ``[floor(r n / W), floor((r + 1) n / W))``. Some are empty when
    ``n < world_size``.

    Args:
        n: number of items (samples, files), >= 0.
        rank: this process, ``0 <= rank < world_size``.
        world_size: number of processes W.

    Returns:
        ``(start, stop)``.
    """
    rank, world_size = _check_rank(rank, world_size)
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f"n must be a non-negative int, got {n!r}")
    return rank * n // world_size, (rank + 1) * n // world_size


def shard(items: Sequence, rank: int, world_size: int) -> list:
    """The contiguous block of ``items`` (files, sample ranges) that process ``rank`` handles.

    Every item goes to exactly one process (see `shard_range`); process order is item order,
    so the concatenation of all shares in rank order is ``list(items)``.

    Args:
        items: a sequence (list, tuple, range).
        rank: this process.
        world_size: number of processes.

    Returns:
        A list, possibly empty.
    """
    if not isinstance(items, Sequence):
        raise TypeError(
            f"items must be a sequence (list, tuple, range), got {type(items).__name__}"
        )
    start, stop = shard_range(len(items), rank, world_size)
    return list(items[start:stop])


def rank_and_world_size(group=None) -> tuple[int, int]:
    """``(rank, world_size)`` in ``group`` (default: the default group); ``(0, 1)`` when
    ``torch.distributed`` is not initialised, so that single-process code needs no branch."""
    import torch.distributed as dist

    if not (dist.is_available() and dist.is_initialized()):
        return 0, 1
    return dist.get_rank(group), dist.get_world_size(group)


def all_reduce_moments(moments: Moments | Sequence[Moments], group=None):
    """Sum `Moments` over all processes with one ``all_reduce``.

    Every process of ``group`` must call it, with the same number of `Moments` of the same
    number of features (a collective). Several `Moments` (e.g. the folds of cross-validation)
    travel in one message. Without an initialised process group the input is returned as is
    (as copies), so the same code runs in one process.

    Args:
        moments: one `Moments` or a sequence of them (not modified).
        group: a ``torch.distributed`` process group; default the default group.

    Returns:
        New `Moments`: one, or a list in the input's order, holding the sums over processes
        (identical in every process).

    Raises:
        TypeError: if an item is not a `Moments`.
        ValueError: on an empty sequence or items with different numbers of features.
    """
    import torch.distributed as dist

    single = isinstance(moments, Moments)
    items = [moments] if single else list(moments)
    if not items:
        raise ValueError("no Moments given to all_reduce_moments")
    for m in items:
        if not isinstance(m, Moments):
            raise TypeError(f"expected torchjfa.Moments, got {type(m).__name__}")
    d = items[0].n_features
    if any(m.n_features != d for m in items):
        raise ValueError(f"all Moments must have the same number of features ({d})")
    if not (dist.is_available() and dist.is_initialized()):
        out = [m.copy() for m in items]
    else:
        flat = torch.cat([m.to_flat() for m in items])
        dist.all_reduce(flat, op=dist.ReduceOp.SUM, group=group)
        out = [Moments.from_flat(part, d) for part in flat.split(Moments.flat_size(d))]
    return out[0] if single else out


@contextlib.contextmanager
def process_group(
    backend: str = "gloo",
    *,
    init_method: str | None = None,
    rank: int | None = None,
    world_size: int | None = None,
    timeout_s: float = 300.0,
) -> Iterator[None]:
    """Initialise the default ``torch.distributed`` process group for a block, then destroy it.

    With no arguments the group is set up from the environment that ``torchrun`` (or
    Lightning, or SLURM via ``torchrun``) exports: ``RANK``, ``WORLD_SIZE``, ``MASTER_ADDR``,
    ``MASTER_PORT``. Without those variables (a plain ``python script.py``) it does nothing, so
    a script runs unchanged on one process. If a group is already initialised (Lightning
    started one) it is used and left alone.

    Args:
        backend: ``"gloo"`` (CPU; works everywhere) or ``"nccl"`` (CUDA tensors).
        init_method: e.g. ``"tcp://127.0.0.1:29500"``; default ``"env://"``.
        rank: needed with a ``tcp://`` or ``file://`` ``init_method``.
        world_size: needed with a ``tcp://`` or ``file://`` ``init_method``.
        timeout_s: how long a collective may wait for the other processes before it fails,
            seconds (so a crashed peer does not hang the others forever).

    Raises:
        ValueError: on a non-positive timeout or a rank outside ``[0, world_size)``.
    """
    import torch.distributed as dist

    if not timeout_s > 0:
        raise ValueError(f"timeout_s must be positive, got {timeout_s}")
    if not dist.is_available():
        raise RuntimeError("this torch build has no torch.distributed")
    if dist.is_initialized():
        yield
        return
    explicit = init_method is not None
    if not explicit and "WORLD_SIZE" not in os.environ:
        yield  # a single plain process
        return
    if explicit:
        if rank is None or world_size is None:
            raise ValueError(f"init_method={init_method!r} needs rank= and world_size=")
        _check_rank(rank, world_size)
    dist.init_process_group(
        backend,
        init_method=init_method,
        rank=-1 if rank is None else rank,
        world_size=-1 if world_size is None else world_size,
        timeout=datetime.timedelta(seconds=timeout_s),
    )
    try:
        yield
    finally:
        dist.destroy_process_group()
