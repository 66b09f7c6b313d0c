"""Task ``uturn``: turn an articulated truck round on a road too narrow for a forward loop.

* Episodes: :func:`truckrl.tasks.uturn.scene.generate_uturn_scenes` (a narrow straight road with a
  side branch, left or right, sometimes a dead end; start heading towards the branch, goal
  behind the start in the other lane facing back; rules and the proof that a forward U-turn does
  not fit on the road in that module). The truck must reverse at least once: :attr:`reverse` is
  True, so every truck gets a ``max_reverse_speed`` and the speed goes down to minus it.
* Errors and success as the intersection task: tractor rear-axle position to the goal [m],
  tractor and trailer heading to the goal heading [rad], all within ``30 m * 2**-d`` and
  ``60 deg * 2**-d`` at difficulty ``d``, without collision or jack-knife.
* Reward: the paper's terms and values (+0.05 per metre of progress, +0.5 per radian of tractor
  and of trailer heading correction, time 0, +5 success, -7 collision or jack-knife, -8 timeout),
  each a separate key.
* Shaping (``env.task.reward.shaping``): ``goal`` measures progress as the straight distance to
  the goal (the paper's). Here that punishes the manoeuvre's first half: the goal lies behind,
  so driving forward to the branch loses reward, and reversing straight back down the start lane
  towards the goal (heading still wrong) earns it, a dead end.

  ``route`` (default) measures progress with the potential

      to_go = w * (|p - T| + |T - g|) + (1 - w) * |p - g|,   w = (1 + cos(theta - theta_0)) / 2

  with ``p`` the tractor rear axle, ``g`` the goal, ``T`` the **turning point** (on the branch
  axis, ``turn_depth`` of the branch depth beyond the curb: :func:`turning_point`), ``theta`` the
  tractor heading and ``theta_0`` the start heading. While the truck still faces the way it started (``w = 1``)
  the distance to go runs via the branch; once it faces back (``w = 0``) it is the straight
  distance to the goal; in between (in the branch) it blends. The heading terms stay measured
  to the goal heading: turning round is what the task asks, wherever it happens. Being a
  function of the state, the shaping is potential-based: the optimal policies are those of the
  sparse terminal rewards, up to discounting. The pull past the branch is part of the route:
  until the tractor rear axle has been level with the **pull point** ``P`` (on the road past
  the branch, where the start curriculum's reverse path begins; the state's latched
  ``pulled``), ``|p - T|`` reads ``|p - P| + |P - T|``: the pull (about a truck length away from
  ``T``) would otherwise cost reward, and a policy can learn to stop at the mouth.
* Observation extras (3): signed speed / ``max_reverse_speed`` (below -1 never, < 0 reversing),
  ``max_reverse_speed`` mapped from its configured range to [-1, 1], and the phase ``pulled``
  (1 once the truck has pulled past the branch to ``P``). With ``env.task.observe_route``
  (9 extras; on in ``experiment=uturn``) also ``P`` and ``T`` in the tractor frame and the
  branch axis direction relative to the tractor heading.
* Start curriculum (``env.task.start``, :meth:`UTurnTask.on_reset`): at low difficulty the
  truck starts part-way through the manoeuvre, at its end first.
* Scene metadata: ``state["route"]`` holds the generator's per-episode ``info``
  (:data:`~truckrl.tasks.uturn.scene.INFO_KEYS`); :attr:`UTurnTask.category_dims` bins evaluation
  by branch side, dead end, road width, branch width, branch angle and truck length.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.config.fields import param, validate
from truckrl.sim.geometry import rotate, to_local
from truckrl.tasks.base import Task
from truckrl.tasks.config import SENSOR_SCALE, TaskConfig
from truckrl.tasks.goals import PoseGoal, PoseRewardConfig, pose_reward_terms
from truckrl.tasks.schema import CategoryDim
from truckrl.tasks.uturn.scene import INFO_KEYS, UTurnSceneConfig, generate_uturn_scenes
from truckrl.tasks.uturn.start import (
    UTurnStartConfig,
    curriculum_start,
    pulled_past,
    reverse_path,
)

if TYPE_CHECKING:
    from tensordict import TensorDict

    from truckrl.tasks.config import EnvConfig

#: State key of the per-episode scene metadata ``{key: [N]}`` (:data:`INFO_KEYS`): the key every
#: task records its scene metadata under (evaluation bins episodes by it, ``category_dims``).
INFO_STATE_KEY = "route"


@dataclass
class UTurnRewardConfig(PoseRewardConfig):
    """Reward weights (the paper's values) and the progress shaping (module doc)."""

    shaping: str = param(
        "route",
        choices=("goal", "route"),
        doc="progress measured straight to the goal (paper) or via a turning point at turn_depth "
        "blended by heading (route; module doc)",
    )
    turn_depth: float = param(
        0.5,
        lo=0.0,
        hi=1.0,
        unit="branch depths",
        doc="shaping=route: turning point on the branch axis, this fraction of the branch depth "
        "from the curb",
    )


@dataclass
class UTurnConfig(TaskConfig):
    """Config of the uturn task: scene rules, reward weights and the start curriculum."""

    name: str = param("uturn", choices=("uturn",), doc="task folder")
    scene: UTurnSceneConfig = field(default_factory=UTurnSceneConfig)
    reward: UTurnRewardConfig = field(default_factory=UTurnRewardConfig)
    start: UTurnStartConfig = field(default_factory=UTurnStartConfig)
    observe_route: bool = param(
        False,
        doc="6 more observation features: the pull point P and the turning point T in the "
        "tractor frame (/ sensor scale) and the branch axis direction (sin, cos) relative to "
        "the tractor heading: where the manoeuvre goes, which 16 LiDAR beams show only coarsely",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task")


def turning_point(info: Mapping[str, Tensor], depth_fraction: float) -> Tensor:
    """The turning point ``T [N, 2]`` [m]: on the branch axis, ``depth_fraction`` of the branch
    depth beyond the branch-side curb line (world coordinates).

    Args:
        info: scene metadata ``{key: [N]}`` (``road_width``, ``branch_depth``, ``branch_side``,
            ``branch_angle`` and the frame ``mouth_x``, ``mouth_y``, ``road_heading``).
    """
    a, side = info["branch_angle"], info["branch_side"]
    depth = depth_fraction * info["branch_depth"]
    # mouth centre on the curb line, then along b = (cos a, side sin a) to `depth` off the curb
    local = torch.stack((depth * a.cos() / a.sin(), side * (0.5 * info["road_width"] + depth)), -1)
    mouth = torch.stack((info["mouth_x"], info["mouth_y"]), -1)
    return rotate(local, info["road_heading"]) + mouth


class UTurnTask(PoseGoal, Task):
    """Turnaround on a narrow road through a side branch; see the module docstring."""

    name = "uturn"
    config_class = UTurnConfig
    reverse = True
    num_extras = 3
    category_dims = (
        CategoryDim(
            "start",
            "start_kind",
            names=("road", "past branch", "on the arc", "in branch", "pulling past"),
        ),
        CategoryDim("branch side", "branch_left", names=("right", "left")),
        CategoryDim("dead end", "dead_end", names=("open road", "dead end")),
        CategoryDim("road width [m]", "road_width", edges=(9.0, 10.0, 11.0, 12.0)),
        CategoryDim("branch width [m]", "branch_width", edges=(10.0, 11.5, 13.0)),
        CategoryDim(
            "branch angle [deg]",
            "branch_angle",
            edges=(75.0, 85.0, 95.0, 105.0),
            scale=180.0 / math.pi,
        ),
        CategoryDim("truck length [m]", "truck_length", edges=(12.0, 15.0, 18.0, 21.0)),
    )
    #: ``turn_point [N, 2]`` (route shaping's ``T``), ``start_heading [N]`` (``theta_0``),
    #: ``pull_point [N, 2]`` (``P``, where the truck has pulled far enough past the branch) and
    #: ``pulled [N]`` (1.0 once the rear axle has been level with ``P``, else 0.0) and
    #: ``turn_axis [N, 2]`` (unit vector along the branch axis into the branch;
    #: ``observe_route``).
    extra_state_keys = ("turn_point", "start_heading", "pull_point", "pulled", "turn_axis")

    def __init__(self, cfg: EnvConfig) -> None:
        super().__init__(cfg)
        if self.cfg.task.observe_route:
            self.num_extras = 9  # P and T (x, y each), branch axis (sin, cos)

    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        from tensordict import TensorDict

        params = self.sample_params(m, rng, device)
        sc = generate_uturn_scenes(self.cfg.task.scene, params, rng, device)
        scene = {
            "start": sc.start,
            "goal": sc.goal,
            "segments": sc.segments,
            "mask": sc.mask,
            "kind": sc.kind,
        }
        state = self.initial_state(params, scene, device)
        state[INFO_STATE_KEY] = TensorDict(sc.info, batch_size=[m], device=device)
        return self.complete_state(state)

    def complete_state(self, state: TensorDict) -> TensorDict:
        """Add ``start_heading`` (the current tractor heading), ``turn_point``, ``pull_point``
        and ``pulled`` where missing.

        ``turn_point`` and ``pull_point`` need the scene metadata (``state["route"]``): ``P`` is
        the tractor rear axle of the start curriculum's first path pose
        (:func:`reverse_path`, ``sigma = 0``: the trailer ``past_gap`` beyond the mouth). A state
        built by hand without it gets the midpoint of the start and the goal as ``T``, and
        counts as pulled past (route shaping then degrades to a detour through ``T``).
        """
        keys = state.keys()
        if "start_heading" not in keys:
            state["start_heading"] = state["pose"][:, 2].clone()
        if "turn_point" not in keys:
            if INFO_STATE_KEY in keys:
                info = state[INFO_STATE_KEY]
                state["turn_point"] = turning_point(
                    {k: info[k] for k in INFO_KEYS}, self.cfg.task.reward.turn_depth
                )
            else:
                state["turn_point"] = 0.5 * (state["pose"][:, :2] + state["goal"][:, :2])
        if "pull_point" not in keys:
            if INFO_STATE_KEY in keys and "place_draw" in state[INFO_STATE_KEY].keys():
                path = reverse_path(state[INFO_STATE_KEY], state["params"], self.cfg.task.start)
                state["pull_point"] = path.pose(torch.zeros_like(state["start_heading"]))[:, :2]
            else:
                state["pull_point"] = state["turn_point"].clone()
                state["pulled"] = torch.ones_like(state["start_heading"])
        if "pulled" not in keys:
            state["pulled"] = pulled_past(state["pose"], state).to(state["start_heading"])
        if "turn_axis" not in keys:
            if INFO_STATE_KEY in keys:
                info = state[INFO_STATE_KEY]
                a, side = info["branch_angle"], info["branch_side"]
                local = torch.stack((a.cos(), side * a.sin()), -1)
                state["turn_axis"] = rotate(local, info["road_heading"])
            else:  # by hand: from the start towards T
                rel = state["turn_point"] - state["pose"][:, :2]
                state["turn_axis"] = rel / rel.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        return state

    def step(self, s: dict[str, Any], action: Tensor) -> dict[str, Tensor]:
        """The shared step; ``pulled`` latches once the rear axle is level with ``P`` (a state
        without ``pulled``, built by hand for the kinematics alone, steps without it)."""
        new = super().step(s, action)
        if "pulled" not in s:
            return new
        ahead = pulled_past(new["pose"], s).to(s["pulled"])
        new["pulled"] = torch.maximum(s["pulled"], ahead)
        return new

    def on_reset(self, state: TensorDict, difficulty: Tensor) -> TensorDict:
        """The start curriculum (``env.task.start``):
        :func:`~truckrl.tasks.uturn.start.curriculum_start` (the reference path, the forward leg,
        the schedule and the free-by-test rule). A state without the curriculum's metadata
        (built by hand) is returned unchanged."""
        cur = self.cfg.task.start
        if not cur.enabled or INFO_STATE_KEY not in state.keys():
            return state
        info = state[INFO_STATE_KEY]
        if "stage_draw" not in info.keys():
            return state
        return curriculum_start(state, info, difficulty, cur, self.errors)

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        w = self.cfg.task.reward
        if w.shaping == "route":
            progress = route_to_go(before) - route_to_go(after)
        else:
            progress = before["pos_error"] - after["pos_error"]
        return pose_reward_terms(w, before, after, flags, progress)

    def observation_extras(self, s: dict[str, Any]) -> Tensor:
        """``[N, 3]`` (``[N, 9]`` with ``env.task.observe_route``): signed speed /
        ``max_reverse_speed``; ``max_reverse_speed`` mapped from ``env.vehicle.max_reverse_speed``
        to [-1, 1] (0 for a range of one value); the phase ``pulled`` (1 once the truck has
        pulled far enough past the branch, where route shaping's distance to go changes form).
        With ``observe_route``: then ``P`` and ``T`` in the tractor frame (x, y each, / the
        sensor scale) and the sine and cosine of the branch axis heading minus the tractor
        heading."""
        p = s["params"]
        v_rev = p["max_reverse_speed"]
        lo, hi = self.cfg.vehicle.max_reverse_speed
        span = hi - lo
        norm = (v_rev - 0.5 * (lo + hi)) * (2.0 / span) if span > 0 else v_rev * 0.0
        extras = torch.stack((s["speed"] / v_rev, norm, s["pulled"]), -1)
        if not self.cfg.task.observe_route:
            return extras
        pose = s["pose"]
        theta = pose[:, 2]
        points = torch.stack((s["pull_point"], s["turn_point"]), 1)  # [N, 2, 2]
        local = to_local(points, pose[:, :2], theta) / SENSOR_SCALE
        axis = torch.atan2(s["turn_axis"][:, 1], s["turn_axis"][:, 0]) - theta
        return torch.cat((extras, local.flatten(1), axis.sin()[:, None], axis.cos()[:, None]), -1)


def route_to_go(s: dict[str, Any]) -> Tensor:
    """Route shaping's distance to go ``[N]`` [m] (module doc): while the tractor faces the
    start direction, via the pull point ``P`` (until ``pulled``) and the turning point ``T``;
    straight to the goal once it faces back; blended by ``w = (1 + cos(theta - theta_0)) / 2``.
    A state without ``pulled`` counts as pulled past."""
    p, g, t = s["pose"][:, :2], s["goal"][:, :2], s["turn_point"]
    w = 0.5 * (1.0 + torch.cos(s["pose"][:, 2] - s["start_heading"]))
    via = (p - t).norm(dim=-1) + (t - g).norm(dim=-1)
    pulled = s.get("pulled")
    if pulled is not None:
        pp = s["pull_point"]
        before_pull = (p - pp).norm(dim=-1) + (pp - t).norm(dim=-1) + (t - g).norm(dim=-1)
        via = torch.where(pulled > 0.5, via, before_pull)
    return w * via + (1.0 - w) * (p - g).norm(dim=-1)


TASK = UTurnTask
