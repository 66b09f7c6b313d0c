"""The start states the planner plans: the held-out scenes ``evaluate_policy`` draws; and the
samples a scripted driver's successful episodes leave for behaviour cloning."""

from __future__ import annotations

import dataclasses

import torch
from tensordict import TensorDict
from torch import Tensor

from truckrl.config.fields import build
from truckrl.env import LIDAR_KEY, OBS_KEY, TruckEnv
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


def kept_samples(rows: list[tuple[Tensor, Tensor, Tensor, Tensor]], keep: Tensor) -> TensorDict:
    """The samples of the episodes in ``keep [E]`` (bool) out of per-step ``rows`` ``(alive [E]
    bool, observation [E, F], lidar [E, R], action [E, 2])`` recorded before each step: ``[M]``
    with "observation", "lidar" and "action", step-major."""
    picked = [(alive & keep, o, li, a) for alive, o, li, a in rows]
    return TensorDict(
        {
            OBS_KEY: torch.cat([o[m] for m, o, _, _ in picked]),
            LIDAR_KEY: torch.cat([li[m] for m, _, li, _ in picked]),
            "action": torch.cat([a[m] for m, _, _, a in picked]),
        },
        batch_size=[sum(int(m.sum()) for m, *_ in picked)],
    )
