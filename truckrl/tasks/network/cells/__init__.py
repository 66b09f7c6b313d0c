"""Task ``truckrl.tasks.network.cells``: the ``network`` task with the intersection task's
observation against the route's junction exits as sub-goals (:mod:`.task`)."""

from truckrl.tasks.network.cells.task import TASK

__all__ = ["TASK"]
