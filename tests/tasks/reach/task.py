"""A second task that exists only for the tests: reach a point on an empty plane.

It proves the task interface: one folder (this one) with a config class and a task is all a new
task needs; TruckEnv, the RL code and evaluation run it unchanged, and nothing in the package names
it (``tests/test_task_folders.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict
from torch import Tensor

from truckrl.config.fields import param, validate
from truckrl.tasks.base import Task
from truckrl.tasks.config import TaskConfig
from truckrl.tasks.schema import Quantity


@dataclass
class ReachConfig(TaskConfig):
    name: str = param("tests.tasks.reach", doc="this folder")
    distance: float = param(20.0, lo=1.0, hi=100.0, unit="m", doc="goal straight ahead")
    bonus: float = param(1.0, doc="reward on success")

    def __post_init__(self) -> None:
        validate(self, "env.task")


class ReachTask(Task):
    name = "reach"
    config_class = ReachConfig
    error_quantities = (Quantity("distance_error", "m", "distance"),)
    reward_keys = ("r_approach", "r_bonus")
    num_extras = 1  # the goal distance, an observation extra

    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        params = self.sample_params(m, rng, device)
        start = torch.zeros(m, 3, device=device)
        goal = torch.zeros(m, 3, device=device)
        goal[:, 0] = self.cfg.task.distance
        scene = {
            "start": start,
            "goal": goal,
            "segments": torch.zeros(m, 1, 4, device=device),
            "mask": torch.zeros(m, 1, dtype=torch.bool, device=device),
            "kind": torch.zeros(m, 1, dtype=torch.int8, device=device),
        }
        return self.initial_state(params, scene, device)

    def errors(self, s: dict[str, Any]) -> dict[str, Tensor]:
        pose, goal = s["pose"], s["goal"]
        return {"distance_error": torch.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])}

    def success(self, err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
        return err["distance_error"] <= tol_pos

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        zero = torch.zeros_like(after["distance_error"])
        return {
            "r_approach": before["distance_error"] - after["distance_error"],
            "r_bonus": torch.where(flags["success"], self.cfg.task.bonus, zero),
        }

    def observation_extras(self, s: dict[str, Any]) -> Tensor:
        return s["distance_error"][:, None] / 50.0


TASK = ReachTask
