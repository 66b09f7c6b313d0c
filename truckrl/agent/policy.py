"""Rebuild a trained policy from a checkpoint: the one loader used by evaluation, the viewer and
export (through :func:`truckrl.agent.checkpoint.load_training_state`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import yaml

from truckrl.agent.checkpoint import CheckpointError, load_training_state
from truckrl.agent.network import ModelConfig, make_actor_critic
from truckrl.sim.validation import ConfigError, build
from truckrl.task import EnvConfig


@dataclass
class LoadedPolicy:
    """A checkpoint's actor with what is needed to run it.

    Attributes:
        actor: TorchRL module reading "observation" and "lidar", writing "action" (the mean under
            ``ExplorationType.DETERMINISTIC``), in eval mode on the requested device.
        env_config: the env config (task and control included) the policy was trained with.
        difficulty: the curriculum difficulty saved in the checkpoint.
        path: the checkpoint file.
        counters: training counters (iteration, frames, wall time).
    """

    actor: Any
    env_config: EnvConfig
    difficulty: float
    path: Path
    counters: dict


def saved_config(state: dict[str, Any]) -> dict[str, Any]:
    """The training config saved in a checkpoint, as a plain mapping."""
    try:
        data = yaml.safe_load(state["config"])
    except yaml.YAMLError as e:
        raise CheckpointError(f"{state['path']}: saved config is not YAML ({e})") from None
    if not isinstance(data, dict):
        raise CheckpointError(f"{state['path']}: saved config is not a mapping")
    return data


def load_policy(checkpoint: str | os.PathLike, device: str | torch.device = "cpu") -> LoadedPolicy:
    """Load a training checkpoint (file or run dir) and rebuild its actor.

    Raises:
        CheckpointError: missing, corrupt, or weights that do not fit the saved config.
    """
    state = load_training_state(checkpoint, map_location=device)
    path = state["path"]
    saved = saved_config(state)
    try:
        env_cfg = build(EnvConfig, saved.get("env"), "env")
        model_cfg = build(ModelConfig, saved.get("model"), "model")
        if env_cfg.lidar.num_beams != state["num_beams"]:
            raise ValueError(
                f"num_beams {state['num_beams']} != env.lidar.num_beams {env_cfg.lidar.num_beams}"
            )
        ac = make_actor_critic(model_cfg, int(state["num_obs"]), int(state["num_beams"]))
        ac.model.load_state_dict(state["model"])
        difficulty = float(state["curriculum"]["difficulty"])
        counters = dict(state["counters"])
    except (KeyError, AttributeError, TypeError, ValueError, RuntimeError, ConfigError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"{path}: not a usable policy checkpoint ({first})") from None
    ac.model.to(device).eval()
    return LoadedPolicy(ac.actor, env_cfg, difficulty, path, counters)
