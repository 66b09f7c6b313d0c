"""The env's outputs and one PPO iteration stay bit-identical to the recordings in tests/golden/.

A refactor must not change a single bit. A change that is meant to alter outputs re-records them
(``python tests/golden/golden.py``) and says why in its commit message.
"""

import numpy as np
import pytest
import torch

from tests.golden.golden import PPO_FILE, ROLLOUT_FILE, golden_ppo, golden_rollout, load_golden


def _compare(expected_file, actual: dict[str, np.ndarray]) -> None:
    expected = load_golden(expected_file)
    assert sorted(actual) == sorted(expected), "the set of output keys changed"
    for k, v in expected.items():
        a = actual[k]
        assert a.dtype == v.dtype and a.shape == v.shape, k
        np.testing.assert_array_equal(a, v, err_msg=f"{k} differs from the golden recording")


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # the recordings were made with one thread (reduction order)
    yield
    torch.set_num_threads(n)


def test_golden_rollout_bit_identical():
    _compare(ROLLOUT_FILE, golden_rollout())


def test_golden_ppo_iteration_bit_identical():
    _compare(PPO_FILE, golden_ppo())
