"""The env's outputs stay bit-identical, and one PPO iteration float-identical, to the recordings
in tests/golden/.

A refactor of the env must not change a single bit. The recordings are made and checked in a
subprocess under :data:`~tests.golden.golden.PINNED_ENV` (scalar kernels, one thread), so they do
not depend on the machine's vector unit. The PPO iteration's matrix products still go through
BLAS, whose blocking may differ by CPU, so it is compared to 2e-6 of each entry's largest
magnitude, a few float32 ulps, far below what any change of the update's arithmetic moves (a 1 %
change of one gradient moves parameters by ~1e-5 relative). A change that is meant to alter
outputs re-records them (``python -m tests.golden.golden``) and says why in its commit message.
"""

from pathlib import Path

import numpy as np
import pytest

from tests.golden.golden import (
    PPO_FILE,
    ROLLOUT_FILE,
    TASK_ROLLOUT_FILES,
    load_golden,
    record_pinned,
)


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    """A folder with every recording made afresh by the code under test."""
    out = tmp_path_factory.mktemp("golden")
    record_pinned(out)
    return out


def _compare(expected_file: Path, actual_file: Path, rtol: float = 0.0) -> None:
    expected, actual = load_golden(expected_file), load_golden(actual_file)
    assert sorted(actual) == sorted(expected), "the set of output keys changed"
    for k, v in expected.items():
        a = actual[k]
        assert a.dtype == v.dtype and a.shape == v.shape, k
        msg = f"{k} differs from the golden recording"
        if rtol == 0.0 or not np.issubdtype(v.dtype, np.floating):
            np.testing.assert_array_equal(a, v, err_msg=msg)
        else:  # relative to the largest magnitude of the entry: tiny values round the same
            np.testing.assert_allclose(a, v, rtol=0.0, atol=rtol * np.abs(v).max(), err_msg=msg)


def test_golden_rollout_bit_identical(fresh):
    _compare(ROLLOUT_FILE, fresh / ROLLOUT_FILE.name)


def test_golden_ppo_iteration_float_identical(fresh):
    _compare(PPO_FILE, fresh / PPO_FILE.name, rtol=2e-6)


@pytest.mark.parametrize("name", sorted(TASK_ROLLOUT_FILES))
def test_golden_task_rollout_bit_identical(fresh, name):
    path = TASK_ROLLOUT_FILES[name]
    _compare(path, fresh / path.name)
