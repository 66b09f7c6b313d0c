"""The test-only ``reach`` task folder, shaped as the shipped ones (``truckrl/tasks/<name>/``)."""

from tests.tasks.reach.task import TASK

__all__ = ["TASK"]
