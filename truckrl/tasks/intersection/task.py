"""Task ``intersection`` (the paper's): drive forward from a road shoulder to a goal pose on the
same road or across a crossing, through parked obstacles, within tightening tolerances.

* Episodes: :func:`truckrl.tasks.intersection.scene.generate_scenes` (one straight road or two crossing roads,
  split curbs, parked obstacles, start and goal on the shoulders; rules in that module).
* Errors: position of the tractor rear axle to the goal [m]; tractor and trailer heading to the
  goal heading [rad] (the goal has the trailer aligned).
* Success: all three errors within the tolerances ``30 m * 2**-d`` and ``60 deg * 2**-d`` at
  difficulty ``d``, without collision or jack-knife.
* Reward (paper, "Rewards"): +0.05 per metre of progress, +0.5 per radian of tractor and of trailer
  heading correction, time reward 0, +5 success, -7 collision or jack-knife, -8 timeout.
* Shaping (``env.task.reward.shaping``): ``goal`` (the paper's) measures progress as the straight
  distance to the goal and heading correction against the goal heading. ``route`` measures both
  along the lane route :func:`route_path`: the start lane up to the corner where it meets the goal
  lane, then the goal lane (:func:`route_reference`). With ``goal`` shaping, turning towards the
  goal at once earns the heading terms; in a right turn that puts the trailer over the near curb,
  and a policy can learn to stay put rather than crash. With ``route`` shaping the heading terms
  pay only for turning where the lanes meet. Both are potential-based (differences of a function
  of the state), so the same policies are optimal up to discounting.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.config.fields import param, validate
from truckrl.sim.geometry import wrap_angle
from truckrl.tasks.base import Task
from truckrl.tasks.config import TaskConfig
from truckrl.tasks.goals import PoseGoal, PoseRewardConfig, pose_reward_terms
from truckrl.tasks.intersection.bins import episode_bins
from truckrl.tasks.intersection.scene import ROUTE_KEYS, SceneConfig, generate_scenes

if TYPE_CHECKING:
    from tensordict import TensorDict


@dataclass
class RewardConfig(PoseRewardConfig):
    """Reward weights (paper, "Rewards")."""

    shaping: str = param(
        "goal",
        choices=("goal", "route"),
        doc="progress and heading terms measured to the goal (paper) or along the lane route "
        "(module doc)",
    )


@dataclass
class IntersectionConfig(TaskConfig):
    """Config of the intersection task: scene rules and reward weights."""

    name: str = param("intersection", choices=("intersection",), doc="task folder")
    scene: SceneConfig = field(default_factory=SceneConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        validate(self, "env.task")


class IntersectionTask(PoseGoal, Task):
    """The paper's task; see the module docstring."""

    name = "intersection"
    config_class = IntersectionConfig

    extra_state_keys = ("route_path",)

    @classmethod
    def category_bins(cls, info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]] | None:
        """Route, turn, crossing, trailer, road-width and goal-distance bins
        (:func:`~truckrl.tasks.intersection.bins.episode_bins`)."""
        return episode_bins(info)

    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        params = self.sample_params(m, rng, device)
        scenes = generate_scenes(self.cfg.task.scene, params, rng, device)
        scene = {k: getattr(scenes, k) for k in ("start", "goal", "segments", "mask", "kind")}
        scene["route"] = {k: getattr(scenes, k) for k in ROUTE_KEYS}
        return self.complete_state(self.initial_state(params, scene, device))

    def complete_state(self, state: TensorDict) -> TensorDict:
        """Add ``route_path [N, 3, 2]`` (from the current pose to the goal) where it is missing."""
        if "route_path" not in state.keys():
            state["route_path"] = route_path(state["pose"][:, :3], state["goal"])
        return state

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        w = self.cfg.task.reward
        if w.shaping == "route":
            before, after = route_errors(before), route_errors(after)
        return pose_reward_terms(w, before, after, flags)


#: Smallest |sin| of the angle between the start and goal lanes for which they count as meeting
#: at a corner; below it (about 10 deg, parallel lanes) the route is the straight start-goal line.
MIN_CORNER_SIN = 0.17


def route_path(start: Tensor, goal: Tensor) -> Tensor:
    """The lane route ``[N, 3, 2]`` [m]: start, corner, goal (tractor rear-axle positions).

    The corner is where the start lane (the line through ``start`` along its heading) meets the
    goal lane (the line through ``goal`` along its heading), when it lies ahead of the start and
    before the goal. Otherwise (a straight road or straight on: parallel lanes; or a corner
    behind the start or past the goal) it is the midpoint, and the route is the straight line.

    Args:
        start: ``[N, 3]`` start pose ``(x, y, heading)`` [m, m, rad].
        goal: ``[N, 3]`` goal pose, same convention.
    """
    s, g = start[:, :2], goal[:, :2]
    ahead, _, ok = lane_corner(start, goal)
    u = torch.stack((start[:, 2].cos(), start[:, 2].sin()), -1)
    corner = torch.where(ok[:, None], s + ahead[:, None] * u, 0.5 * (s + g))
    return torch.stack((s, corner, g), 1)


def lane_corner(start: Tensor, goal: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Where the start lane meets the goal lane (the lines through each pose along its heading).

    Args:
        start: ``[N, 3]`` start pose ``(x, y, heading)`` [m, m, rad].
        goal: ``[N, 3]`` goal pose, same convention.

    Returns:
        ``(ahead [N] [m], before [N] [m], ok [N] bool)``: the distance from the start to the
        corner along the start heading, from the corner to the goal along the goal heading, and
        whether the corner is a real one (lanes at least ``MIN_CORNER_SIN`` from parallel, the
        corner ahead of the start and before the goal; elsewhere the distances are meaningless).
    """
    u = torch.stack((start[:, 2].cos(), start[:, 2].sin()), -1)
    v = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)
    d = goal[:, :2] - start[:, :2]
    cross_uv = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    safe = torch.where(cross_uv.abs() < 1e-9, torch.ones_like(cross_uv), cross_uv)
    ahead = (d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0]) / safe  # start -> corner along u [m]
    before = (u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0]) / safe  # corner -> goal along v [m]
    ok = (cross_uv.abs() >= MIN_CORNER_SIN) & (ahead > 0) & (before > 0)
    return ahead, before, ok


def route_reference(xy: Tensor, path: Tensor, goal_heading: Tensor) -> tuple[Tensor, Tensor]:
    """Distance to go along the route from ``xy`` and the route's heading there.

    ``xy`` is projected on the nearer of the two legs (ties: the second). Distance to go = the
    lateral distance to that leg + the rest of the route from the projection [m]; the heading
    is the first leg's direction (start to corner) on the first leg and the goal heading on the
    second (the two agree when the corner is a real one: the second leg lies on the goal lane).

    Args:
        xy: ``[N, 2]`` tractor rear-axle position [m].
        path: ``[N, 3, 2]`` from :func:`route_path`.
        goal_heading: ``[N]`` [rad].

    Returns:
        ``(to_go [N] [m], heading [N] [rad])``.
    """
    a, b = path[:, :-1], path[:, 1:]  # [N, 2 legs, 2]
    ab = b - a
    length = torch.linalg.vector_norm(ab, dim=-1)  # [N, 2]
    t = ((xy[:, None] - a) * ab).sum(-1) / length.square().clamp_min(1e-12)
    t = t.clamp(0.0, 1.0)
    lateral = torch.linalg.vector_norm(xy[:, None] - (a + t[..., None] * ab), dim=-1)
    rest = (1.0 - t) * length + torch.stack((length[:, 1], torch.zeros_like(t[:, 1])), -1)
    second = lateral[:, 1] <= lateral[:, 0]
    to_go = torch.where(second, lateral[:, 1] + rest[:, 1], lateral[:, 0] + rest[:, 0])
    first = torch.atan2(ab[:, 0, 1], ab[:, 0, 0])
    return to_go, torch.where(second, goal_heading, first)


def route_errors(s: dict[str, Any]) -> dict[str, Tensor]:
    """The errors that ``route`` shaping rewards: distance to go along the route [m] and the
    tractor and trailer heading to the route's heading at the truck [rad] (``{key: [N]}``)."""
    pose = s["pose"]
    to_go, heading = route_reference(pose[:, :2], s["route_path"], s["goal"][:, 2])
    return {
        "pos_error": to_go,
        "tractor_heading_error": wrap_angle(heading - pose[:, 2]).abs(),
        "trailer_heading_error": wrap_angle(heading - pose[:, 2] - pose[:, 3]).abs(),
    }


TASK = IntersectionTask
