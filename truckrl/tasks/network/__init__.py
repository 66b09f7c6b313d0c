"""The ``network`` task folder: see :mod:`truckrl.tasks.network.task`."""

from truckrl.tasks.network.task import TASK

__all__ = ["TASK"]
