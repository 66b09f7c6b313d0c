"""Task lookup by name: ``truckrl.tasks.<name>`` is a package (a task folder) that defines ``TASK``.

A task folder holds everything that differs between tasks (``docs/architecture.md``): its
:class:`~truckrl.tasks.base.Task` subclass with its config class (a
:class:`~truckrl.tasks.config.TaskConfig` whose ``name`` is the folder name), exported as ``TASK``
from the package. Hydra offers it as ``task=<name>`` (``truckrl.config.schemas.register`` finds
every folder); the env, the RL code and the entry points find it by name. A task outside this
package works from Python with its dotted package path as the name (``name="mypkg.parking"``).
"""

from __future__ import annotations

import importlib
import pkgutil

from truckrl.config.fields import ConfigError


def task_names() -> list[str]:
    """Names of the task folders shipped in ``truckrl/tasks``."""
    import truckrl.tasks

    return sorted(m.name for m in pkgutil.iter_modules(truckrl.tasks.__path__) if m.ispkg)


def task_package(name: str) -> str:
    """The package of task ``name``: the folder ``truckrl.tasks.<name>``, or ``name`` itself when
    it is a dotted path (a task folder outside the package)."""
    return name if "." in name else f"truckrl.tasks.{name}"


def task_class(name: str) -> type:
    """The :class:`~truckrl.tasks.base.Task` subclass of task ``name``.

    Raises:
        ConfigError: no such task package, or it defines no ``TASK``.
    """
    parts = name.split(".") if isinstance(name, str) else [""]
    if not all(p.isidentifier() for p in parts) or (len(parts) == 1 and name not in task_names()):
        raise ConfigError(f"env.task.name = {name!r} is not one of {task_names()}")
    try:
        module = importlib.import_module(task_package(name))
    except ModuleNotFoundError:
        raise ConfigError(f"env.task.name = {name!r} is not one of {task_names()}") from None
    cls = getattr(module, "TASK", None)
    if cls is None:
        raise ConfigError(f"{task_package(name)} defines no TASK")
    return cls
