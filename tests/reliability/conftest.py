"""One torch thread for the in-process runs of these tests: their tensors are tiny, and on a busy
2-core machine two spinning intra-op threads made each session ~10x slower."""

import pytest
import torch


@pytest.fixture(autouse=True)
def one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
