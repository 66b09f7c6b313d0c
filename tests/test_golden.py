"""The env's outputs stay bit-identical, and one PPO iteration float-identical, to the recordings
in tests/golden/.

A refactor of the env must not change its outputs. The recordings are made and checked in a
subprocess under :data:`~tests.golden.golden.PINNED_ENV` (scalar kernels, one thread). That pins
the bits on machines of one vendor, but not across them: on an AMD EPYC (AVX-512) the pinned
rollout differs from the recordings in the last bits of the LiDAR, ``pos_error`` and what is
computed from them (at most 2 float32 ulps of a distance, 1.5e-6 of a normalised range), while
every pose, flag and counter is equal. Integer and boolean entries are therefore compared exactly
and float entries to :data:`ROLLOUT_TOL` (absolute and relative, elementwise), about 16 ulps at
unit magnitude: a 0.1 % change of a reward weight moves ``r_progress`` by 2e-5 and fails it. The
PPO iteration's matrix products go through BLAS, whose blocking differs by CPU, so it is compared
to :data:`PPO_TOL` of each entry's largest magnitude, a few float32 ulps, below what any change of
the update's arithmetic moves (a 1 % change of one gradient moves parameters by ~1e-5 relative).
A change that is meant to alter outputs re-records them (``python -m tests.golden.golden``) and
says why in its commit message.
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

#: Float tolerance of the env recordings, absolute and relative (module doc).
ROLLOUT_TOL = 2e-6
#: Tolerance of the PPO iteration, relative to each entry's largest magnitude (module doc).
PPO_TOL = 5e-6


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    """A folder with every recording made afresh by the code under test."""
    out = tmp_path_factory.mktemp("golden")
    record_pinned(out)
    return out


def _compare(expected_file: Path, actual_file: Path, scaled: float = 0.0) -> None:
    """Integer and boolean entries equal; float entries within :data:`ROLLOUT_TOL`, or, with
    ``scaled``, within ``scaled`` times the entry's largest magnitude."""
    expected, actual = load_golden(expected_file), load_golden(actual_file)
    assert sorted(actual) == sorted(expected), "the set of output keys changed"
    for k, v in expected.items():
        a = actual[k]
        assert a.dtype == v.dtype and a.shape == v.shape, k
        msg = f"{k} differs from the golden recording"
        if not np.issubdtype(v.dtype, np.floating):
            np.testing.assert_array_equal(a, v, err_msg=msg)
        elif scaled:  # relative to the largest magnitude of the entry: tiny values round the same
            np.testing.assert_allclose(a, v, rtol=0.0, atol=scaled * np.abs(v).max(), err_msg=msg)
        else:
            np.testing.assert_allclose(a, v, rtol=ROLLOUT_TOL, atol=ROLLOUT_TOL, err_msg=msg)


def test_golden_rollout_bit_identical(fresh):
    _compare(ROLLOUT_FILE, fresh / ROLLOUT_FILE.name)


def test_golden_ppo_iteration_float_identical(fresh):
    _compare(PPO_FILE, fresh / PPO_FILE.name, scaled=PPO_TOL)


@pytest.mark.parametrize("name", sorted(TASK_ROLLOUT_FILES))
def test_golden_task_rollout_bit_identical(fresh, name):
    path = TASK_ROLLOUT_FILES[name]
    _compare(path, fresh / path.name)
