"""How far the env's outputs now are from the golden recordings, key by key (nothing re-recorded).

Run from the repository root::

    PYTHONPATH=. python tests/reliability/compare_golden.py

For every key of ``tests/golden/rollout.npz`` and ``ppo.npz`` that differs: how many values
differ, the largest absolute difference, and the largest one relative to the key's largest
magnitude.
"""

from __future__ import annotations

import numpy as np
import torch

from tests.golden.golden import PPO_FILE, ROLLOUT_FILE, golden_ppo, golden_rollout, load_golden


def compare(name, path, actual: dict[str, np.ndarray]) -> None:
    expected = load_golden(path)
    assert sorted(actual) == sorted(expected), "the set of output keys changed"
    same = 0
    for k in sorted(expected):
        e, a = expected[k], actual[k]
        if a.dtype == e.dtype and a.shape == e.shape and np.array_equal(a, e, equal_nan=True):
            same += 1
            continue
        if a.dtype == np.bool_ or e.dtype == np.bool_:
            diff = a != e
            print(f"  {k}: {int(diff.sum())} / {e.size} values differ (bool)")
            continue
        ad, ed = a.astype(np.float64), e.astype(np.float64)
        diff = ~((ad == ed) | (np.isnan(ad) & np.isnan(ed)))
        d = np.abs(ad - ed)[diff]
        scale = np.nanmax(np.abs(ed)) if ed.size else 1.0
        print(
            f"  {k}: {int(diff.sum())} / {e.size} values differ, max |diff| {d.max():.3g}"
            f" (relative to max |value| {scale:.3g}: {d.max() / scale:.3g})"
        )
    print(f"{name}: {same} of {len(expected)} keys bit-identical")


def main() -> None:
    torch.set_num_threads(1)
    compare("rollout.npz", ROLLOUT_FILE, golden_rollout())
    compare("ppo.npz", PPO_FILE, golden_ppo())


if __name__ == "__main__":
    main()
