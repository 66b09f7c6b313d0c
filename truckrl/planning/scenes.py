"""The start states the planner plans: the held-out scenes ``evaluate_policy`` draws."""

from __future__ import annotations

import dataclasses

import torch
from tensordict import TensorDict

from truckrl.config.fields import build
from truckrl.env import TruckEnv
from truckrl.tasks import EnvConfig


def held_out_states(
    env_cfg: EnvConfig | dict | None,
    episodes: int,
    seed: int,
    device: torch.device | str = "cpu",
    difficulty: float | None = None,
) -> TensorDict:
    """The start states ``[episodes]`` of the scenes that ``evaluate_policy`` draws for ``seed``
    (at ``difficulty``, default the env's starting one: a task with a start curriculum,
    ``Task.on_reset``, places its starts by the difficulty, as ``evaluate_policy`` does)."""
    cfg = dataclasses.replace(build(EnvConfig, env_cfg, "env"), compile=False)
    env = TruckEnv(num_envs=episodes, device=device, config=cfg, seed=seed)
    if difficulty is not None:
        env.set_difficulty(difficulty)
    env.reset()
    states = env.get_state()
    env.close()
    return states
