"""The ``dock`` task folder: see :mod:`truckrl.tasks.dock.task`."""

from truckrl.tasks.dock.task import TASK

__all__ = ["TASK"]
