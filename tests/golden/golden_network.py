"""The golden rollout of the network task: ``rollout_network.npz``.

``python -m tests.golden.golden_network`` re-records it (``--out DIR`` writes it elsewhere), in a
subprocess under :data:`~tests.golden.golden.PINNED_ENV` (scalar kernels, one thread) as the
other golden files are; ``tests/tasks/network/test_network_golden.py`` records it afresh the same
way and compares it (integer entries exactly, floats to a few ulps). Re-record only when a change is *meant* to alter the task's
outputs, and say why in the commit message.

The rollout: ``TruckEnv(num_envs=8, seed=0)`` of task ``network`` at difficulty 3 (its last
curriculum level: a route through 2 junctions with every spawned vehicle), episode pool 8,
120 steps of actions uniform in [-1, 1] from a generator seeded 1234, partial resets included.
Kept per step ``[8, 120]``: the outcome flags, the reward, the tractor pose, the route's distance
to go, and the vehicles' arc lengths and speeds ``[8, 120, M]``; and the start state's route
metadata.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from tests.golden.golden import PINNED_ENV

HERE = Path(__file__).resolve().parent
NETWORK_FILE = HERE / "rollout_network.npz"
ENVS, STEPS, DIFFICULTY = 8, 120, 3.0


def golden_network_rollout() -> dict[str, np.ndarray]:
    """The fixed rollout (module doc) as ``{name: array}``."""
    from tensordict import TensorDict

    from truckrl.env import TruckEnv

    env = TruckEnv(
        num_envs=ENVS, seed=0, config={"task": {"name": "network"}, "episode_pool": ENVS}
    )
    env.set_difficulty(DIFFICULTY)
    td = env.reset()
    start = env.get_state()
    out: dict[str, list[np.ndarray]] = {}
    gen = torch.Generator().manual_seed(1234)
    for _ in range(STEPS):
        action = torch.rand(ENVS, 2, generator=gen) * 2.0 - 1.0
        step, td = env.step_and_maybe_reset(TensorDict({"action": action}, batch_size=[ENVS]))
        nxt = step["next"]
        state = env.get_state()
        rows = {
            **{k: nxt[k][:, 0] for k in ("done", "success", "collision", "jackknife", "truncated")},
            "reward": nxt["reward"][:, 0],
            "pose": state["pose"],
            "route_to_go": state["route_to_go"],
            "traffic_s": state["tr_s"],
            "traffic_v": state["tr_v"],
        }
        for k, v in rows.items():
            out.setdefault(k, []).append(v.numpy().copy())
    env.close()
    data = {k: np.stack(v, 1) for k, v in out.items()}
    for k in start["route"].keys():
        data[f"start/{k}"] = start["route", k].numpy()
    return data


def record_pinned(out: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m tests.golden.golden_network --out out`` under :data:`PINNED_ENV`."""
    cmd = [sys.executable, "-m", "tests.golden.golden_network", "--out", str(out)]
    env = {**os.environ, **PINNED_ENV}
    root = HERE.parent.parent
    return subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=timeout)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="record rollout_network.npz under PINNED_ENV")
    ap.add_argument("--out", type=Path, default=HERE, help="folder (default: tests/golden)")
    args = ap.parse_args(argv)
    if any(os.environ.get(k) != v for k, v in PINNED_ENV.items()):  # torch reads them at import
        return record_pinned(args.out).returncode
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / NETWORK_FILE.name, **golden_network_rollout())
    print(f"wrote {args.out / NETWORK_FILE.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
