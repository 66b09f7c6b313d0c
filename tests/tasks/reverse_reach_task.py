"""A reversing test task: back up straight (or with a sideways offset) on an empty plane.

``reverse = True``: the trucks get a per-truck ``max_reverse_speed`` and the control lets the
speed go down to ``-max_reverse_speed``. The goal lies ``distance`` metres straight *behind* the
start with the same heading, shifted sideways by ``offset`` metres to a random side; the truck
must reverse to it. Errors and success as the intersection task: tractor rear-axle position, and
tractor and trailer heading to the goal heading (the dock task measures on the trailer instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict
from torch import Tensor

from truckrl.config.fields import param, validate
from truckrl.sim.geometry import wrap_angle
from truckrl.tasks.base import Task
from truckrl.tasks.config import TaskConfig
from truckrl.tasks.schema import Quantity


@dataclass
class ReverseReachConfig(TaskConfig):
    name: str = param("tests.tasks.reverse_reach_task", doc="this module")
    distance: tuple[float, float] = param(
        (15.0, 25.0), lo=1.0, hi=100.0, unit="m", doc="goal this far straight behind the start"
    )
    offset: tuple[float, float] = param(
        (0.0, 0.0), lo=0.0, hi=20.0, unit="m", doc="and this far sideways (random side)"
    )
    bonus: float = param(5.0, doc="reward on success")
    penalty: float = param(-7.0, doc="reward on collision or jack-knife")

    def __post_init__(self) -> None:
        validate(self, "env.task")


class ReverseReachTask(Task):
    name = "reverse_reach"
    config_class = ReverseReachConfig
    reverse = True
    error_quantities = (
        Quantity("pos_error", "m", "position"),
        Quantity("tractor_heading_error", "rad", "tractor heading"),
        Quantity("trailer_heading_error", "rad", "trailer heading"),
    )
    reward_keys = ("r_progress", "r_heading", "r_success", "r_failure")

    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        cfg = self.cfg.task
        params = self.sample_params(m, rng, device)
        u = torch.rand(4, m, generator=rng, device=device)
        heading = (2.0 * u[0] - 1.0) * math.pi
        back = cfg.distance[0] + (cfg.distance[1] - cfg.distance[0]) * u[1]
        side = (cfg.offset[0] + (cfg.offset[1] - cfg.offset[0]) * u[2]) * torch.where(
            u[3] < 0.5, -1.0, 1.0
        )
        c, s = heading.cos(), heading.sin()
        start = torch.stack((torch.zeros_like(c), torch.zeros_like(c), heading), -1)
        goal = torch.stack((-back * c - side * s, -back * s + side * c, heading), -1)
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
        return {
            "pos_error": torch.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1]),
            "tractor_heading_error": wrap_angle(goal[:, 2] - pose[:, 2]).abs(),
            "trailer_heading_error": wrap_angle(goal[:, 2] - pose[:, 2] - pose[:, 3]).abs(),
        }

    def success(self, err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
        return (
            (err["pos_error"] <= tol_pos)
            & (err["tractor_heading_error"] <= tol_ang)
            & (err["trailer_heading_error"] <= tol_ang)
        )

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        cfg = self.cfg.task
        zero = torch.zeros_like(after["pos_error"])
        heading = ("tractor_heading_error", "trailer_heading_error")
        return {
            "r_progress": 0.05 * (before["pos_error"] - after["pos_error"]),
            "r_heading": 0.5 * sum(before[k] - after[k] for k in heading),
            "r_success": torch.where(flags["success"], cfg.bonus, zero),
            "r_failure": torch.where(flags["collision"] | flags["jackknife"], cfg.penalty, zero),
        }


TASK = ReverseReachTask
