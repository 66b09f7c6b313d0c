"""Task lookup by name: ``truckrl.task.<name>`` is a module that defines ``TASK``.

Adding a task is one module here: a :class:`~truckrl.task.base.Task` subclass with its config
class (a :class:`~truckrl.task.config.TaskConfig` whose ``name`` is the module name), exported as
``TASK``. Hydra offers it as ``task=<name>`` (``truckrl.configs.register`` finds every module); the
env, the agent and the entry points find it by name. A task outside this package works from Python
with its dotted module path as the name (``name="mypkg.parking"``).
"""

from __future__ import annotations

import importlib
import pkgutil

from truckrl.sim.validation import ConfigError

_NOT_TASKS = {"base", "config", "registry", "schema"}


def task_names() -> list[str]:
    """Names of the task modules shipped in ``truckrl/task``."""
    import truckrl.task

    return sorted(
        m.name for m in pkgutil.iter_modules(truckrl.task.__path__) if m.name not in _NOT_TASKS
    )


def task_class(name: str) -> type:
    """The :class:`~truckrl.task.base.Task` subclass of task ``name``.

    Raises:
        ConfigError: no such task module, or it defines no ``TASK``.
    """
    parts = name.split(".") if isinstance(name, str) else [""]
    if not all(p.isidentifier() for p in parts) or name in _NOT_TASKS:
        raise ConfigError(f"env.task.name = {name!r} is not one of {task_names()}")
    try:
        module = importlib.import_module(name if len(parts) > 1 else f"truckrl.task.{name}")
    except ModuleNotFoundError:
        raise ConfigError(f"env.task.name = {name!r} is not one of {task_names()}") from None
    cls = getattr(module, "TASK", None)
    if cls is None:
        raise ConfigError(f"truckrl.task.{name} defines no TASK")
    return cls
