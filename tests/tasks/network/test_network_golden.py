"""The network task's golden rollout stays as tests/golden/rollout_network.npz recorded it
(``python -m tests.golden.golden_network``; what it holds: that module's doc): integer and
boolean entries equal, float entries within tests/test_golden.py's ``ROLLOUT_TOL`` (why: its
doc)."""

import numpy as np

from tests.golden.golden_network import NETWORK_FILE, record_pinned
from tests.test_golden import ROLLOUT_TOL


def test_golden_network_rollout_bit_identical(tmp_path):
    record_pinned(tmp_path)
    with np.load(NETWORK_FILE) as f:
        expected = {k: f[k] for k in f.files}
    with np.load(tmp_path / NETWORK_FILE.name) as f:
        actual = {k: f[k] for k in f.files}
    assert sorted(actual) == sorted(expected), "the set of recorded keys changed"
    for k, v in expected.items():
        assert actual[k].dtype == v.dtype and actual[k].shape == v.shape, k
        msg = f"{k} differs from the recording"
        if np.issubdtype(v.dtype, np.floating):
            np.testing.assert_allclose(
                actual[k], v, rtol=ROLLOUT_TOL, atol=ROLLOUT_TOL, err_msg=msg
            )
        else:
            np.testing.assert_array_equal(actual[k], v, err_msg=msg)
    # the recording is a rollout worth pinning: traffic drives, and some episode ends
    assert expected["traffic_v"].max() > 1.0 and expected["done"].any()
