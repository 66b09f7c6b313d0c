"""Errors, success and reward weights of a goal pose, for every task whose goal is a rear-axle
pose with the trailer aligned (the paper's goal; ``intersection`` and ``uturn`` use it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from truckrl.config.fields import param
from truckrl.sim.geometry import wrap_angle
from truckrl.tasks.config import TerminalRewardConfig
from truckrl.tasks.schema import Quantity

#: The three errors of :func:`pose_errors`, with units (``Task.error_quantities``).
POSE_ERRORS: tuple[Quantity, ...] = (
    Quantity("pos_error", "m", "position"),
    Quantity("tractor_heading_error", "rad", "tractor heading"),
    Quantity("trailer_heading_error", "rad", "trailer heading"),
)


def pose_errors(s: dict[str, Any]) -> dict[str, Tensor]:
    """Position of the tractor rear axle to the goal [m]; tractor and trailer heading to the goal
    heading [rad] (the goal is a rear-axle pose with the trailer aligned), each ``[N]``."""
    pose, goal = s["pose"], s["goal"]
    pos = torch.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])
    tractor = wrap_angle(goal[:, 2] - pose[:, 2]).abs()
    trailer = wrap_angle(goal[:, 2] - pose[:, 2] - pose[:, 3]).abs()
    return {
        "pos_error": pos,
        "tractor_heading_error": tractor,
        "trailer_heading_error": trailer,
    }


def pose_success(err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
    """``[N]`` bool: all three :func:`pose_errors` within the tolerances."""
    return (
        (err["pos_error"] <= tol_pos)
        & (err["tractor_heading_error"] <= tol_ang)
        & (err["trailer_heading_error"] <= tol_ang)
    )


@dataclass
class PoseRewardConfig(TerminalRewardConfig):
    """The paper's reward weights for a goal pose (paper, "Rewards"): the terminal ones and the
    progress and heading-correction terms; a task's reward config extends it with its shaping."""

    progress: float = param(0.05, unit="1/m", doc="per metre of progress", source="paper")
    tractor_heading: float = param(
        0.5, unit="1/rad", doc="per radian of tractor heading correction", source="paper"
    )
    trailer_heading: float = param(
        0.5, unit="1/rad", doc="per radian of trailer heading correction", source="paper"
    )
