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


#: Reward terms of :func:`pose_reward_terms`, in summation order (``Task.reward_keys``).
POSE_REWARD_KEYS: tuple[str, ...] = (
    "r_progress",
    "r_tractor_heading",
    "r_trailer_heading",
    "r_time",
    "r_success",
    "r_collision",
    "r_timeout",
)


def pose_reward_terms(
    w: PoseRewardConfig,
    before: dict[str, Tensor],
    after: dict[str, Tensor],
    flags: dict[str, Tensor],
    progress: Tensor | None = None,
) -> dict[str, Tensor]:
    """The paper's reward terms ``{key: [N]}`` (:data:`POSE_REWARD_KEYS`) of one step.

    Args:
        w: the weights.
        before, after: the :func:`pose_errors` (or a task's shaped version of them) before and
            after the step; the heading terms pay their decrease [rad].
        flags: ``success``, ``collision``, ``jackknife``, ``truncated`` (bool ``[N]``).
        progress: metres gained this step; default the decrease of ``pos_error``.
    """
    zero = torch.zeros_like(after["pos_error"])
    failed = flags["collision"] | flags["jackknife"]
    if progress is None:
        progress = before["pos_error"] - after["pos_error"]
    return {
        "r_progress": w.progress * progress,
        "r_tractor_heading": w.tractor_heading
        * (before["tractor_heading_error"] - after["tractor_heading_error"]),
        "r_trailer_heading": w.trailer_heading
        * (before["trailer_heading_error"] - after["trailer_heading_error"]),
        "r_time": zero + w.time,
        "r_success": torch.where(flags["success"], w.success, zero),
        "r_collision": torch.where(failed, w.collision, zero),
        "r_timeout": torch.where(flags["truncated"], w.timeout, zero),
    }


class PoseGoal:
    """Mixin for a :class:`~truckrl.tasks.base.Task` (list it first) whose goal is a pose: the
    errors, success test and reward keys of this module."""

    error_quantities = POSE_ERRORS
    reward_keys = POSE_REWARD_KEYS

    def errors(self, s: dict[str, Any]) -> dict[str, Tensor]:
        """:func:`pose_errors`."""
        return pose_errors(s)

    def success(self, err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
        """:func:`pose_success`."""
        return pose_success(err, tol_pos, tol_ang)
