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
from truckrl.sim.collision import truck_collides, widened
from truckrl.sim.geometry import rotate, to_local, wrap_angle
from truckrl.sim.vehicle import truck_extents
from truckrl.tasks.base import Task
from truckrl.tasks.config import SENSOR_SCALE, TaskConfig
from truckrl.tasks.goals import POSE_ERRORS, pose_errors, pose_success
from truckrl.tasks.schema import CategoryDim
from truckrl.tasks.uturn.scene import (
    INFO_KEYS,
    START_ARC,
    START_BRANCH,
    START_LEG,
    START_PAST,
    START_ROAD,
    UTurnSceneConfig,
    generate_uturn_scenes,
)

if TYPE_CHECKING:
    from tensordict import TensorDict

    from truckrl.tasks.config import EnvConfig

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

    def __post_init__(self) -> None:
        validate(self, "env.task.reward")


@dataclass
class UTurnStartConfig:
    """Start curriculum (``env.task.start.*``; :meth:`UTurnTask.on_reset`): early in training the
    truck starts part-way through the manoeuvre, somewhere on a reference path of its trailer
    axle that reverses from the road past the branch into it."""

    enabled: bool = param(True, doc="false: every episode starts where the generator put it")
    stage_difficulty: tuple[float, float] = param(
        (0.0, 4.0),
        lo=0.0,
        hi=30.0,
        unit="-",
        doc="difficulties over which starts move from the end of the reference path (in the "
        "branch) back along it to the generator's road start (all, from the second on)",
    )
    branch_end_gap: tuple[float, float] = param(
        (0.5, 2.0),
        lo=0.0,
        hi=50.0,
        unit="m",
        doc="end of the path: the trailer's rear corners this far short of the branch end wall "
        "(drawn per episode)",
    )
    past_gap: tuple[float, float] = param(
        (1.0, 6.0),
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="start of the path: the trailer rear this far beyond the mouth's far chamfer (drawn "
        "per episode; at most the room before a dead end less 1 m)",
    )
    arc_radius: tuple[float, float] = param(
        (9.0, 13.0),
        lo=1.0,
        hi=100.0,
        unit="m",
        doc="radius of the path's arc from the road into the branch axis (drawn per episode)",
    )
    clearance: float = param(
        0.2,
        lo=0.0,
        hi=5.0,
        unit="m",
        doc="a start on the path keeps this much room to every segment, else it moves further "
        "along the path towards the branch",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.start")


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


class UTurnTask(Task):
    """Turnaround on a narrow road through a side branch; see the module docstring."""

    name = "uturn"
    config_class = UTurnConfig
    reverse = True
    error_quantities = POSE_ERRORS
    reward_keys = (
        "r_progress",
        "r_tractor_heading",
        "r_trailer_heading",
        "r_time",
        "r_success",
        "r_collision",
        "r_timeout",
    )
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
        """The start curriculum (``env.task.start``).

        **The reference path** (:func:`reverse_path`) of the trailer axle: from a pose on the
        road centreline past the branch (the trailer rear ``past_gap`` beyond the mouth's far
        chamfer), straight back, an arc of ``arc_radius`` onto the branch axis, and up the axis
        until the trailer's rear corners are ``branch_end_gap`` short of the end wall. A start at
        path fraction ``sigma`` (by arc length) is the truck at rest with its trailer axle there,
        the trailer facing against the direction of travel along the path (on the road at
        ``sigma = 0`` it faces the start heading, at ``sigma = 1`` out of the branch); straight
        off the arc, and on the arc articulated as in the steady turn round the arc's centre
        (capped at :data:`ARC_ARTICULATION` of ``max_articulation``).

        **The forward leg** before it: from the road start, straight ahead to the pull point
        ``P`` (the tractor rear axle of the path's first pose), where the truck has pulled far
        enough past the branch to reverse into it.

        **The schedule.** With ``p = clamp((d - d0) / (d1 - d0), 0, 1)`` at difficulty ``d``
        (``stage_difficulty = (d0, d1)``) and the episode's ``stage_draw`` ``r``,
        ``z = 3 p + r``: where ``z < 2`` the truck starts on the path at ``sigma = 1 - z / 2``;
        where ``2 <= z < 3`` on the forward leg, at rest facing the start heading, ``z - 2`` of
        the way from ``P`` back to the road start; otherwise at the generator's road start. So
        difficulty ``d0`` draws ``sigma`` in ``(1/2, 1]``, the window slides back along the
        path and the leg, and from ``d1`` on every start is the road start.

        **Free by test.** A path start whose truck, widened by ``clearance``, touches a segment
        moves on along the path (eight evenly spaced fallbacks to ``sigma = 1``; where none is
        free, the road start). The end pose, straight on the branch axis with
        ``branch_side_clearance`` each side, is free in every default scene. The tests check
        every kind of start on 10,000 scenes with independent geometry.

        ``start_heading`` (route shaping's ``theta_0``) keeps the road heading, so the shaping
        is one potential for every start; ``pulled`` is 1 on the path and on the leg from ``P``
        on. ``info["start_kind"]`` records road / past branch / on the arc / in the branch /
        pulling past (:data:`~truckrl.tasks.uturn.scene.START_ROAD` ...) and
        ``info["start_sigma"]`` the path fraction (on the leg minus its fraction, -1 on the
        road). A state without the curriculum's metadata (built by hand) is returned unchanged.
        """
        cur = self.cfg.task.start
        if not cur.enabled or INFO_STATE_KEY not in state.keys():
            return state
        info = state[INFO_STATE_KEY]
        if "stage_draw" not in info.keys():
            return state
        pose, params = state["pose"], state["params"]
        d = difficulty.to(pose.dtype)
        d0, d1 = cur.stage_difficulty
        prog = ((d - d0) / (d1 - d0)).clamp(0.0, 1.0) if d1 > d0 else (d >= d0).to(d)
        z = 3.0 * prog + info["stage_draw"]
        on_path = z < 2.0
        on_leg = (z >= 2.0) & (z < 3.0)
        sigma = (1.0 - 0.5 * z).clamp(0.0, 1.0)

        path = reverse_path(info, params, cur)
        k = 9  # the drawn sigma, then evenly on to 1
        steps = torch.linspace(0.0, 1.0, k, device=pose.device)
        sig = sigma[None] + (1.0 - sigma[None]) * steps[:, None]  # [k, m]
        cand = torch.stack([path.pose(sg) for sg in sig.unbind(0)])  # [k, m, 4]
        wide = widened(params, cur.clearance)
        m = pose.shape[0]
        hit = truck_collides(
            cand.reshape(k * m, 4),
            {key: v.repeat(k) for key, v in wide.items()},
            state["segments"].repeat(k, 1, 1),
            state["mask"].repeat(k, 1),
        ).view(k, m)
        free = ~hit
        on_path = on_path & free.any(0)  # none free (never seen): the road start
        first = free.to(torch.int8).argmax(0)  # first free candidate [m]
        moved = cand.gather(0, first.view(1, m, 1).expand(1, m, 4))[0]
        sigma = sig.gather(0, first.view(1, m))[0]
        # the forward leg: straight, facing the start heading, (z - 2) of the way from P back
        # to the road start (both on the straight road, the truck in its half: free)
        frac = (z - 2.0).clamp(0.0, 1.0)
        pp = state["pull_point"]
        leg_xy = pp + frac[:, None] * (pose[:, :2] - pp)
        leg = torch.cat((leg_xy, pose[:, 2:3], torch.zeros_like(frac)[:, None]), -1)

        new_pose = torch.where(on_path[:, None], moved, torch.where(on_leg[:, None], leg, pose))
        state["pose"] = new_pose
        state.update(self.errors(state))
        state["pulled"] = (on_path | pulled_past(new_pose, state)).to(state["pulled"])
        kind = torch.where(
            sigma < path.arc_from,
            START_PAST,
            torch.where(sigma < path.arc_to, START_ARC, START_BRANCH),
        )
        kind = torch.where(on_path, kind, torch.where(on_leg, START_LEG, START_ROAD))
        info["start_kind"] = kind.to(info["start_kind"])
        info["start_sigma"] = torch.where(on_path, sigma, torch.where(on_leg, -frac, -1.0))
        return state

    def errors(self, s: dict[str, Any]) -> dict[str, Tensor]:
        """:func:`~truckrl.tasks.goals.pose_errors`."""
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


def pulled_past(pose: Tensor, s: Mapping[str, Any]) -> Tensor:
    """``[N]`` bool: the tractor rear axle of ``pose [N, 4]`` is level with or beyond the pull
    point ``s["pull_point"]`` along the start heading ``s["start_heading"]``."""
    h = s["start_heading"]
    ahead = (pose[:, 0] - s["pull_point"][:, 0]) * h.cos() + (
        pose[:, 1] - s["pull_point"][:, 1]
    ) * h.sin()
    return ahead >= 0.0


@dataclass
class ReversePath:
    """The start curriculum's reference path of the trailer axle, per scene: built in the
    scene's local frame with the branch mirrored to the left (``side``), posed in the world
    through ``frame``.

    Three pieces by arc length: straight back along the road centreline from ``p0`` (motion
    heading ``road + pi``), an arc of radius ``radius`` turning onto the branch axis, then up
    the axis. ``arc_from`` / ``arc_to`` ``[N]`` are the path fractions where the arc starts and
    ends. :meth:`pose` gives the truck whose trailer axle is at a fraction: straight off the
    arc, in the steady turn on it.
    """

    p0: Tensor  # [N, 2] start of the path, local left-branch frame [m]
    back: Tensor  # [N] length of the straight piece [m]
    radius: Tensor  # [N] [m]
    turn: Tensor  # [N] signed turn of the motion heading over the arc [rad]
    up: Tensor  # [N] length along the branch axis [m]
    side: Tensor  # [N] +1 left branch, -1 right
    frame: Tensor  # [N, 3] mouth centre x, y and road heading (local -> world)
    trailer_wheelbase: Tensor  # [N] trailer axle to kingpin [m]
    kingpin_offset: Tensor  # [N] kingpin behind the tractor rear axle [m]
    max_phi: Tensor  # [N] articulation cap on the arc [rad]

    @property
    def length(self) -> Tensor:
        return self.back + self.radius * self.turn.abs() + self.up

    @property
    def arc_from(self) -> Tensor:
        return self.back / self.length

    @property
    def arc_to(self) -> Tensor:
        return (self.back + self.radius * self.turn.abs()) / self.length

    def pose(self, sigma: Tensor) -> Tensor:
        """``[N, 4]`` world pose ``(x, y, theta, phi)`` of the truck whose trailer axle is at path
        fraction ``sigma [N]``, the trailer facing against the direction of travel along the
        path: articulation 0 off the arc, the steady turn (capped at ``max_phi``) on it."""
        s = sigma * self.length
        arc_len = self.radius * self.turn.abs()
        # left-branch local frame (right branches mirrored by side at the end)
        s1 = s.clamp(max=self.back)
        s2 = (s - self.back).clamp(0.0, None).minimum(arc_len)
        s3 = (s - self.back - arc_len).clamp(0.0, None)
        a0 = torch.full_like(s, math.pi)  # motion heading on the straight piece
        start_arc = self.p0 + torch.stack((-self.back, torch.zeros_like(s)), -1)
        frac = s2 / arc_len.clamp_min(1e-6)
        ang = a0 + self.turn * frac  # motion heading on the arc (turn < 0: clockwise)
        centre = start_arc + self.radius[:, None] * torch.stack(
            (torch.zeros_like(s), torch.ones_like(s)), -1
        )
        on_arc = centre + self.radius[:, None] * torch.stack((-ang.sin(), ang.cos()), -1)
        end_ang = a0 + self.turn
        up_dir = torch.stack((end_ang.cos(), end_ang.sin()), -1)
        xy = torch.where(
            (s <= self.back)[:, None],
            self.p0 + torch.stack((-s1, torch.zeros_like(s)), -1),
            on_arc + s3[:, None] * up_dir,
        )
        motion = torch.where(s <= self.back, a0, torch.where(s3 > 0, end_ang, ang))
        psi = motion + math.pi  # the trailer faces against its travel (reversing)
        # tractor: straight behind the hitch off the arc; on the arc the steady turn, every
        # axle circling the arc's centre C, so the rear axle X = K + a u(theta) (K the kingpin)
        # moves perpendicular to X - C: (K - C) . u(theta) = -a
        u_psi = torch.stack((psi.cos(), psi.sin()), -1)
        kingpin = xy + self.trailer_wheelbase[:, None] * u_psi
        rel = kingpin - centre
        beta = torch.atan2(rel[:, 1], rel[:, 0])
        spread = torch.acos((-self.kingpin_offset / rel.norm(dim=-1)).clamp(-1.0, 1.0))
        t1, t2 = beta + spread, beta - spread
        near = wrap_angle(t1 - psi).abs() <= wrap_angle(t2 - psi).abs()
        steady = torch.where(near, t1, t2)
        phi = wrap_angle(psi - steady).clamp(-self.max_phi, self.max_phi)
        phi = torch.where((s > self.back) & (s3 <= 0), phi, torch.zeros_like(phi))
        theta = psi - phi
        axle = kingpin + self.kingpin_offset[:, None] * torch.stack((theta.cos(), theta.sin()), -1)
        local_xy = torch.stack((axle[:, 0], self.side * axle[:, 1]), -1)
        world = rotate(local_xy, self.frame[:, 2]) + self.frame[:, :2]
        h = wrap_angle(self.side * theta + self.frame[:, 2])
        return torch.stack((world[:, 0], world[:, 1], h, self.side * phi), -1)


#: Cap of the steady-turn articulation of a start on the arc, as a share of ``max_articulation``
#: (a start at the stop would be a jack-knife at step 0).
ARC_ARTICULATION = 0.8


def reverse_path(
    info: Mapping[str, Tensor], params: Mapping[str, Tensor], cur: UTurnStartConfig
) -> ReversePath:
    """The start curriculum's :class:`ReversePath` of each scene (:meth:`UTurnTask.on_reset`):
    ``place_draw`` fixes the arc radius, the past-branch gap and the branch end gap."""
    front, rear, half_w = truck_extents(params)
    l_axle = params["kingpin_offset"] + params["trailer_wheelbase"]  # rear axle to trailer axle
    overhang = rear - l_axle  # trailer axle to the trailer rear
    a, half = info["branch_angle"], 0.5 * info["road_width"]
    sin_a, cos_a = a.sin(), a.cos()
    place = info["place_draw"]

    def draw(bounds: tuple[float, float]) -> Tensor:
        return bounds[0] + (bounds[1] - bounds[0]) * place

    # start: trailer rear past_gap beyond the far chamfer's foot, the front 1 m short of x_far
    rear_x = 0.5 * info["branch_width"] / sin_a + info["mouth_chamfer"]
    room = info["x_far"] - rear_x - (front + rear) - 1.0
    gap = torch.minimum(draw(cur.past_gap), room).clamp_min(0.0)
    x0 = rear_x + gap + overhang  # the trailer axle
    # arc (left-branch frame): motion heading pi -> a, clockwise by pi - a, from (x_arc, 0)
    radius = draw(cur.arc_radius)
    turn = a - math.pi
    dy = radius * (1.0 - torch.cos(turn))
    x_end = (dy - half) * cos_a / sin_a  # the arc ends on the branch axis
    x_arc = x_end - radius * torch.sin(turn)
    back = (x0 - x_arc).clamp_min(0.0)
    p0 = torch.stack((torch.maximum(x0, x_arc), torch.zeros_like(x0)), -1)
    # end: the trailer's rear corners branch_end_gap short of the end wall (skewed by pi/2 - a)
    skew = half_w * (cos_a / sin_a).abs()
    depth_axle = (info["branch_depth"] - draw(cur.branch_end_gap) - skew) / sin_a - overhang
    up = (depth_axle - (dy - half) / sin_a).clamp_min(0.0)
    frame = torch.stack((info["mouth_x"], info["mouth_y"], info["road_heading"]), -1)
    return ReversePath(
        p0,
        back,
        radius,
        turn,
        up,
        info["branch_side"],
        frame,
        params["trailer_wheelbase"],
        params["kingpin_offset"],
        ARC_ARTICULATION * params["max_articulation"],
    )


TASK = UTurnTask
