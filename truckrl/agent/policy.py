"""Rebuild a trained policy from a checkpoint: the one loader used by evaluation and the viewer."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf

from truckrl.agent.checkpoint import CheckpointError, load_checkpoint, resolve_checkpoint
from truckrl.agent.network import ModelConfig, make_actor_critic
from truckrl.env import EnvConfig
from truckrl.sim.validation import ConfigError, from_mapping


@dataclass
class LoadedPolicy:
    """A checkpoint's actor with what is needed to run it.

    Attributes:
        actor: TorchRL module reading "observation" and "lidar", writing "action" (the mean under
            ``ExplorationType.DETERMINISTIC``), in eval mode on the requested device.
        env_config: the env/control config the policy was trained with.
        difficulty: the curriculum difficulty saved in the checkpoint.
        path: the checkpoint file.
        counters: training counters (iteration, frames, wall time).
    """

    actor: Any
    env_config: EnvConfig
    difficulty: float
    path: Path
    counters: dict


def load_policy(checkpoint: str | os.PathLike, device: str | torch.device = "cpu") -> LoadedPolicy:
    """Load a training checkpoint (file or run dir) and rebuild its actor.

    Raises:
        CheckpointError: missing, corrupt, or weights that do not fit the saved config.
    """
    path = resolve_checkpoint(checkpoint)
    state = load_checkpoint(path, map_location=device)
    try:
        saved = OmegaConf.create(state["config"])
        env_cfg = EnvConfig.from_hydra(saved.env, saved.control)
        model_cfg = from_mapping(ModelConfig, OmegaConf.to_container(saved.model), "model")
        ac = make_actor_critic(model_cfg, int(state["num_obs"]), int(state["num_beams"]))
        ac.model.load_state_dict(state["model"])
        difficulty = float(state["curriculum"]["difficulty"])
        counters = dict(state["counters"])
    except (KeyError, AttributeError, TypeError, ValueError, RuntimeError, ConfigError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"{path}: not a usable policy checkpoint ({first})") from None
    ac.model.to(device).eval()
    return LoadedPolicy(ac.actor, env_cfg, difficulty, path, counters)
