"""``make_env``: a :class:`~truckrl.env.truck_env.TruckEnv` of a named task in one call, with config
overrides written as dotted keys, the way the command line writes them::

    env = make_env("dock", num_envs=64, **{"lidar.num_beams": 32})
    env = make_env(difficulty=6, control={"longitudinal": "speed"})

The overrides are fields of :class:`~truckrl.tasks.EnvConfig` (``truckrl tools configs env``
lists them); a bad key or value raises :class:`~truckrl.config.fields.ConfigError` naming the
field, before any env is built.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch

from truckrl.config.fields import ConfigError, build
from truckrl.env.truck_env import TruckEnv
from truckrl.tasks import EnvConfig
from truckrl.tasks.config import DEFAULT_TASK, with_env_overrides


def nested_overrides(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``{"lidar.num_beams": 32, "control": {"lateral": "rate"}}`` as one nested mapping
    ``{"lidar": {"num_beams": 32}, "control": {"lateral": "rate"}}``.

    Dotted keys and mappings mix freely; mappings merge key by key.

    Raises:
        ConfigError: a key that is not a dotted name, or one field given both as a value and as
            a group of fields (``lidar=...`` beside ``lidar.num_beams=...``).
    """
    out: dict[str, Any] = {}

    def put(node: dict[str, Any], parts: list[str], value: Any, key: str) -> None:
        *parents, leaf = parts
        for i, part in enumerate(parents):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                where = ".".join(parts[: i + 1])
                raise ConfigError(f"{key}: {where} is given a value, not a group of fields")
            node = child
        if isinstance(value, Mapping):
            child = node.setdefault(leaf, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{key}: {'.'.join(parts)} is given a value, not a group")
            for k, v in value.items():
                put(child, _parts(k, f"{key}.{k}"), v, f"{key}.{k}")
        elif leaf in node:
            raise ConfigError(f"{key}: {'.'.join(parts)} is given twice")
        else:
            node[leaf] = value

    for key, value in overrides.items():
        put(out, _parts(key, key), value, key)
    return out


def _parts(key: Any, shown: str) -> list[str]:
    parts = key.split(".") if isinstance(key, str) else [""]
    if not all(p.isidentifier() for p in parts):
        raise ConfigError(f"{shown!r}: an override key is a dotted field name (lidar.num_beams)")
    return parts


def make_env(
    task: str = DEFAULT_TASK,
    num_envs: int = 1,
    device: torch.device | str = "cpu",
    seed: int | None = 0,
    difficulty: float | None = None,
    **overrides: Any,
) -> TruckEnv:
    """A :class:`TruckEnv` of ``num_envs`` trucks of task ``task``.

    Args:
        task: a task folder under ``truckrl/tasks/`` (``intersection``, ``dock``, ``uturn``), or
            the dotted package of a task outside truckrl.
        num_envs: trucks N held as one batch (``batch_size=[N]``).
        device: torch device of the state and of every output.
        seed: seed of the scene and vehicle generator (the same seed gives the same scenes);
            ``None`` draws one from torch's global generator.
        difficulty: the starting curriculum difficulty, ``tolerance.difficulty`` (tolerances
            scale by ``2**-difficulty``); ``None`` keeps the config's.
        **overrides: :class:`~truckrl.tasks.EnvConfig` fields, as dotted keys
            (``**{"lidar.num_beams": 32}``), as mappings (``lidar={"num_beams": 32}``) or both;
            the task's own fields are under ``task.`` (``**{"task.scene.crossing_prob": 1.0}``).

    Raises:
        ConfigError: an unknown task, field or value (the message names ``env.<field>``), or the
            task or the difficulty given twice.
    """
    if difficulty is not None:
        if "tolerance.difficulty" in overrides:
            raise ConfigError("difficulty and tolerance.difficulty are one field: give one")
        overrides = {**overrides, "tolerance.difficulty": difficulty}
    tree = nested_overrides(overrides)
    fields = tree.get("task", {})
    if not isinstance(fields, dict) or "name" in fields:
        raise ConfigError(
            "task.name is make_env's first argument (make_env('dock')); the task's fields are "
            "overrides under task. (task.FIELD=VALUE)"
        )
    base = build(EnvConfig, {"task": {"name": task}}, "env")
    config = with_env_overrides(base, tree, fixed=False)
    return TruckEnv(num_envs=num_envs, device=device, config=config, seed=seed)
