"""Batched random scenes: one straight road or two crossing roads, parked obstacles, start and goal.

Every scene of a batch is drawn independently; all randomness comes from one ``torch.Generator``
(same seed -> same scenes, on its device). Everything is emitted as line segments
``[N, E, 4]`` with a validity mask, ``E = 8 + 4 * max_obstacles`` fixed by the config.

Layout (all lengths in metres, angles in radians)
-------------------------------------------------
* **Roads and curbs** (:mod:`truckrl.sim.roads`): both roads pass through the scene centre ``P``
  (uniform in a square of half-side ``center_jitter`` around the origin) and span
  ``+-half_extent`` along ``d_r``; road 1 (crossing scenes only) is road 0 turned by the crossing
  angle. At a crossing the 8 curb segments meet at the corners of the intersection parallelogram
  (``intersection``, counter-clockwise); a straight road has 2, the other 6 slots are padding.
* **Arms.** A crossing has four arms: road ``r`` on side ``sigma = +-1`` of ``P``. ``e_r`` is the
  extent of the parallelogram along ``d_r`` (largest ``|(corner - P) . d_r|``).

Start and goal (the reachability rule)
--------------------------------------
Poses are the tractor rear-axle centre with articulation 0, driving on the right-hand half of the
road: the curb-side edge of the wider body sits ``shoulder_gap`` metres from the curb (the truck
stays in its half of the road and fully on it).

* Straight road: start and goal drive the same way; the goal lies *ahead* of the start, and
  their straight-line distance is drawn from ``goal_distance``.
* Crossing: the start lies on a random arm heading *towards* ``P`` (approach arm); the goal lies on
  one of the three other arms heading *away* from ``P`` (straight on, or a turn either way; never
  a U-turn). Both footprints (tractor and trailer) stay at least ``pose_intersection_margin``
  beyond the parallelogram along their road. The goal's distance along its arm is solved so that
  the start-goal distance is a draw from ``goal_distance``; draws that fall outside the arm are
  resampled for ``rounds`` rounds, and a crossing scene still without a valid pair becomes a
  straight-road scene (valid by construction).
* Every start and goal rear axle stays ``curb_reach`` metres (the LiDAR range) inside the curb ends.
* Left turns leave the trailer room to straighten (``left_turn_exit``; the room is
  :func:`~truckrl.sim.roads.turn_exit_room`): the goal lies at least ``(tan(turn / 2) +
  left_turn_exit)`` trailer wheelbases past the corner of the start and goal lanes; a pair that
  does not is rejected like one that does not fit its arm. Without it (``left_turn_exit = 0``)
  some sharp left turns of long trailers leave no room to straighten: neither the planner nor a
  trained policy solves them at difficulty 6. Right turns need no such rule.

Each scene records its **route** (``SceneBatch.route``): :data:`ROUTE_STRAIGHT_ROAD` (a straight
road scene, fallbacks included), or at a crossing :data:`ROUTE_STRAIGHT_ON` (goal on the opposite
arm), :data:`ROUTE_LEFT` or :data:`ROUTE_RIGHT` (goal on an arm of the other road, the heading
turning counter-clockwise or clockwise). It and the other route descriptors (turn angle, crossing
angle, road widths, goal distance) are derived from the drawn quantities: recording them draws no
random numbers.

Obstacles (the solvability rule)
--------------------------------
Up to ``max_obstacles`` rectangles parked along the curbs (``mask`` tells which exist), slot by
slot as :func:`truckrl.sim.roads.curb_boxes` lays them out: ``obstacle_spacing`` long slots from
``obstacle_intersection_clearance`` beyond the parallelogram, one obstacle each with
``obstacle_min_gap / 2`` to spare at both ends, occupied with ``obstacle_keep_prob``, lying
``obstacle_curb_offset`` (> 0: it never touches a curb) inside its curb, so in the curb strip of
depth ``obstacle_curb_offset[1] + obstacle_width[1]``.

What holds by construction, given the checks of :class:`SceneConfig`:

* a free central corridor at least ``min_free_corridor`` wide on every road;
* at least ``obstacle_intersection_clearance`` to the intersection, hence (times the sine of the
  crossing angle) at least ``max(obstacle_pose_clearance, obstacle_min_gap)`` to everything on the
  other road; at least ``obstacle_min_gap`` between obstacles;
* at least ``min_free_corridor / 2 >= obstacle_pose_clearance`` to a start or goal on the other half
  of the same road.

What is drawn by rejection (the interval tests along the road; an obstacle still failing after
``rounds`` rounds is dropped): on the start's or goal's own lane (same road, same half), no
obstacle within ``obstacle_pose_clearance`` of the footprint, nor in the start's *departure zone*
(``pose_zone_length`` ahead of its front bumper) or the goal's *approach zone*
(``pose_zone_length`` behind its rear end); and no obstacle sticking out of the road's ends.

So the truck can always pull out of the start shoulder, drive the free corridor through an
obstacle-free intersection, and pull into the goal shoulder, driving forward only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import KIND_CURB, KIND_OBSTACLE, wrap_angle
from truckrl.sim.roads import (
    CROSSING_CURB_SLOTS,
    BoxRule,
    Roads,
    crossing_curbs,
    crossing_roads,
    curb_boxes,
    first_valid,
    lane_interval,
    lane_offset,
    pick_road,
    repeat_rounds,
    right_normal,
    scene_device,
    turn_exit_room,
    uniform,
)
from truckrl.sim.vehicle import truck_extents

#: Curb segment slots per scene: 2 roads x 2 curbs x 2 pieces (a straight road uses the first 2).
CURB_SLOTS = CROSSING_CURB_SLOTS
#: ``route`` values of a scene: one straight road (crossing fallbacks included); at a crossing,
#: straight on, a left turn (counter-clockwise) or a right turn (clockwise).
ROUTE_STRAIGHT_ROAD, ROUTE_STRAIGHT_ON, ROUTE_LEFT, ROUTE_RIGHT = 0, 1, 2, 3
#: Readable name of each ``route`` value, indexed by it.
ROUTE_NAMES: tuple[str, ...] = ("straight road", "straight on", "left", "right")
#: :class:`SceneBatch` fields that describe each episode's route (``[N]`` each).
ROUTE_KEYS: tuple[str, ...] = (
    "route",
    "turn_angle",
    "crossing_angle",
    "start_road_width",
    "goal_road_width",
    "goal_distance",
)


@dataclass
class SceneConfig:
    """Scene generator parameters (``env.task.scene.*``). See the module doc for the rules.

    The paper (Sec. "Scenes and unified geometry") randomizes road widths, headings, centres,
    crossing angles, start/goal and obstacles without stating ranges; the defaults fit an
    articulated truck (widths that let it turn, 25-70 m tasks, 50 m LiDAR range). Bounds that
    depend on other fields are checked in ``__post_init__`` and named in each field's doc.
    """

    crossing_prob: float = param(
        0.7, lo=0.0, hi=1.0, unit="-", doc="probability of two crossing roads (else one road)"
    )
    road_width: tuple[float, float] = param(
        (10.0, 18.0), lo=0.0, lo_open=True, hi=200.0, unit="m", doc="road width, curb to curb"
    )
    crossing_angle: tuple[float, float] = param(
        (math.pi / 4, 3 * math.pi / 4),
        lo=0.05,
        hi=math.pi - 0.05,
        unit="rad",
        doc="angle between the two roads (never near-parallel)",
    )
    center_jitter: float = param(
        10.0,
        lo=0.0,
        hi=1e4,
        unit="m",
        doc="the scene centre is uniform in +-this square around the origin",
    )
    half_extent: float = param(
        100.0,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        unit="m",
        doc="roads (curbs) span +-this along their direction from the scene centre",
    )
    curb_reach: float = param(
        50.0,
        lo=0.0,
        hi=1e4,
        hi_open=True,
        unit="m",
        doc="curbs reach this far beyond every start/goal rear axle; < half_extent",
        source="paper LiDAR range",
    )
    goal_distance: tuple[float, float] = param(
        (25.0, 70.0),
        lo=0.0,
        lo_open=True,
        unit="m",
        doc="start-goal straight-line distance; <= 2 * (half_extent - curb_reach)",
    )
    shoulder_gap: tuple[float, float] = param(
        (0.5, 1.5),
        lo=0.0,
        unit="m",
        doc="curb to the curb-side edge of the truck at start and goal; <= road_width min / 2",
    )
    pose_intersection_margin: float = param(
        2.0,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="start/goal footprints stay this far beyond the intersection",
    )
    pose_zone_length: float = param(
        20.0,
        lo=0.0,
        hi=1e4,
        unit="m",
        doc="obstacle-free lane ahead of the start's front / behind the goal's rear",
    )
    max_obstacles: int = param(
        16, lo=0, hi=4096, unit="-", doc="obstacle slots per scene (4 segments each)"
    )
    obstacle_spacing: float = param(
        12.0,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        unit="m",
        doc="slot length along a curb; >= obstacle_length max + obstacle_min_gap",
    )
    obstacle_keep_prob: float = param(
        0.5, lo=0.0, hi=1.0, unit="-", doc="probability that a slot holds an obstacle"
    )
    obstacle_length: tuple[float, float] = param(
        (3.5, 9.0), lo=0.0, lo_open=True, hi=100.0, unit="m", doc="obstacle length along the curb"
    )
    obstacle_width: tuple[float, float] = param(
        (1.5, 2.2), lo=0.0, lo_open=True, hi=100.0, unit="m", doc="obstacle width across the curb"
    )
    obstacle_curb_offset: tuple[float, float] = param(
        (0.2, 0.6),
        lo=0.0,
        lo_open=True,
        hi=100.0,
        unit="m",
        doc="gap between curb and obstacle (> 0: obstacles never touch a curb)",
    )
    obstacle_min_gap: float = param(
        1.0, lo=0.0, lo_open=True, hi=100.0, unit="m", doc="minimum distance between obstacles"
    )
    obstacle_pose_clearance: float = param(
        2.0,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="minimum distance from obstacles to the start and goal footprints",
    )
    obstacle_intersection_clearance: float = param(
        6.0,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="minimum distance from obstacles to the intersection; >= max(obstacle_pose_clearance,"
        " obstacle_min_gap) / sin(crossing_angle)",
    )
    min_free_corridor: float = param(
        4.0,
        lo=0.0,
        unit="m",
        doc="obstacle-free central band of every road; >= max(2 * obstacle_pose_clearance, "
        "obstacle_min_gap), <= road_width min - 2 * (obstacle_curb_offset max + "
        "obstacle_width max)",
    )
    rounds: int = param(
        8, lo=1, hi=1000, unit="-", doc="rejection-sampling rounds before the fallback"
    )
    left_turn_exit: float = param(
        3.0,
        lo=0.0,
        hi=100.0,
        unit="trailer wheelbases",
        doc="left turns: the goal lies at least (tan(turn / 2) + this) x trailer wheelbase past "
        "the corner of the start and goal lanes (0 = no such rule: experiment=paper)",
        source="measured with truckrl plan (docs/planner.md, Scenes that are solvable)",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.scene")
        # Bounds that depend on other fields (see each field's doc).
        if self.curb_reach >= self.half_extent:
            raise ConfigError(
                f"env.task.scene.curb_reach = {self.curb_reach} must be below "
                f"env.task.scene.half_extent = {self.half_extent}"
            )
        reach = 2.0 * (self.half_extent - self.curb_reach)
        if self.goal_distance[1] > reach:
            raise ConfigError(
                f"env.task.scene.goal_distance = {list(self.goal_distance)}: values must be in "
                f"(0, {reach}] (2 * (half_extent - curb_reach))"
            )
        half_road = 0.5 * self.road_width[0]
        if self.shoulder_gap[1] > half_road:
            raise ConfigError(
                f"env.task.scene.shoulder_gap = {list(self.shoulder_gap)}: values must be in "
                f"[0, {half_road}] (road_width min / 2)"
            )
        need = self.obstacle_length[1] + self.obstacle_min_gap
        if self.obstacle_spacing < need:
            raise ConfigError(
                f"env.task.scene.obstacle_spacing = {self.obstacle_spacing} must be at least "
                f"obstacle_length max + obstacle_min_gap = {need}"
            )
        strip = self.obstacle_curb_offset[1] + self.obstacle_width[1]
        room = self.road_width[0] - 2.0 * strip
        if self.min_free_corridor > room:
            raise ConfigError(
                f"env.task.scene.min_free_corridor = {self.min_free_corridor} must be at most "
                f"road_width min - 2 * (obstacle_curb_offset max + obstacle_width max) = {room}"
            )
        # Guarantees behind the obstacle rules (see module doc): the free corridor keeps
        # opposite-curb obstacles clear of a pose and of each other, and the intersection
        # clearance keeps obstacles of one road clear of everything on the other road.
        need = max(2.0 * self.obstacle_pose_clearance, self.obstacle_min_gap)
        if self.min_free_corridor < need:
            raise ConfigError(
                f"env.task.scene.min_free_corridor = {self.min_free_corridor} must be at least "
                f"max(2 * env.task.scene.obstacle_pose_clearance, env.task.scene.obstacle_min_gap) = {need}"
            )
        sin_min = min(math.sin(a) for a in self.crossing_angle)
        need = max(self.obstacle_pose_clearance, self.obstacle_min_gap) / sin_min
        if self.obstacle_intersection_clearance < need:
            raise ConfigError(
                f"env.task.scene.obstacle_intersection_clearance = "
                f"{self.obstacle_intersection_clearance} must be at least "
                f"max(obstacle_pose_clearance, obstacle_min_gap) / sin(crossing angle) = {need:.3f}"
            )

    @property
    def num_segments(self) -> int:
        """``E``: curb slots plus 4 edges per obstacle slot."""
        return CURB_SLOTS + 4 * self.max_obstacles


@dataclass
class SceneBatch:
    """A batch of ``N`` scenes as plain tensors (world metres, radians).

    Attributes:
        segments: ``[N, E, 4]`` curb segments (slots ``0..7``) then 4 edges per obstacle slot.
        mask: ``[N, E]`` bool, ``False`` = padding (unused curb slot, absent obstacle).
        kind: ``[N, E]`` int8, :data:`KIND_CURB` or :data:`KIND_OBSTACLE` (by slot).
        start: ``[N, 3]`` start pose ``(x, y, heading)`` of the tractor rear axle, articulation 0.
        goal: ``[N, 3]`` goal pose, same convention.
        crossing: ``[N]`` bool, two crossing roads (else one straight road).
        intersection: ``[N, 4, 2]`` crossing parallelogram corners, counter-clockwise; zeros
            where ``crossing`` is ``False``.
        roads: ``[N, 2, 4]`` per road ``(centre x, centre y, heading, width)``.
        road_mask: ``[N, 2]`` bool, which roads exist.
        route: ``[N]`` int8 route category: :data:`ROUTE_STRAIGHT_ROAD`, :data:`ROUTE_STRAIGHT_ON`,
            :data:`ROUTE_LEFT` or :data:`ROUTE_RIGHT` (names in :data:`ROUTE_NAMES`).
        turn_angle: ``[N]`` float [rad] signed heading change from start to goal, in
            ``(-pi, pi]``, positive = left (counter-clockwise); 0 on a straight road and straight on.
        crossing_angle: ``[N]`` float [rad] angle from road 0 to road 1 as sampled (in
            ``SceneConfig.crossing_angle``); 0 where ``crossing`` is ``False``.
        start_road_width: ``[N]`` float [m] curb-to-curb width of the start's road.
        goal_road_width: ``[N]`` float [m] curb-to-curb width of the goal's road.
        goal_distance: ``[N]`` float [m] straight-line distance between the start and goal
            rear-axle centres.
    """

    segments: Tensor
    mask: Tensor
    kind: Tensor
    start: Tensor
    goal: Tensor
    crossing: Tensor
    intersection: Tensor
    roads: Tensor
    road_mask: Tensor
    route: Tensor
    turn_angle: Tensor
    crossing_angle: Tensor
    start_road_width: Tensor
    goal_road_width: Tensor
    goal_distance: Tensor

    def __len__(self) -> int:
        return self.segments.shape[0]

    @property
    def device(self) -> torch.device:
        return self.segments.device

    def assign(self, index: Tensor, other: SceneBatch) -> None:
        """Overwrite scenes ``index [M]`` (long or ``[N]`` bool) in place with ``other`` (``M`` scenes)."""
        for f in fields(self):
            getattr(self, f.name)[index] = getattr(other, f.name)

    def to(self, device) -> SceneBatch:
        """The scenes on ``device``: a copy on another device, the same tensors (no copy) on this
        one, as ``Tensor.to``; ``.assign`` on the result then writes into ``self`` too."""
        return SceneBatch(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})


@dataclass
class _Extents:
    """Truck footprint at articulation 0 relative to the tractor rear axle [m], each ``[n]``."""

    front: Tensor  # ahead of the axle (tractor front bumper)
    rear: Tensor  # behind the axle (tractor or trailer rear end, whichever is farther)
    half_width: Tensor  # half the wider body


# One sequence of stages (roads, poses, curbs, obstacles): the order of random draws in one place.
def generate_scenes(
    cfg: SceneConfig,
    params: dict[str, Tensor],
    generator: torch.Generator | None = None,
    device=None,
) -> SceneBatch:
    """Draw one random scene per truck: a :class:`SceneBatch` of ``N`` valid scenes (module doc).

    Args:
        cfg: generator parameters.
        params: vehicle parameters ``{key: Tensor[N]}`` from
            :func:`truckrl.sim.vehicle.sample_vehicle_params`; the start and goal footprints use them.
        generator: source of all randomness; its device is the output device.
        device: output device when no generator is given (default: that of ``params``).
    """
    dev, p = scene_device(params, generator, device)
    n = p["wheelbase"].shape[0]

    def rand(*shape: int) -> Tensor:
        return torch.rand(*shape, generator=generator, device=dev)

    ext = _Extents(*truck_extents(p))
    crossing = rand(n) < cfg.crossing_prob
    roads = _sample_roads(cfg, rand, n, dev)
    ok, cross_start, cross_goal, cross_route = _crossing_poses(
        cfg, rand, roads, ext, p["trailer_wheelbase"]
    )
    crossing = crossing & ok
    straight_start, straight_goal = _straight_poses(cfg, rand, roads, ext)
    c = crossing.unsqueeze(-1)
    start = torch.where(c, cross_start, straight_start)  # [n, 4]: x, y, heading, road
    goal = torch.where(c, cross_goal, straight_goal)
    curbs, curb_mask = crossing_curbs(roads, crossing, cfg.half_extent)
    roads.corners = roads.corners * crossing.view(n, 1, 1)
    obstacles, obstacle_mask = _obstacles(cfg, rand, roads, crossing, start, goal, ext)

    segments = torch.cat((curbs, obstacles), dim=1)
    mask = torch.cat((curb_mask, obstacle_mask), dim=1)
    kind = torch.full((n, cfg.num_segments), KIND_OBSTACLE, dtype=torch.int8, device=dev)
    kind[:, :CURB_SLOTS] = KIND_CURB
    road_mask = torch.stack((torch.ones_like(crossing), crossing), dim=-1)
    route = torch.where(crossing, cross_route, ROUTE_STRAIGHT_ROAD).to(torch.int8)
    turn = goal[:, 2] - start[:, 2]  # headings in [-pi, pi]: atan2 wraps to (-pi, pi]
    turn_angle = torch.atan2(torch.sin(turn), torch.cos(turn))
    return SceneBatch(
        segments=segments * mask.unsqueeze(-1),
        mask=mask,
        kind=kind,
        start=start[:, :3],
        goal=goal[:, :3],
        crossing=crossing,
        intersection=roads.corners,
        roads=roads.table() * road_mask.unsqueeze(-1),
        road_mask=road_mask,
        route=route,
        turn_angle=turn_angle,
        crossing_angle=torch.where(crossing, roads.angle, 0.0),
        start_road_width=pick_road(roads.width, start[:, 3].long()),
        goal_road_width=pick_road(roads.width, goal[:, 3].long()),
        goal_distance=(goal[:, :2] - start[:, :2]).norm(dim=-1),
    )


def _sample_roads(cfg: SceneConfig, rand, n: int, dev) -> Roads:
    """Random centre, headings and widths, and the crossing parallelogram of every scene."""
    centre = (2.0 * rand(n, 2) - 1.0) * cfg.center_jitter
    h0 = wrap_angle(2.0 * math.pi * rand(n))
    angle = uniform(cfg.crossing_angle, rand(n))
    heading = torch.stack((h0, wrap_angle(h0 + angle)), dim=-1)
    return crossing_roads(centre, heading, uniform(cfg.road_width, rand(n, 2)), angle)


def _pose(x: Tensor, u: Tensor, road: Tensor) -> Tensor:
    """``[n, 4]``: position, heading of direction ``u``, and road index (as float)."""
    return torch.cat((x, torch.atan2(u[:, 1:], u[:, :1]), road.unsqueeze(-1).float()), dim=-1)


def _crossing_poses(
    cfg: SceneConfig, rand, roads: Roads, ext: _Extents, trailer_wheelbase: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Start on an approach arm, goal on another arm, by ``cfg.rounds`` rounds of rejection
    (left turns also by the exit rule, :func:`~truckrl.sim.roads.turn_exit_room`).

    Returns:
        ``ok [n]`` (a valid pair was found), start and goal ``[n, 4]`` (see :func:`_pose`), and
        ``route [n]`` (long: :data:`ROUTE_STRAIGHT_ON`, :data:`ROUTE_LEFT` or
        :data:`ROUTE_RIGHT`; :data:`ROUTE_STRAIGHT_ROAD` where not ``ok``).
    """
    n, k = roads.centre.shape[0], cfg.rounds
    L, reach = cfg.half_extent, cfg.half_extent - cfg.curb_reach
    margin = cfg.pose_intersection_margin
    # All rounds in one batched pass: row j * n + i is round j of scene i. The draws keep their
    # per-round order (so a seed's scenes are those of a loop over rounds, on any device), and
    # every value is computed by the same elementwise arithmetic as one round at a time.
    draws = [(rand(n, 6), rand(n, 2)) for _ in range(k)]
    r = torch.cat([d[0] for d in draws])  # [k n, 6]
    gaps = uniform(cfg.shoulder_gap, torch.cat([d[1] for d in draws]))  # [k n, 2]
    roads = Roads(**{f.name: repeat_rounds(getattr(roads, f.name), k) for f in fields(roads)})
    ext = _Extents(
        repeat_rounds(ext.front, k), repeat_rounds(ext.rear, k), repeat_rounds(ext.half_width, k)
    )
    centre = roads.centre
    rs = (r[:, 0] < 0.5).long()
    sig_s = torch.where(r[:, 1] < 0.5, 1.0, -1.0)
    choice = (3.0 * r[:, 2]).long().clamp_max(2)  # 0 straight on, 1 / 2 turn either way
    rg = torch.where(choice == 0, rs, 1 - rs)
    sig_g = torch.where(choice == 0, -sig_s, torch.where(choice == 1, 1.0, -1.0))
    us = -sig_s.unsqueeze(-1) * pick_road(roads.dirs, rs)  # towards P
    ug = sig_g.unsqueeze(-1) * pick_road(roads.dirs, rg)  # away from P
    lat_s = lane_offset(pick_road(roads.width, rs), gaps[:, 0], ext.half_width)
    lat_g = lane_offset(pick_road(roads.width, rg), gaps[:, 1], ext.half_width)
    # distances along the arms from P: footprints clear of the intersection and of road ends
    as_lo = pick_road(roads.extent, rs) + margin + ext.front
    as_hi = torch.clamp(L - ext.rear, max=reach)
    ag_lo = pick_road(roads.extent, rg) + margin + ext.rear
    ag_hi = torch.clamp(L - ext.front, max=reach)
    # goal distance: uniform over goal_distance and the distances between the nearest and
    # the farthest pose pair on these arms (all values between are reachable by continuity)
    q = centre + lat_g.unsqueeze(-1) * right_normal(ug)
    p_s = centre + lat_s.unsqueeze(-1) * right_normal(us)
    d_near = (p_s - as_lo.unsqueeze(-1) * us - q - ag_lo.unsqueeze(-1) * ug).norm(dim=-1)
    d_far = (p_s - as_hi.unsqueeze(-1) * us - q - ag_hi.unsqueeze(-1) * ug).norm(dim=-1)
    d_lo = torch.clamp(torch.minimum(d_near, d_far), min=cfg.goal_distance[0])
    d_hi = torch.clamp(torch.maximum(d_near, d_far), max=cfg.goal_distance[1])
    dist = d_lo + (d_hi - d_lo).clamp_min(0.0) * r[:, 3]
    # Arm distances (lateral offsets ignored) with a goal at ag_lo or ag_hi exactly `dist`
    # away bound a_s: the goal's arm distance then falls in [ag_lo, ag_hi] in most draws.
    cos_b = -(us * ug).sum(-1)  # angle between the two arms seen from P
    sin2_b = (1.0 - cos_b * cos_b).clamp_min(0.0)
    near = (dist * dist - ag_lo * ag_lo * sin2_b).clamp_min(0.0).sqrt()
    far = dist * dist - ag_hi * ag_hi * sin2_b
    as_hi = torch.minimum(as_hi, ag_lo * cos_b + near)
    as_lo = torch.where(
        far > 0.0, torch.maximum(as_lo, ag_hi * cos_b + far.clamp_min(0.0).sqrt()), as_lo
    )
    a_s = as_lo + (as_hi - as_lo).clamp_min(0.0) * r[:, 4]
    xs = p_s - a_s.unsqueeze(-1) * us
    # goal = q + a * ug with |xs - goal| = dist: the larger root of a quadratic in a
    b = (ug * (xs - q)).sum(-1)
    disc = b * b - ((xs - q) ** 2).sum(-1) + dist * dist
    a_g = b + disc.clamp_min(0.0).sqrt()
    valid = (disc >= 0.0) & (a_g >= ag_lo) & (a_g <= ag_hi) & (as_lo <= as_hi) & (d_lo <= d_hi)
    xg = q + a_g.unsqueeze(-1) * ug
    # the picked exit: a turn goes left where the goal direction is counter-clockwise of the
    # start direction (|cross| = sin(crossing angle) > 0 on the other road)
    left = us[:, 0] * ug[:, 1] - us[:, 1] * ug[:, 0] > 0.0
    if cfg.left_turn_exit > 0.0:
        room = turn_exit_room(xs, us, xg, ug, repeat_rounds(trailer_wheelbase, k))
        valid = valid & ~((choice != 0) & left & (room < cfg.left_turn_exit))
    picked = torch.where(choice == 0, ROUTE_STRAIGHT_ON, torch.where(left, ROUTE_LEFT, ROUTE_RIGHT))
    # each scene takes its first valid round; a scene without one keeps zeros (the fallback)
    ok, row = first_valid(valid.view(k, n))
    start = torch.where(ok.unsqueeze(-1), _pose(xs, us, rs)[row], 0.0)
    goal = torch.where(ok.unsqueeze(-1), _pose(xg, ug, rg)[row], 0.0)
    route = torch.where(ok, picked[row], ROUTE_STRAIGHT_ROAD)
    return ok, start, goal, route


def _straight_poses(cfg: SceneConfig, rand, roads: Roads, ext: _Extents) -> tuple[Tensor, Tensor]:
    """Start and goal ``[n, 4]`` on road 0, same lane and direction, goal ahead (valid by
    construction: used for straight roads and as the crossing fallback)."""
    L, reach = cfg.half_extent, cfg.half_extent - cfg.curb_reach
    n = roads.centre.shape[0]
    r = rand(n, 5)
    u = torch.where(r[:, :1] < 0.5, 1.0, -1.0) * roads.dirs[:, 0]
    lat_s = lane_offset(roads.width[:, 0], uniform(cfg.shoulder_gap, r[:, 1]), ext.half_width)
    lat_g = lane_offset(roads.width[:, 0], uniform(cfg.shoulder_gap, r[:, 2]), ext.half_width)
    dist = uniform(cfg.goal_distance, r[:, 3])
    ahead = (dist * dist - (lat_s - lat_g) ** 2).clamp_min(0.0).sqrt()
    t_lo = torch.clamp(ext.rear - L, min=-reach)
    t_hi = torch.clamp(L - ext.front, max=reach) - ahead
    t_s = t_lo + (t_hi - t_lo).clamp_min(0.0) * r[:, 4]
    right = right_normal(u)
    xs = roads.centre + t_s.unsqueeze(-1) * u + lat_s.unsqueeze(-1) * right
    xg = roads.centre + (t_s + ahead).unsqueeze(-1) * u + lat_g.unsqueeze(-1) * right
    road = torch.zeros(n, dtype=torch.long, device=u.device)
    return _pose(xs, u, road), _pose(xg, u, road)


def _obstacles(
    cfg: SceneConfig,
    rand,
    roads: Roads,
    crossing: Tensor,
    start: Tensor,
    goal: Tensor,
    ext: _Extents,
) -> tuple[Tensor, Tensor]:
    """Obstacle edges ``[n, 4K, 4]`` and mask ``[n, 4K]`` (rules in the module doc): boxes along
    the curbs (:func:`truckrl.sim.roads.curb_boxes`), kept off the start's and goal's own lane
    over their footprint and zone, padded by ``obstacle_pose_clearance``."""
    pad = cfg.obstacle_pose_clearance
    zones = [
        lane_interval(start, roads, -ext.rear - pad, ext.front + cfg.pose_zone_length + pad),
        lane_interval(goal, roads, -ext.rear - cfg.pose_zone_length - pad, ext.front + pad),
    ]
    rule = BoxRule(
        count=cfg.max_obstacles,
        spacing=cfg.obstacle_spacing,
        crossing_clearance=cfg.obstacle_intersection_clearance,
        keep_prob=cfg.obstacle_keep_prob,
        length=cfg.obstacle_length,
        width=cfg.obstacle_width,
        curb_offset=cfg.obstacle_curb_offset,
        min_gap=cfg.obstacle_min_gap,
        rounds=cfg.rounds,
        half_extent=cfg.half_extent,
    )
    return curb_boxes(rule, rand, roads, crossing, zones)
