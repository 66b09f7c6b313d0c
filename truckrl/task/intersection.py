"""Task ``intersection`` (the paper's): drive forward from a road shoulder to a goal pose on the
same road or across a crossing, through parked obstacles, within tightening tolerances.

* Episodes: :func:`truckrl.sim.scene.generate_scenes` (one straight road or two crossing roads,
  split curbs, parked obstacles, start and goal on the shoulders; rules in that module).
* Errors: position of the tractor rear axle to the goal [m]; tractor and trailer heading to the
  goal heading [rad] (the goal has the trailer aligned).
* Success: all three errors within the tolerances ``30 m * 2**-d`` and ``60 deg * 2**-d`` at
  difficulty ``d``, without collision or jack-knife.
* Reward (paper, "Rewards"): +0.05 per metre of progress, +0.5 per radian of tractor and of trailer
  heading correction, time reward 0, +5 success, -7 collision or jack-knife, -8 timeout.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.sim.geometry import wrap_angle
from truckrl.sim.scene import ROUTE_KEYS, SceneConfig, generate_scenes
from truckrl.sim.validation import param, validate
from truckrl.sim.vehicle import sample_vehicle_params
from truckrl.task.base import Task
from truckrl.task.config import TaskConfig
from truckrl.task.schema import Quantity

if TYPE_CHECKING:
    from tensordict import TensorDict


@dataclass
class RewardConfig:
    """Reward weights (paper, "Rewards")."""

    progress: float = param(0.05, unit="1/m", doc="per metre of progress", source="paper")
    tractor_heading: float = param(
        0.5, unit="1/rad", doc="per radian of tractor heading correction", source="paper"
    )
    trailer_heading: float = param(
        0.5, unit="1/rad", doc="per radian of trailer heading correction", source="paper"
    )
    time: float = param(0.0, unit="1/step", doc="every step", source="paper")
    success: float = param(5.0, doc="on success", source="paper")
    collision: float = param(-7.0, doc="on collision or jack-knife", source="paper")
    timeout: float = param(-8.0, doc="on timeout", source="paper")

    def __post_init__(self) -> None:
        validate(self, "env.task.reward")


@dataclass
class IntersectionConfig(TaskConfig):
    """Config of the intersection task: scene rules and reward weights."""

    name: str = param("intersection", choices=("intersection",), doc="task module")
    scene: SceneConfig = field(default_factory=SceneConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        validate(self, "env.task")


class IntersectionTask(Task):
    """The paper's task; see the module docstring."""

    name = "intersection"
    config_class = IntersectionConfig
    error_quantities = (
        Quantity("pos_error", "m", "position"),
        Quantity("tractor_heading_error", "rad", "tractor heading"),
        Quantity("trailer_heading_error", "rad", "trailer heading"),
    )
    reward_keys = (
        "r_progress",
        "r_tractor_heading",
        "r_trailer_heading",
        "r_time",
        "r_success",
        "r_collision",
        "r_timeout",
    )

    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        params = sample_vehicle_params(self.cfg.vehicle, m, rng, device)
        scenes = generate_scenes(self.cfg.task.scene, params, rng, device)
        scene = {k: getattr(scenes, k) for k in ("start", "goal", "segments", "mask", "kind")}
        scene["route"] = {k: getattr(scenes, k) for k in ROUTE_KEYS}
        return self.initial_state(params, scene, device)

    def errors(self, pose: Tensor, goal: Tensor) -> dict[str, Tensor]:
        """Position of the tractor rear axle to the goal [m]; tractor and trailer heading to the
        goal heading [rad] (the goal is a rear-axle pose with the trailer aligned)."""
        pos = torch.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])
        tractor = wrap_angle(goal[:, 2] - pose[:, 2]).abs()
        trailer = wrap_angle(goal[:, 2] - pose[:, 2] - pose[:, 3]).abs()
        return {
            "pos_error": pos,
            "tractor_heading_error": tractor,
            "trailer_heading_error": trailer,
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
        w = self.cfg.task.reward
        zero = torch.zeros_like(after["pos_error"])
        failed = flags["collision"] | flags["jackknife"]
        return {
            "r_progress": w.progress * (before["pos_error"] - after["pos_error"]),
            "r_tractor_heading": w.tractor_heading
            * (before["tractor_heading_error"] - after["tractor_heading_error"]),
            "r_trailer_heading": w.trailer_heading
            * (before["trailer_heading_error"] - after["trailer_heading_error"]),
            "r_time": zero + w.time,
            "r_success": torch.where(flags["success"], w.success, zero),
            "r_collision": torch.where(failed, w.collision, zero),
            "r_timeout": torch.where(flags["truncated"], w.timeout, zero),
        }


TASK = IntersectionTask
