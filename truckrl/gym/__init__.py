"""Gymnasium and Stable-Baselines3 doors to :class:`~truckrl.env.TruckEnv` (``pip install truckrl[gym]``).

Importing this package registers one Gymnasium id per shipped task, ``truckrl/<Name>-v0``, where
``<Name>`` is the task class's name without ``Task`` (``truckrl tools configs env`` lists the
tasks). Gymnasium 1.x loads no plugins, so the ids exist once this module is imported; any of
these does it::

    import gymnasium, truckrl.gym
    gymnasium.register_envs(truckrl.gym)                       # the import, spelled for linters
    env = gymnasium.make("truckrl/Intersection-v0")
    env = gymnasium.make("truckrl.gym:truckrl/Intersection-v0")  # gymnasium imports the module
    envs = gymnasium.make_vec("truckrl/Intersection-v0", num_envs=1024, **{"lidar.num_beams": 32})

``make`` gives :class:`~truckrl.gym.single.TruckGymEnv` (one truck, ``gymnasium.Env``);
``make_vec`` gives :class:`~truckrl.gym.vector.TruckVectorEnv` (N trucks as one batch, through
the id's ``vector_entry_point``: no per-env Python loop). Keyword arguments are
:func:`truckrl.env.make.make_env`'s: ``seed``, ``difficulty``, ``device`` and config overrides
as dotted keys or mappings. :class:`~truckrl.gym.sb3.TruckSB3VecEnv` is the Stable-Baselines3
``VecEnv`` over the same batch. Registering imports the task classes (torch), not TorchRL;
the env classes load on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from truckrl.gym.sb3 import TruckSB3VecEnv
    from truckrl.gym.single import TruckGymEnv
    from truckrl.gym.vector import TruckVectorEnv

#: Namespace and version of the registered ids: ``truckrl/<Name>-v0``.
NAMESPACE, VERSION = "truckrl", 0
ENTRY_POINT = "truckrl.gym.single:TruckGymEnv"
VECTOR_ENTRY_POINT = "truckrl.gym.vector:TruckVectorEnv"

_EXPORTS = {
    "TruckGymEnv": "truckrl.gym.single",
    "TruckVectorEnv": "truckrl.gym.vector",
    "TruckSB3VecEnv": "truckrl.gym.sb3",
}
__all__ = ["ENV_IDS", "TruckGymEnv", "TruckSB3VecEnv", "TruckVectorEnv", "env_id", "register"]


def env_id(task: str) -> str:
    """The Gymnasium id of task folder ``task``: ``truckrl/<Name>-v0``, ``<Name>`` its class
    name without the ``Task`` suffix (a class ``UTurnTask`` gives ``truckrl/UTurn-v0``)."""
    from truckrl.tasks import task_class

    name = task_class(task).__name__
    return f"{NAMESPACE}/{name.removesuffix('Task') or name}-v{VERSION}"


def register(task: str, id: str | None = None) -> str:
    """Register ``task`` (a folder name, or the dotted package of a task outside truckrl) with
    Gymnasium under ``id`` (default :func:`env_id`); returns the id. Registering again replaces
    the entry (Gymnasium warns)."""
    import gymnasium

    id = id or env_id(task)
    gymnasium.register(
        id,
        entry_point=ENTRY_POINT,
        vector_entry_point=VECTOR_ENTRY_POINT,
        kwargs={"task": task},
    )
    return id


def _register_shipped() -> dict[str, str]:
    """Register every shipped task once per process; ``{id: task}``."""
    import gymnasium

    from truckrl.tasks import task_names

    ids = {env_id(t): t for t in task_names()}
    for id, task in ids.items():
        if id not in gymnasium.registry:
            register(task, id)
    return ids


#: The registered ids of the shipped tasks, ``{id: task folder}``.
ENV_IDS: dict[str, str] = _register_shipped()


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
