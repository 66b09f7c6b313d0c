"""The env's outputs stay bit-identical, and one PPO iteration float-identical, to the recordings
in tests/golden/.

A refactor of the env must not change a single bit. The PPO iteration runs matrix products,
whose BLAS kernels (MKL / oneDNN) are chosen per CPU: the same code on an AVX-512 and an AVX2
machine rounds a few sums differently (measured: up to 2.5e-7 relative after the iteration), so
it is compared to 2e-6 relative, a few float32 ulps, far below what any change of the update's
arithmetic moves (a 1 % change of one gradient moves parameters by ~1e-5 relative). A change that
is meant to alter outputs re-records them (``python tests/golden/golden.py``) and says why in its
commit message.
"""

import numpy as np
import pytest
import torch

from tests.golden.golden import PPO_FILE, ROLLOUT_FILE, golden_ppo, golden_rollout, load_golden


def _compare(expected_file, actual: dict[str, np.ndarray], rtol: float = 0.0) -> None:
    expected = load_golden(expected_file)
    assert sorted(actual) == sorted(expected), "the set of output keys changed"
    for k, v in expected.items():
        a = actual[k]
        assert a.dtype == v.dtype and a.shape == v.shape, k
        msg = f"{k} differs from the golden recording"
        if rtol == 0.0 or not np.issubdtype(v.dtype, np.floating):
            np.testing.assert_array_equal(a, v, err_msg=msg)
        else:  # relative to the largest magnitude of the entry: tiny values round the same
            np.testing.assert_allclose(a, v, rtol=0.0, atol=rtol * np.abs(v).max(), err_msg=msg)


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # the recordings were made with one thread (reduction order)
    yield
    torch.set_num_threads(n)


def test_golden_rollout_bit_identical():
    _compare(ROLLOUT_FILE, golden_rollout())


def test_golden_ppo_iteration_float_identical():
    _compare(PPO_FILE, golden_ppo(), rtol=2e-6)
