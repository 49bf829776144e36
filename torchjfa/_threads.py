"""Torch's intra-op threads, one at a time, around work made of many small ops."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["single_thread"]


@contextmanager
def single_thread() -> Iterator[None]:
    """Run torch (and its BLAS) on one thread inside the block, then restore the setting.

    For work made of many small ops: the projection's ~100 x 100 matrices, the eager
    regressor's ops on one chunk of samples. Threads cannot speed such ops up, and where other
    work shares the cores each op waits for its slowest thread, so that a 100 x 100
    matrix-vector product can become many times slower (scikit-learn limits BLAS threads
    around such work for the same reason). The setting is process-wide,
    so other Python threads running torch meanwhile get one thread too.
    """
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
