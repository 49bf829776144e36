"""The excitation tests run torch on one thread: their tensors are small (grids of a few
hundred samples), where a second thread only adds synchronisation, and on a machine shared
with other jobs the threads' spinning made them several times slower."""

import pytest
import torch


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
