"""Rebuild a trained policy from a checkpoint: the one loader used by evaluation, the viewer and
export (through :func:`truckrl.rl.checkpoint.load_training_state`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from truckrl.config.fields import ConfigError, build
from truckrl.rl.checkpoint import CheckpointError, load_training_state, load_weights
from truckrl.tasks import EnvConfig, make_task


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


#: Config fields that were removed, under ``env`` and ``train_env``, with the values that meant
#: what the code does now (``None``: any value, the field no longer changes anything). A saved
#: config holding one of them loads without the field, so older runs still resume and play.
RETIRED_FIELDS: dict[tuple[str, ...], tuple[Any, ...] | None] = {
    ("lidar", "method"): ("dense",),  # the one batched LiDAR left
    ("task", "reach_slack"): None,  # read only by the uturn path shaping, which was removed
}


def _drop_retired(data: dict[str, Any], path: Path | str) -> None:
    """Remove :data:`RETIRED_FIELDS` from a saved config in place.

    Raises:
        CheckpointError: a retired field holds a value whose behaviour no longer exists.
    """
    for root in ("env", "train_env"):
        for keys, allowed in RETIRED_FIELDS.items():
            node = data.get(root)
            for k in keys[:-1]:
                node = node.get(k) if isinstance(node, dict) else None
            if not isinstance(node, dict) or keys[-1] not in node:
                continue
            value = node.pop(keys[-1])
            if allowed is not None and value not in allowed:
                dotted = ".".join((root, *keys))
                raise CheckpointError(
                    f"{path}: {dotted} = {value!r} was removed (only {list(allowed)} remains)"
                )


def saved_config(state: dict[str, Any]) -> dict[str, Any]:
    """The training config saved in a checkpoint, as a plain mapping (retired fields dropped,
    :data:`RETIRED_FIELDS`)."""
    try:
        data = yaml.safe_load(state["config"])
    except yaml.YAMLError as e:
        first = str(e).strip().splitlines()[0]
        raise CheckpointError(f"{state['path']}: saved config is not YAML ({first})") from None
    if not isinstance(data, dict):
        raise CheckpointError(f"{state['path']}: saved config is not a mapping")
    _drop_retired(data, state["path"])
    return data


def check_shapes(state: dict[str, Any], env_cfg: EnvConfig) -> None:
    """Check the checkpoint's observation and LiDAR sizes against its env config.

    Raises:
        CheckpointError: the beam count or the observation size recorded with the weights differs
            from what the saved config's env produces.
    """
    path = state["path"]
    if env_cfg.lidar.num_beams != state["num_beams"]:
        raise CheckpointError(
            f"{path}: the weights are for {state['num_beams']} LiDAR beams but its config has "
            f"env.lidar.num_beams = {env_cfg.lidar.num_beams}"
        )
    try:
        expected = make_task(env_cfg).num_features  # the config decides some tasks' extras
    except (ConfigError, KeyError, ImportError, TypeError) as e:
        raise CheckpointError(f"{path}: unknown task {env_cfg.task.name!r} ({e})") from None
    if state["num_obs"] != expected:
        raise CheckpointError(
            f"{path}: the weights are for {state['num_obs']} observation features but task "
            f"{env_cfg.task.name!r} observes {expected}"
        )


def load_policy(checkpoint: str | os.PathLike, device: str | Any = "cpu") -> LoadedPolicy:
    """Load a training checkpoint (file or run dir) and rebuild its actor.

    Raises:
        CheckpointError: missing, corrupt, or weights that do not fit the saved config (one line).
    """
    from truckrl.rl.network import ModelConfig, make_actor_critic  # torchrl: loaded on use

    state = load_training_state(checkpoint, map_location=device)
    path = state["path"]
    saved = saved_config(state)
    try:
        env_cfg = build(EnvConfig, saved.get("env"), "env")
        model_cfg = build(ModelConfig, saved.get("model"), "model")
    except ConfigError as e:
        raise CheckpointError(f"{path}: its saved config is not valid ({e})") from None
    check_shapes(state, env_cfg)
    ac = make_actor_critic(model_cfg, int(state["num_obs"]), int(state["num_beams"]))
    load_weights(ac.model, state["model"], path)
    ac.model.to(device).eval()
    difficulty = float(state["curriculum"]["difficulty"])
    return LoadedPolicy(ac.actor, env_cfg, difficulty, path, dict(state["counters"]))
