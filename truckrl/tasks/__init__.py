"""The task core (pure torch, no TorchRL): a :class:`Task` per module, found by name.

See :mod:`truckrl.tasks.base` for the state layout and the functional core, and
``docs/architecture.md`` for how to add a task.
"""

from truckrl.tasks.base import NUM_FEATURES, Task, sensor_origin
from truckrl.tasks.config import (
    MAX_DIFFICULTY,
    SENSOR_SCALE,
    EnvConfig,
    TaskConfig,
    ToleranceConfig,
)
from truckrl.tasks.registry import task_class, task_names
from truckrl.tasks.schema import (
    FLAG_KEYS,
    OUTCOMES,
    CategoryDim,
    Outcome,
    Quantity,
    shown,
    shown_float,
)


def make_task(cfg: EnvConfig) -> Task:
    """The task object for ``cfg`` (its class is picked by ``cfg.task.name``)."""
    return task_class(cfg.task.name)(cfg)


__all__ = [
    "CategoryDim",
    "FLAG_KEYS",
    "MAX_DIFFICULTY",
    "NUM_FEATURES",
    "OUTCOMES",
    "SENSOR_SCALE",
    "EnvConfig",
    "Outcome",
    "Quantity",
    "Task",
    "TaskConfig",
    "ToleranceConfig",
    "make_task",
    "sensor_origin",
    "shown",
    "shown_float",
    "task_class",
    "task_names",
]
