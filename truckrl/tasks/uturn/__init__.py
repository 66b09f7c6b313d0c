"""The ``uturn`` task folder: see :mod:`truckrl.tasks.uturn.task`."""

from truckrl.tasks.uturn.task import TASK

__all__ = ["TASK"]
