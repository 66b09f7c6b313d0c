"""Batched turnaround scenes: a narrow straight road with a side branch, goal behind the start.

A tractor-semitrailer (up to ~20 m) cannot turn round on a road narrower than its turning circle,
and on a plain narrow road not even with a three-point turn (its trailer does not fit across).
The solvable geometry is a **turnaround**: a straight road too narrow for a forward U-turn, with a
side branch (a "T" or "hammerhead" arm) deep and wide enough to take the whole truck. The truck
starts on the road heading towards the branch; the goal lies behind the start in the other lane,
facing back. The intended manoeuvre: drive forward past the branch, reverse into it, drive out
forward the other way (or drive forward into the branch, reverse out, drive forward).

Everything is batched (no per-scene loops), pure torch, one ``torch.Generator`` for all
randomness, and emitted as line segments ``[N, E, 4]`` (``E =`` :data:`NUM_SEGMENTS`) with a
mask and a ``kind`` per segment (all :data:`~truckrl.sim.geometry.KIND_CURB`).

Layout (local frame, then rotated by a uniform heading and shifted by ``center_jitter``)
----------------------------------------------------------------------------------------
* **Road.** Along ``+x`` with its centreline on ``y = 0``, curbs at ``y = +-W / 2`` (``W`` =
  ``road_width``), from ``x = -half_extent`` to ``x = +half_extent`` or, in a dead-end scene, to
  an end wall at ``x_end``.
* **Branch.** On side ``sigma`` (+1 left, ``y > 0``; -1 right), its mouth centred at ``x = 0`` on
  the curb ``y = sigma W / 2``. Its axis points along ``b = (cos a, sigma sin a)`` (``a`` =
  ``branch_angle`` from the road's ``+x``; ``pi / 2`` perpendicular, smaller leans away from
  the start). Its side walls leave the curb at ``x = +-h``, ``h = B_w / (2 sin a)`` (so the branch
  is ``B_w`` = ``branch_width`` wide across its axis) and run along ``b`` until ``B_d`` =
  ``branch_depth`` from the curb line (measured perpendicular to the road); an end wall closes it.
  The two mouth corners are cut by chamfers of ``c`` = ``mouth_chamfer`` metres along the curb
  and along the wall. The curb of the branch side thus ends at ``x = -(h + c)`` and resumes at
  ``x = h + c``.
* **Dead end** (probability ``dead_end_prob``): a wall across the road at
  ``x_end = h + c + dead_end_gap * L``, ``L`` the truck length (enough to pull past the branch).
* **Segments** (slot: meaning): 0 curb on the non-branch side; 1, 2 the branch-side curb before
  and after the mouth; 3, 4 the chamfers; 5, 6 the branch side walls (start side, far side);
  7 the branch end wall; 8 the dead-end wall (masked out where there is none).

Start and goal
--------------
Poses are the tractor rear-axle centre, articulation 0. The start drives ``+x`` in the right
lane (``y < 0``), its curb-side edge ``shoulder_gap`` from the curb (kept in its half of the
road); its front bumper is ``start_gap`` before the mouth (``x = -(h + c)``). The goal faces
``-x`` (heading ``start + pi``) in the other lane, mirrored (``shoulder_gap`` from the other
curb), its rear axle ``goal_back`` metres behind the start's rear axle (``x_goal = x_start -
goal_back``). Both footprints lie on the straight road before the mouth, so both are free.

Why the truck must reverse (the forward-U-turn criterion, checked per scene)
----------------------------------------------------------------------------
The tractor's rear axle follows a path of curvature at most ``1 / R``, ``R = L_t / tan(max_steer)``
(``theta_dot = v tan(delta) / L_t``). Going forward from heading 0 to heading ``pi`` it moves
sideways by at least ``2 R``: on the stretch where the heading is inside ``(0, pi)``,
``dy = int sin(theta) ds >= R int sin(theta) |d theta| >= R |cos 0 - cos pi| = 2 R``. At both
ends the tractor body spans its width ``w_t`` across the axle, so a forward U-turn needs a strip
at least ``2 R + w_t`` wide (the trailer only adds to it). Every scene has

    road_width   <= 2 R + w_t - forward_margin      (no forward loop on the road)
    branch_width <= 2 R + w_t - forward_margin      (none across the branch either)

so the truck cannot turn round forward on the road, nor inside the branch (the same argument
across the branch: from heading ``pi / 2`` into it to ``3 pi / 2`` out of it, the axle moves
``2 R`` along the road). Not excluded by this bound: a forward loop that uses the road, the
chamfered mouth and the branch together (heading ``0 -> pi`` ending up in the branch, then out
and round on the road). Whether such a loop exists for the tractor-trailer at the sampled
geometry is not checked here; a forward-only run of the planner baseline would check it.

Why the branch takes the truck (the branch rule)
------------------------------------------------
``branch_depth >= branch_depth_factor[0] * L >= L`` (the whole truck, straight, fits in the
branch with the nose at the curb line), and ``branch_width >= W_max + 2 * branch_side_clearance``
(``W_max`` the wider body). The road width is at least the truck width plus the lane gaps.

Metadata (``UTurnSceneBatch.info``, each ``[N]``, see :data:`INFO_KEYS`)
------------------------------------------------------------------------
``road_width`` [m], ``branch_width`` [m] (across its axis), ``branch_depth`` [m] (from the curb
line, perpendicular to the road), ``branch_side`` (+1 left, -1 right), ``branch_angle`` [rad]
(axis from the start's heading, unsigned in ``(0, pi)``), ``goal_distance`` [m] (start to goal
rear axles, straight), ``dead_end`` (1.0 / 0.0), ``turn_radius`` [m] (``R``), ``forward_width``
[m] (``2 R + w_t``), ``truck_length`` [m] (``L``), ``start_gap`` [m], ``branch_left`` (1.0 left,
0.0 right: ``branch_side`` as a category code), and the local frame: ``mouth_x``, ``mouth_y`` [m]
(the mouth centre) and ``road_heading`` [rad] (the start's heading, = ``frame``),
``mouth_chamfer`` [m] (``c``), ``x_far`` [m] (local x where the road ends: the dead-end wall, or
``half_extent``). Recording them draws no random numbers. The start curriculum's keys
(:meth:`truckrl.tasks.uturn.task.UTurnTask.on_reset`): ``start_kind`` (:data:`START_ROAD` as
generated), ``start_sigma`` (-1 as generated), ``stage_draw`` and ``place_draw`` (uniform in
[0, 1), drawn after everything else so the scenes do not depend on them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import KIND_CURB, wrap_angle
from truckrl.sim.roads import FramedScenes, lane_offset, scene_device, to_world, uniform
from truckrl.sim.vehicle import truck_extents

#: Segment slots per scene (module doc, "Segments").
NUM_SEGMENTS = 9
#: Slot of the dead-end wall (masked out where there is none).
DEAD_END_SLOT = 8
#: What each segment slot is (module doc, "Segments"), for reports.
SEGMENT_NAMES: tuple[str, ...] = (
    "curb, far side",
    "curb before the mouth",
    "curb after the mouth",
    "chamfer, start side",
    "chamfer, far side",
    "branch wall, start side",
    "branch wall, far side",
    "branch end wall",
    "dead-end wall",
)
#: Per-episode metadata keys of :attr:`UTurnSceneBatch.info` (module doc, "Metadata").
INFO_KEYS: tuple[str, ...] = (
    "road_width",
    "branch_width",
    "branch_depth",
    "branch_side",
    "branch_angle",
    "goal_distance",
    "dead_end",
    "turn_radius",
    "forward_width",
    "truck_length",
    "start_gap",
    "branch_left",
    "mouth_x",
    "mouth_y",
    "road_heading",
    "mouth_chamfer",
    "x_far",
    "start_kind",
    "stage_draw",
    "place_draw",
    "start_sigma",
)

#: ``info["start_kind"]`` codes: the generator's start on the road before the branch, and the
#: points of the manoeuvre the start curriculum may move it to (on the reverse path past the
#: branch, on its arc, up the branch axis; on the forward leg before it):
#: :meth:`truckrl.tasks.uturn.task.UTurnTask.on_reset`.
START_ROAD, START_PAST, START_ARC, START_BRANCH, START_LEG = 0.0, 1.0, 2.0, 3.0, 4.0


def _metres(default: tuple[float, float], doc: str, hi: float = 1000.0):
    return param(default, lo=0.0, lo_open=True, hi=hi, unit="m", doc=doc)


@dataclass
class UTurnSceneConfig:
    """Turnaround scene parameters (``env.task.scene.*``); rules in the module doc.

    Ranges are drawn uniformly per scene; the road and branch widths are then clamped per truck
    to the forward-U-turn criterion and the branch rule.
    """

    road_width: tuple[float, float] = _metres(
        (9.0, 12.0),
        "road width, curb to curb; per truck at most 2 R + w_t - forward_margin",
        hi=100.0,
    )
    forward_margin: float = param(
        0.5,
        lo=0.0,
        hi=10.0,
        unit="m",
        doc="road and branch stay this much narrower than a forward U-turn needs (2 R + w_t)",
    )
    branch_width: tuple[float, float] = _metres(
        (10.0, 13.0),
        "branch width across its axis; per truck clamped to [W_max + 2 branch_side_clearance, "
        "2 R + w_t - forward_margin]",
        hi=100.0,
    )
    branch_side_clearance: float = param(
        1.0, lo=0.0, hi=10.0, unit="m", doc="least room each side of the widest body in the branch"
    )
    branch_depth_factor: tuple[float, float] = param(
        (1.15, 1.5),
        lo=1.0,
        hi=10.0,
        unit="truck lengths",
        doc="branch depth from the curb line, in truck lengths L (>= 1: the truck fits)",
    )
    branch_angle: tuple[float, float] = param(
        (math.radians(75.0), math.radians(105.0)),
        lo=math.pi / 3,
        hi=2 * math.pi / 3,
        unit="rad",
        doc="angle of the branch axis from the start's heading (pi/2 = perpendicular)",
    )
    left_prob: float = param(0.5, lo=0.0, hi=1.0, unit="-", doc="probability of a left branch")
    mouth_chamfer: tuple[float, float] = param(
        (4.0, 7.0), lo=0.0, hi=20.0, unit="m", doc="corner cut at both mouth corners (each leg)"
    )
    dead_end_prob: float = param(
        0.3, lo=0.0, hi=1.0, unit="-", doc="probability of a wall across the road past the branch"
    )
    dead_end_gap: tuple[float, float] = param(
        (1.3, 2.0),
        lo=1.0,
        hi=10.0,
        unit="truck lengths",
        doc="dead-end wall beyond the mouth's far chamfer, in truck lengths (>= 1: room to pull past)",
    )
    start_gap: tuple[float, float] = _metres(
        (5.0, 20.0), "start's front bumper to the mouth's near chamfer", hi=200.0
    )
    goal_back: tuple[float, float] = param(
        (0.0, 15.0),
        lo=0.0,
        hi=200.0,
        unit="m",
        doc="goal rear axle this far behind the start's rear axle, along the road",
    )
    shoulder_gap: tuple[float, float] = param(
        (0.3, 1.0),
        lo=0.0,
        hi=5.0,
        unit="m",
        doc="curb to the curb-side edge of the truck at start and goal (kept in its half)",
    )
    half_extent: float = param(
        130.0,
        lo=10.0,
        hi=1e4,
        unit="m",
        doc="the road (curbs) spans +-this from the mouth; > start_gap max + goal_back max + 80",
    )
    center_jitter: float = param(
        10.0, lo=0.0, hi=1e4, unit="m", doc="the mouth centre is uniform in +-this square"
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.scene")
        need = self.start_gap[1] + self.goal_back[1] + 80.0
        if self.half_extent <= need:
            raise ConfigError(
                f"env.task.scene.half_extent = {self.half_extent} must exceed start_gap max + "
                f"goal_back max + 80 = {need} (truck, branch and LiDAR range behind the goal)"
            )


class UTurnSceneBatch(FramedScenes):
    """``N`` turnaround scenes as plain tensors (world metres, radians).

    Attributes:
        segments: ``[N, E, 4]`` (slots in the module doc), zeros where masked.
        mask: ``[N, E]`` bool.
        kind: ``[N, E]`` int8, all :data:`~truckrl.sim.geometry.KIND_CURB`.
        start: ``[N, 3]`` start pose (rear axle x, y, heading), articulation 0.
        goal: ``[N, 3]`` goal pose, heading ``start + pi`` (wrapped).
        frame: ``[N, 3]`` the local frame (mouth centre x, y, road heading = start heading).
        info: ``{key: [N]}`` metadata (:data:`INFO_KEYS`, module doc).
    """


def forward_uturn_width(p: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
    """``(R, 2 R + w_t)`` [m], each ``[N]``: the tractor's least rear-axle turning radius
    ``L_t / tan(max_steer)`` and the least strip width a forward U-turn needs (module doc)."""
    radius = p["wheelbase"] / torch.tan(p["max_steer"])
    return radius, 2.0 * radius + p["tractor_width"]


@dataclass
class _Drawn:
    """One turnaround scene's drawn quantities, each ``[n]`` (module doc, "Layout")."""

    road_w: Tensor  # road width W [m], clamped per truck
    branch_w: Tensor  # branch width B_w across its axis [m], clamped per truck
    branch_d: Tensor  # branch depth B_d from the curb line [m]
    angle: Tensor  # branch angle a [rad]
    sigma: Tensor  # branch side, +1 left, -1 right
    chamfer: Tensor  # mouth chamfer c [m]
    dead: Tensor  # bool, a dead-end wall
    dead_gap: Tensor  # dead-end wall beyond the far chamfer [m]
    start_gap: Tensor  # start's front bumper to the near chamfer [m]
    goal_back: Tensor  # goal rear axle behind the start's [m]
    gap_s: Tensor  # start's shoulder gap [m]
    gap_g: Tensor  # goal's shoulder gap [m]
    heading: Tensor  # road heading (+x of the local frame) [rad]


def _draw(
    cfg: UTurnSceneConfig, r: Tensor, length: Tensor, half_w: Tensor, fwd_width: Tensor
) -> _Drawn:
    """The scene's quantities from ``r [n, 14]`` (uniform in [0, 1)), the road and branch widths
    clamped to the forward-U-turn criterion and the branch rule (module doc)."""
    width_cap = fwd_width - cfg.forward_margin
    lane_need = 2.0 * half_w  # the truck fits in its half of the road at the least
    road_w = torch.minimum(uniform(cfg.road_width, r[:, 0]), width_cap)
    road_w = torch.maximum(road_w, 2.0 * lane_need)
    branch_lo = 2.0 * half_w + 2.0 * cfg.branch_side_clearance
    branch_w = torch.minimum(uniform(cfg.branch_width, r[:, 1]), width_cap)
    branch_w = torch.maximum(branch_w, branch_lo)
    return _Drawn(
        road_w=road_w,
        branch_w=branch_w,
        branch_d=uniform(cfg.branch_depth_factor, r[:, 2]) * length,
        angle=uniform(cfg.branch_angle, r[:, 3]),
        sigma=torch.where(r[:, 4] < cfg.left_prob, 1.0, -1.0),
        chamfer=uniform(cfg.mouth_chamfer, r[:, 5]),
        dead=r[:, 6] < cfg.dead_end_prob,
        dead_gap=uniform(cfg.dead_end_gap, r[:, 7]) * length,
        start_gap=uniform(cfg.start_gap, r[:, 8]),
        goal_back=uniform(cfg.goal_back, r[:, 9]),
        gap_s=uniform(cfg.shoulder_gap, r[:, 10]),
        gap_g=uniform(cfg.shoulder_gap, r[:, 11]),
        heading=wrap_angle(2.0 * math.pi * r[:, 12]),
    )


def _local_segments(d: _Drawn, h: Tensor, x_far: Tensor, half_extent: float) -> Tensor:
    """The :data:`NUM_SEGMENTS` segments ``[n, 9, 4]`` in the local frame (road along ``+x``,
    mouth centre at the origin; slots in the module doc); ``h`` is half the mouth's width along
    the curb, ``x_far`` where the road ends."""
    half = 0.5 * d.road_w
    sin_a, cos_a = torch.sin(d.angle), torch.cos(d.angle)
    c, sigma = d.chamfer, d.sigma
    b = torch.stack((cos_a, sigma * sin_a), -1)  # branch axis [n, 2]
    along = (d.branch_d / sin_a)[:, None]  # wall length along b
    x_near = torch.full_like(half, -half_extent)
    y_b = sigma * half  # the branch-side curb line
    y_o = -sigma * half  # the other curb

    def pt(x: Tensor, y: Tensor) -> Tensor:
        return torch.stack((x, y), -1)

    wall0 = pt(-h, y_b)  # near mouth corner (start side)
    wall1 = pt(h, y_b)
    chamfer0 = (pt(-h - c, y_b), wall0 + c[:, None] * b)
    chamfer1 = (pt(h + c, y_b), wall1 + c[:, None] * b)
    end0, end1 = wall0 + along * b, wall1 + along * b
    return torch.stack(
        (
            torch.cat((pt(x_near, y_o), pt(x_far, y_o)), -1),
            torch.cat((pt(x_near, y_b), chamfer0[0]), -1),
            torch.cat((chamfer1[0], pt(x_far, y_b)), -1),
            torch.cat(chamfer0, -1),
            torch.cat(chamfer1, -1),
            torch.cat((chamfer0[1], end0), -1),
            torch.cat((chamfer1[1], end1), -1),
            torch.cat((end0, end1), -1),
            torch.cat((pt(x_far, -half), pt(x_far, half)), -1),
        ),
        1,
    )


def generate_uturn_scenes(
    cfg: UTurnSceneConfig,
    params: dict[str, Tensor],
    generator: torch.Generator | None = None,
    device=None,
) -> UTurnSceneBatch:
    """Draw one turnaround scene per truck (rules in the module doc).

    Args:
        cfg: generator parameters.
        params: vehicle parameters ``{key: [N]}`` (:func:`truckrl.sim.vehicle.sample_vehicle_params`).
        generator: source of all randomness; its device is the output device.
        device: output device when no generator is given (default: that of ``params``).
    """
    dev, p = scene_device(params, generator, device)
    n = p["wheelbase"].shape[0]
    r = torch.rand(n, 14, generator=generator, device=dev)
    front, rear, half_w = truck_extents(p)
    length = front + rear
    radius, fwd_width = forward_uturn_width(p)
    d = _draw(cfg, r, length, half_w, fwd_width)
    centre = (2.0 * torch.rand(n, 2, generator=generator, device=dev) - 1.0) * cfg.center_jitter
    del r

    # ---- local geometry (road along +x, mouth centre at the origin)
    half = 0.5 * d.road_w
    h, c = 0.5 * d.branch_w / torch.sin(d.angle), d.chamfer
    x_far = torch.where(d.dead, h + c + d.dead_gap, torch.full_like(half, cfg.half_extent))
    segs = _local_segments(d, h, x_far, cfg.half_extent)  # [n, 9, 4]
    mask = torch.ones(n, NUM_SEGMENTS, dtype=torch.bool, device=dev)
    mask[:, DEAD_END_SLOT] = d.dead

    # ---- start and goal (local): each in its lane, the goal goal_back behind the start
    zero = torch.zeros_like(half)
    x_s = -(h + c) - d.start_gap - front
    start_local = torch.stack((x_s, -lane_offset(d.road_w, d.gap_s, half_w), zero), -1)
    goal_xy = (x_s - d.goal_back, lane_offset(d.road_w, d.gap_g, half_w))
    goal_local = torch.stack((*goal_xy, zero + math.pi), -1)

    # ---- to the world
    heading = d.heading
    local = segs.view(n, NUM_SEGMENTS, 2, 2)
    segments = to_world(local, heading, centre).reshape(n, NUM_SEGMENTS, 4) * mask[..., None]

    def world_pose(pl: Tensor) -> Tensor:
        xy = to_world(pl[:, :2], heading, centre)
        return torch.cat((xy, wrap_angle(pl[:, 2:] + heading[:, None])), -1)

    start, goal = world_pose(start_local), world_pose(goal_local)
    kind = torch.full((n, NUM_SEGMENTS), KIND_CURB, dtype=torch.int8, device=dev)
    info = {
        "road_width": d.road_w,
        "branch_width": d.branch_w,
        "branch_depth": d.branch_d,
        "branch_side": d.sigma,
        "branch_angle": d.angle,
        "goal_distance": (goal[:, :2] - start[:, :2]).norm(dim=-1),
        "dead_end": d.dead.float(),
        "turn_radius": radius,
        "forward_width": fwd_width,
        "truck_length": length,
        "start_gap": d.start_gap,
        "branch_left": (d.sigma > 0).float(),
        "mouth_x": centre[:, 0],
        "mouth_y": centre[:, 1],
        "road_heading": heading,
    }
    # drawn last, so that the earlier draws (and so the scenes) do not depend on these keys
    late = torch.rand(n, 2, generator=generator, device=dev)
    info.update(
        mouth_chamfer=c,
        x_far=x_far,
        start_kind=torch.full_like(half, START_ROAD),
        stage_draw=late[:, 0],
        place_draw=late[:, 1],
        start_sigma=torch.full_like(half, -1.0),
    )
    frame = torch.cat((centre, heading[:, None]), -1)
    return UTurnSceneBatch(segments, mask, kind, start, goal, frame, info)
