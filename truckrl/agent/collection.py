"""Environments for data collection: seeding per worker, in-process or ParallelEnv, and the
curriculum difficulty sent to every worker."""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
from torchrl.envs import EnvBase, ParallelEnv

from truckrl.env import TruckEnv
from truckrl.task import EnvConfig


def env_seed(seed: int, iteration: int, worker: int) -> int:
    """Independent, reproducible seed per (run seed, session start iteration, worker)."""
    return int(np.random.SeedSequence([seed, iteration, worker]).generate_state(1)[0])


def make_env(
    env_cfg: EnvConfig,
    workers: int,
    num_envs: int,
    seed: int,
    iteration: int = 0,
    device: str | torch.device = "cpu",
) -> EnvBase:
    """One in-process TruckEnv (``workers=1``) or a ParallelEnv of ``workers`` batched TruckEnvs,
    each of ``num_envs`` trucks, seeded from ``(seed, iteration, worker)``."""
    make = functools.partial(TruckEnv, num_envs=num_envs, device=device, config=env_cfg)
    if workers == 1:
        return make(seed=env_seed(seed, iteration, 0))
    fns = [functools.partial(make, seed=env_seed(seed, iteration, w)) for w in range(workers)]
    env = ParallelEnv(workers, fns, device=device)
    env.start()
    return env


def set_difficulty(env: EnvBase, difficulty: float) -> tuple[float, float]:
    """Send the difficulty to every worker; return ``(position [m], heading [deg])`` tolerances
    read back from the (first) environment."""
    env.set_difficulty(difficulty)
    tol = env.tolerances()
    pos, ang = tol[0] if isinstance(env, ParallelEnv) else tol
    return float(pos.reshape(-1)[0]), math.degrees(float(ang.reshape(-1)[0]))


def check_difficulty(batch, difficulty: float) -> None:
    """Raise if a collected batch ``[..., T]`` was not run at ``difficulty`` at its last step."""
    reached = batch["next", "difficulty"][..., -1, :]
    if not torch.isclose(reached, torch.full_like(reached, difficulty)).all():
        raise RuntimeError(f"difficulty {difficulty} did not reach every environment worker")
