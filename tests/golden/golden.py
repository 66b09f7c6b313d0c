"""Golden recordings that pin the env's outputs and one PPO iteration bit for bit.

``python -m tests.golden.golden`` re-records every file; ``--out DIR`` writes them elsewhere (the
test compares such a fresh set with the recordings). Both run under :data:`PINNED_ENV`: torch's
scalar kernels and MKL's compatible code path, one thread, so the bits do not depend on which
vector unit the machine has (AVX2 and AVX-512 kernels round ``r_progress`` differently). Do that only when a change is *meant* to
alter outputs, and say why in the commit message; a refactor must leave them untouched.

* ``rollout.npz``: ``TruckEnv(num_envs=64, seed=0)`` with the default config, 200 steps of
  actions drawn from a fixed generator (uniform in [-1.2, 1.2], so the clamp is exercised, plus a
  NaN action every 37th step on truck 5 for the non-finite guard), with partial resets. Every
  leaf of every step is kept (root and ``next``); the file stores a root entry only where it is
  not the previous step's ``next`` entry (:func:`pack`), which keeps it under 2 MiB.
* ``rollout_dock.npz``, ``rollout_uturn.npz``: the same kind of rollout for the reversing tasks,
  ``TruckEnv(num_envs=16, seed=0)`` with ``task.name`` set, 100 steps (:func:`golden_task_rollout`).
* ``ppo.npz``: one PPO update (2 epochs x 4 minibatches) on a 16-truck x 32-step rollout of the
  paper's network under ``torch.manual_seed(0)``: the loss metrics and every parameter after it.
* ``outcomes_<task>.npz`` (``--outcomes [TASK ...]``, not part of the default set): how each of
  the 100 held-out episodes of a shipped policy ends, as ``truckrl eval
  checkpoint=pretrained:<task> difficulty=<claimed> episodes=100 seed=12345`` plays them
  (:func:`golden_outcomes`; checked by ``tests/rl/test_pretrained.py``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
ROLLOUT_FILE = HERE / "rollout.npz"
PPO_FILE = HERE / "ppo.npz"
#: Environment the recordings are made and checked under (read by torch and MKL at import).
PINNED_ENV = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE", "OMP_NUM_THREADS": "1"}
#: Reversing tasks pinned by their own recordings (N = 16, 100 steps).
TASK_ROLLOUT_FILES = {name: HERE / f"rollout_{name}.npz" for name in ("dock", "uturn")}
#: Shipped policies and the difficulty their model card's success rate is claimed at
#: (``truckrl/tasks/<task>/pretrained.md``).
CLAIMED_DIFFICULTY = {"intersection": 6.0, "dock": 7.0, "uturn": 4.0, "network": 4.0}
#: Per-episode outcomes of each shipped policy (:func:`golden_outcomes`).
OUTCOME_FILES = {task: HERE / f"outcomes_{task}.npz" for task in CLAIMED_DIFFICULTY}
#: Held-out scenes of the outcome recordings: ``truckrl eval``'s default seed, 100 episodes.
OUTCOME_SEED, OUTCOME_EPISODES = 12345, 100


def _flat(td) -> dict[str, np.ndarray]:
    out = {}
    for key in td.keys(include_nested=True, leaves_only=True):
        name = "/".join(key) if isinstance(key, tuple) else key
        out[name] = td.get(key).detach().cpu().numpy()
    return out


def _fixed_rollout(num_envs: int, steps: int, config: dict | None) -> dict[str, np.ndarray]:
    """Every output key of every step of ``steps`` fixed random actions (eager env, seed 0)."""
    from truckrl.env import TruckEnv

    env = TruckEnv(num_envs=num_envs, seed=0, config=config)
    gen = torch.Generator().manual_seed(1234)
    step = [0]

    def policy(td):
        a = torch.rand(num_envs, 2, generator=gen) * 2.4 - 1.2
        if step[0] % 37 == 0:
            a[5] = float("nan")
        step[0] += 1
        return td.set("action", a)

    td = env.rollout(steps, policy, break_when_any_done=False)
    env.close()
    return _flat(td)


def golden_rollout() -> dict[str, np.ndarray]:
    """Every output key of every step of the fixed rollout (eager env, default config)."""
    return _fixed_rollout(64, 200, None)


def golden_task_rollout(name: str) -> dict[str, np.ndarray]:
    """The fixed rollout of task ``name`` (16 trucks, 100 steps, the task's default config)."""
    return _fixed_rollout(16, 100, {"task": {"name": name}})


#: Suffix of a packed root key: its values at the steps where an episode (re)starts.
FRESH = "@fresh"


def fresh_steps(rollout: dict[str, np.ndarray]) -> np.ndarray:
    """``[N, T]`` bool: step 0 and every step after an episode ended (partial resets)."""
    done = rollout["next/done"][..., 0]
    return np.concatenate((np.ones_like(done[:, :1]), done[:, :-1]), axis=1)


def pack(rollout: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The rollout without what it stores twice: a root entry at step ``t + 1`` is the ``next``
    entry of step ``t`` unless an episode restarted there, so a root key that has a ``next`` twin
    keeps only its values at :func:`fresh_steps` (``<key>@fresh``). Checked to round-trip."""
    fresh = fresh_steps(rollout)
    out = dict(rollout)
    for key in [k for k in rollout if f"next/{k}" in rollout]:
        out.pop(key)
        out[key + FRESH] = rollout[key][fresh]
    restored = unpack(out)
    assert sorted(restored) == sorted(rollout)
    for key, value in rollout.items():
        assert np.array_equal(restored[key], value, equal_nan=True), key
    return out


def unpack(packed: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack`: every root key back at every step."""
    out = {k: v for k, v in packed.items() if not k.endswith(FRESH)}
    fresh = fresh_steps(out)
    for key in [k for k in packed if k.endswith(FRESH)]:
        name = key[: -len(FRESH)]
        nxt = out[f"next/{name}"]
        full = np.concatenate((nxt[:, :1], nxt[:, :-1]), axis=1).copy()
        full[fresh] = packed[key]
        out[name] = full
    return out


def load_golden(path: Path) -> dict[str, np.ndarray]:
    """A recording, rollout keys unpacked (see :func:`pack`)."""
    with np.load(path, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    return unpack(data) if any(k.endswith(FRESH) for k in data) else data


def golden_ppo() -> dict[str, np.ndarray]:
    """Loss metrics and parameters after one PPO update on a fixed rollout."""
    from truckrl.env import TruckEnv
    from truckrl.rl.network import ModelConfig, make_actor_critic
    from truckrl.rl.ppo import PPO, PPOConfig

    torch.manual_seed(0)
    env = TruckEnv(num_envs=16, seed=3)
    ac = make_actor_critic(ModelConfig(), 26, 16)
    with torch.no_grad():
        batch = env.rollout(32, ac.actor, break_when_any_done=False)
    env.close()
    ppo = PPO(ac, PPOConfig(num_epochs=2, num_minibatches=4, lr=3e-4))
    metrics = ppo.update(batch)
    out = {f"metric/{k}": np.asarray(v, dtype=np.float64) for k, v in metrics.items()}
    for name, p in ac.model.state_dict().items():
        out[f"param/{name}"] = p.detach().cpu().numpy()
    return out


def golden_outcomes(task: str) -> dict[str, np.ndarray]:
    """How each held-out episode of the shipped ``task`` policy ends, played as ``truckrl eval``
    plays them (:func:`~truckrl.evaluation.rollout.evaluate_policy`: the mean action, one batch
    of :data:`OUTCOME_EPISODES` scenes of :data:`OUTCOME_SEED`) at its claimed difficulty.

    Returns:
        "outcome" ``[E]`` int8: bit ``i`` set when outcome ``OUTCOMES[i]``'s flag is set at the
        episode's end (1 success, 2 collision, 4 jackknife, 8 timeout); "tolerance" ``[2]``
        float64 (position [m], heading [deg]); "difficulty" [] float64.
    """
    from truckrl.evaluation.rollout import evaluate_policy
    from truckrl.rl.policy import load_policy
    from truckrl.tasks import OUTCOMES

    policy = load_policy(f"pretrained:{task}")
    difficulty = CLAIMED_DIFFICULTY[task]
    results, tolerance, _ = evaluate_policy(
        policy.actor, policy.env_config, difficulty, OUTCOME_EPISODES, OUTCOME_SEED
    )
    outcome = sum(results[o.flag].to(torch.int8) << i for i, o in enumerate(OUTCOMES))
    return {
        "outcome": outcome.numpy().astype(np.int8),
        "tolerance": np.asarray(tolerance, dtype=np.float64),
        "difficulty": np.asarray(difficulty, dtype=np.float64),
    }


def record(out: Path, outcomes: list[str] | None = None) -> list[Path]:
    """Write every recording into ``out``, or with ``outcomes`` only those tasks'
    ``outcomes_<task>.npz``; returns the files written."""
    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)
    if outcomes is not None:
        files = {out / OUTCOME_FILES[t].name: golden_outcomes(t) for t in outcomes}
    else:
        files = {out / ROLLOUT_FILE.name: pack(golden_rollout()), out / PPO_FILE.name: golden_ppo()}
        for name, path in TASK_ROLLOUT_FILES.items():
            files[out / path.name] = pack(golden_task_rollout(name))
    for path, data in files.items():
        np.savez_compressed(path, **data)
    return list(files)


def record_pinned(out: Path, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m tests.golden.golden --out out args...`` in a subprocess under
    :data:`PINNED_ENV` (set before torch is imported, as it must be); raises on failure."""
    root = HERE.parent.parent
    cmd = [sys.executable, "-m", "tests.golden.golden", "--out", str(out), *args]
    env = {**os.environ, **PINNED_ENV}
    return subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=timeout)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="record the golden files under PINNED_ENV")
    ap.add_argument(
        "--out", type=Path, default=HERE, help="folder to write (default: tests/golden)"
    )
    ap.add_argument(
        "--outcomes",
        nargs="*",
        choices=sorted(OUTCOME_FILES),
        metavar="TASK",
        help="record only the shipped policies' outcomes_<TASK>.npz (no TASK: all of them)",
    )
    args = ap.parse_args(argv)
    if any(os.environ.get(k) != v for k, v in PINNED_ENV.items()):  # torch reads them at import
        env = {**os.environ, **PINNED_ENV}
        cmd = [
            sys.executable,
            "-m",
            "tests.golden.golden",
            *(sys.argv[1:] if argv is None else argv),
        ]
        os.execve(sys.executable, cmd, env)
    outcomes = None if args.outcomes is None else (args.outcomes or sorted(OUTCOME_FILES))
    for path in record(args.out, outcomes):
        print(f"wrote {path} ({path.stat().st_size:,} B)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
