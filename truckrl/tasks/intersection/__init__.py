"""The ``intersection`` task folder: see :mod:`truckrl.tasks.intersection.task`."""

from truckrl.tasks.intersection.task import TASK

__all__ = ["TASK"]
