"""The network task's golden rollout stays bit-identical to tests/golden/rollout_network.npz
(recorded by ``python -m tests.golden.golden_network``; what it holds: that module's doc)."""

import numpy as np

from tests.golden.golden_network import NETWORK_FILE, record_pinned


def test_golden_network_rollout_bit_identical(tmp_path):
    record_pinned(tmp_path)
    with np.load(NETWORK_FILE) as f:
        expected = {k: f[k] for k in f.files}
    with np.load(tmp_path / NETWORK_FILE.name) as f:
        actual = {k: f[k] for k in f.files}
    assert sorted(actual) == sorted(expected), "the set of recorded keys changed"
    for k, v in expected.items():
        assert actual[k].dtype == v.dtype and actual[k].shape == v.shape, k
        np.testing.assert_array_equal(actual[k], v, err_msg=f"{k} differs from the recording")
    # the recording is a rollout worth pinning: traffic drives, and some episode ends
    assert expected["traffic_v"].max() > 1.0 and expected["done"].any()
