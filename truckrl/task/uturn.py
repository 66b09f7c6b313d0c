"""Task ``uturn``: turn an articulated truck round on a road too narrow for a forward loop.

* Episodes: :func:`truckrl.sim.uturn_scene.generate_uturn_scenes` (a narrow straight road with a
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
  towards the goal (heading still wrong) earns it, a dead end. ``route`` (default) measures
  progress with the potential

      to_go = w * (|p - T| + |T - g|) + (1 - w) * |p - g|,   w = (1 + cos(theta - theta_0)) / 2

  with ``p`` the tractor rear axle, ``g`` the goal, ``T`` the **turning point** (on the branch
  axis, ``turn_depth`` of the branch depth beyond the curb: :func:`turning_point`), ``theta`` the
  tractor heading
  and ``theta_0`` the start heading. While the truck still faces the way it started (``w = 1``)
  the distance to go runs via the branch; once it faces back (``w = 0``) it is the straight
  distance to the goal; in between (in the branch) it blends. The heading terms stay measured
  to the goal heading: turning round is what the task asks, wherever it happens. Being a
  function of the state, the shaping is potential-based: the optimal policies are those of the
  sparse terminal rewards, up to discounting. It still charges the pull past the branch (about
  a truck length away from ``T``), the one part of the route it does not model.
* Observation extras (2): signed speed / ``max_reverse_speed`` (below -1 never, < 0 reversing)
  and ``max_reverse_speed`` mapped from its configured range to [-1, 1].
* Scene metadata: ``state["route"]`` holds the generator's per-episode ``info``
  (:data:`~truckrl.sim.uturn_scene.INFO_KEYS`); :attr:`UTurnTask.category_dims` bins evaluation
  by branch side, dead end, road width, branch width, branch angle and truck length.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.sim.geometry import rotate, wrap_angle
from truckrl.sim.uturn_scene import (
    INFO_KEYS,
    START_BRANCH,
    START_PAST,
    UTurnSceneConfig,
    generate_uturn_scenes,
)
from truckrl.sim.validation import param, validate
from truckrl.sim.vehicle import truck_extents
from truckrl.task.base import Task
from truckrl.task.config import TaskConfig
from truckrl.task.intersection import IntersectionTask, pose_errors, pose_success
from truckrl.task.schema import CategoryDim

if TYPE_CHECKING:
    from tensordict import TensorDict

#: State key of the per-episode scene metadata ``{key: [N]}`` (:data:`INFO_KEYS`): the key every
#: task records its scene metadata under (evaluation bins episodes by it, ``category_dims``).
INFO_STATE_KEY = "route"


@dataclass
class UTurnRewardConfig:
    """Reward weights (the paper's values) and the progress shaping (module doc)."""

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
    shaping: str = param(
        "route",
        choices=("goal", "route"),
        doc="progress measured straight to the goal (paper) or via the branch's turning point "
        "(module doc)",
    )
    turn_depth: float = param(
        0.5,
        lo=0.0,
        hi=1.0,
        unit="branch depths",
        doc="turning point on the branch axis, this fraction of the branch depth from the curb",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.reward")


@dataclass
class UTurnStartConfig:
    """Start curriculum (``env.task.start.*``; :meth:`UTurnTask.on_reset`): early in training the
    truck starts part-way through the manoeuvre, reversed into the branch or pulled past it."""

    enabled: bool = param(True, doc="false: every episode starts where the generator put it")
    stage_difficulty: tuple[float, float] = param(
        (0.0, 4.0),
        lo=0.0,
        hi=30.0,
        unit="-",
        doc="difficulties over which starts move from in the branch (all, at the first) via "
        "past the branch to the generator's road start (all, from the second on); linear between",
    )
    branch_end_gap: tuple[float, float] = param(
        (0.5, 2.0),
        lo=0.0,
        hi=50.0,
        unit="m",
        doc="in-branch start: the trailer's rear corners this far short of the branch end wall "
        "(drawn per episode)",
    )
    past_gap: tuple[float, float] = param(
        (1.0, 6.0),
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="past-the-branch start: the trailer rear this far beyond the mouth's far chamfer "
        "(drawn per episode; at most the room before a dead end less 1 m)",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.start")


@dataclass
class UTurnConfig(TaskConfig):
    """Config of the uturn task: scene rules, reward weights and the start curriculum."""

    name: str = param("uturn", choices=("uturn",), doc="task module")
    scene: UTurnSceneConfig = field(default_factory=UTurnSceneConfig)
    reward: UTurnRewardConfig = field(default_factory=UTurnRewardConfig)
    start: UTurnStartConfig = field(default_factory=UTurnStartConfig)

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


class UTurnTask(Task):
    """Turnaround on a narrow road through a side branch; see the module docstring."""

    name = "uturn"
    config_class = UTurnConfig
    reverse = True
    error_quantities = IntersectionTask.error_quantities
    reward_keys = (
        "r_progress",
        "r_tractor_heading",
        "r_trailer_heading",
        "r_time",
        "r_success",
        "r_collision",
        "r_timeout",
    )
    num_extras = 2
    category_dims = (
        CategoryDim("start", "start_kind", names=("road", "past branch", "in branch")),
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
    #: ``turn_point [N, 2]`` (route shaping's ``T``) and ``start_heading [N]`` (``theta_0``).
    extra_state_keys = ("turn_point", "start_heading")

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
        """Add ``start_heading`` (the current tractor heading) and ``turn_point`` where missing.

        ``turn_point`` needs the scene metadata (``state["route"]``); a state built by hand
        without it gets the midpoint of the start and the goal (route shaping then degrades to
        a detour through that point).
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
        return state

    def on_reset(self, state: TensorDict, difficulty: Tensor) -> TensorDict:
        """The start curriculum (``env.task.start``): each episode's start kind follows from its
        difficulty ``d`` and its ``stage_draw`` ``r``. With ``u = 2 clamp((d - d0) / (d1 - d0),
        0, 1)`` (``stage_difficulty = (d0, d1)``) the truck starts

        * **in the branch** where ``u + r < 1``: reversed in along the branch axis, facing out,
          the trailer's rear corners ``branch_end_gap`` short of the end wall (less where the
          front corners would otherwise stick out of the branch);
        * **past the branch** where ``1 <= u + r < 2``: on the road centreline facing the start
          heading, the trailer rear ``past_gap`` beyond the mouth's far chamfer (and the front
          bumper at least 1 m short of a dead end);
        * **on the road** (the generator's start) otherwise.

        Both moved starts are at rest, articulation 0, and collision-free by construction (the
        truck straight on the branch axis with ``branch_side_clearance`` each side; on the
        straight road beyond the mouth, the road wider than the truck), checked on 10,000 scenes
        by the tests. ``start_heading`` (route shaping's ``theta_0``) keeps the road heading,
        so the shaping stays one potential for every start. A state without the curriculum's
        metadata (built by hand) is returned unchanged.
        """
        cur = self.cfg.task.start
        if not cur.enabled or INFO_STATE_KEY not in state.keys():
            return state
        info = state[INFO_STATE_KEY]
        if "stage_draw" not in info.keys():
            return state
        pose = state["pose"]
        d = difficulty.to(pose.dtype)
        d0, d1 = cur.stage_difficulty
        u = 2.0 * ((d - d0) / (d1 - d0)).clamp(0.0, 1.0) if d1 > d0 else 2.0 * (d >= d0).to(d)
        v = u + info["stage_draw"]
        in_branch, past = v < 1.0, (v >= 1.0) & (v < 2.0)

        front, rear, half_w = truck_extents(state["params"])
        a, side, half = info["branch_angle"], info["branch_side"], 0.5 * info["road_width"]
        sin_a, cos_a = a.sin(), a.cos()
        place = info["place_draw"]
        # in the branch: the rear-centre's depth from the curb line leaves end_gap to the end
        # wall at the rear corners (the end wall runs along the road, skew to the axis by
        # pi/2 - a, so a corner reaches half_w |cot a| deeper than the centre)
        g0, g1 = cur.branch_end_gap
        skew = half_w * (cos_a / sin_a).abs()
        depth = info["branch_depth"] - (g0 + (g1 - g0) * place) - skew
        t = depth / sin_a - rear  # rear axle along the branch axis from the mouth centre
        # ... but the front corners stay beyond the curb line (a gap drawn too wide shrinks)
        t = torch.maximum(t, front + skew / sin_a)
        branch_pose = torch.stack(
            (t * cos_a, side * (half + t * sin_a), torch.atan2(-side * sin_a, -cos_a)), -1
        )
        # past the branch: the trailer rear gap beyond the far chamfer's foot on the curb
        h = 0.5 * info["branch_width"] / sin_a
        rear_x = h + info["mouth_chamfer"]
        p0, p1 = cur.past_gap
        room = info["x_far"] - rear_x - (front + rear) - 1.0
        gap = torch.minimum(p0 + (p1 - p0) * place, room).clamp_min(0.0)
        zero = torch.zeros_like(gap)
        past_pose = torch.stack((rear_x + gap + rear, zero, zero), -1)

        local = torch.where(in_branch[:, None], branch_pose, past_pose)
        heading = info["road_heading"]
        xy = rotate(local[:, :2], heading) + torch.stack((info["mouth_x"], info["mouth_y"]), -1)
        moved = torch.cat((xy, wrap_angle(local[:, 2:] + heading[:, None]), zero[:, None]), -1)
        move = in_branch | past
        state["pose"] = torch.where(move[:, None], moved, pose)
        state.update(self.errors(state))
        kind = torch.where(in_branch, START_BRANCH, START_PAST)
        info["start_kind"] = torch.where(move, kind.to(info["start_kind"]), info["start_kind"])
        return state

    def errors(self, s: dict[str, Any]) -> dict[str, Tensor]:
        """As the intersection task (:func:`~truckrl.task.intersection.pose_errors`)."""
        return pose_errors(s)

    def success(self, err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
        return pose_success(err, tol_pos, tol_ang)

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        w = self.cfg.task.reward
        zero = torch.zeros_like(after["pos_error"])
        failed = flags["collision"] | flags["jackknife"]
        if w.shaping == "route":
            progress = route_to_go(before) - route_to_go(after)
        else:
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

    def observation_extras(self, s: dict[str, Any]) -> Tensor:
        """``[N, 2]``: signed speed / ``max_reverse_speed``; ``max_reverse_speed`` mapped from
        ``env.vehicle.max_reverse_speed`` to [-1, 1] (0 for a range of one value)."""
        p = s["params"]
        v_rev = p["max_reverse_speed"]
        lo, hi = self.cfg.vehicle.max_reverse_speed
        span = hi - lo
        norm = (v_rev - 0.5 * (lo + hi)) * (2.0 / span) if span > 0 else v_rev * 0.0
        return torch.stack((s["speed"] / v_rev, norm), -1)


def route_to_go(s: dict[str, Any]) -> Tensor:
    """Route shaping's distance to go ``[N]`` [m] (module doc): via the turning point while the
    tractor faces the start direction, straight to the goal once it faces back, blended by
    ``w = (1 + cos(theta - theta_0)) / 2``."""
    p, g, t = s["pose"][:, :2], s["goal"][:, :2], s["turn_point"]
    w = 0.5 * (1.0 + torch.cos(s["pose"][:, 2] - s["start_heading"]))
    via = (p - t).norm(dim=-1) + (t - g).norm(dim=-1)
    return w * via + (1.0 - w) * (p - g).norm(dim=-1)


TASK = UTurnTask
