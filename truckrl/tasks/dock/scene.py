"""Batched random loading-dock scenes: a row of bays at a building wall, parked trailers, an apron.

Every scene of a batch is drawn independently, all at once (no per-scene Python loop); all
randomness comes from one ``torch.Generator`` (same seed -> same scenes, on its device). The scene
is line segments ``[N, E, 4]`` with a validity mask and a ``kind`` per segment, the layout of
every task's scene (``kind`` :data:`~truckrl.sim.geometry.KIND_CURB` for the building and the yard's
curb and walls, :data:`~truckrl.sim.geometry.KIND_OBSTACLE` for parked trailers), with
``E = 3 + 5 * max_bays`` fixed by the config.

Layout (the dock frame; lengths in metres, angles in radians)
-------------------------------------------------------------
The **dock frame** has its origin at the centre of the target bay on the dock face, ``x`` along
the dock face and ``y`` out of the building across the apron (the bay axis). Each scene is drawn in
this frame and then turned by a uniform heading and shifted by up to ``center_jitter`` (the frame
is recorded as :attr:`DockSceneBatch.frame`).

* **Bays.** ``num_bays`` bays of one width ``W`` (``bay_width``) side by side along the dock face;
  the target is bay ``t`` (uniform), so bay ``i`` spans ``x in [(i - t - 1/2) W, (i - t + 1/2) W]``.
* **Walls.** A side wall (bollard line) between and at the ends of the bays: ``num_bays + 1``
  segments ``x = (i - t - 1/2) W``, ``0 <= y <= bay_depth``.
* **Dock face.** The building wall ``y = 0``, from the first wall to the last, extended by
  ``yard_margin`` at both ends.
* **Apron.** Open ground ``0 < y < apron_depth``, closed by a far curb ``y = apron_depth`` as long
  as the dock face; its ends are open (the yard road continues).
* **Parked trailers.** Every bay but the target holds a parked trailer with probability
  ``occupied_prob``: a rectangle (4 segments), aligned with the bay axis, its rear
  ``parked_rear_gap`` from the dock face, ``parked_length`` long, ``parked_width`` wide and shifted
  sideways by at most ``parked_lateral_jitter`` from the bay centre (so it never touches its walls:
  checked by :class:`DockSceneConfig`).

Goal and start (the truck: tractor rear axle, articulation 0)
-------------------------------------------------------------
* **Goal.** The trailer's rear-centre at ``(0, dock_gap)`` (``dock_gap`` in front of the dock
  face, in the middle of the target bay), the trailer heading along ``+y`` (away from the dock: the
  truck reverses in). The goal pose is the tractor rear axle of that truck,
  ``rear + (a_tk + L_ka + trailer_rear_overhang) * (0, 1)``.
* **Start.** Pulled forward on the apron: heading ``u = (s cos(alpha), sin(alpha))`` with a random
  driving direction ``s = +-1`` along the dock face and an angle ``alpha`` (``start_angle``,
  positive = nose away from the building), the trailer rear-centre ``start_lateral_offset`` past
  the bay axis in the driving direction, and its distance from the dock face uniform over all
  values that keep the truck inside the **start band** ``y_lo <= y <= y_hi``, ``y_lo = max(bay_depth,
  front of every parked trailer) + start_clearance`` and ``y_hi = apron_depth - start_clearance``.
  Where the band is too narrow for the drawn angle, ``|alpha|`` is clamped to
  ``asin((y_hi - y_lo - 2 hw) / length)`` (``hw``: half the wider body; ``length``: trailer rear to
  tractor front), at which the truck's bounding rectangle fits.
* **Apron depth.** Drawn from ``apron_depth`` and raised where needed so that the goal truck's front
  stays ``start_clearance`` from the far curb and the start band holds the truck at ``alpha = 0``.

What holds by construction (given the checks of :class:`DockSceneConfig` and a truck narrower than
the bays, checked by :class:`truckrl.tasks.dock.task.DockTask`):

* the target bay holds no segment: its walls lie on its sides, the dock face on its back;
* the goal truck is clear of everything: it lies in the target bay's strip ``|x| < W / 2``, in which
  the only segments are the dock face (``dock_gap`` behind the trailer) and the far curb (at least
  ``start_clearance`` beyond the tractor front); neighbouring parked trailers stay in their own
  bays' strips;
* so is every pose **pulled straight out of the bay** by ``0 <= D <= pull_room`` (the start
  curriculum of :mod:`truckrl.tasks.dock.task`): the same strip, ``pull_room = apron_depth -
  start_clearance - dock_gap - length``;
* the start truck lies in the start band, which no segment enters (walls and parked trailers end
  below ``y_lo``, the dock face and the far curb lie outside it).

Per-episode metadata (:attr:`DockSceneBatch.info`, :data:`DOCK_INFO_KEYS`, each ``[N]``): see
:class:`DockSceneBatch`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import KIND_CURB, KIND_OBSTACLE, rectangle_segments, wrap_angle
from truckrl.sim.roads import FramedScenes, scene_device, to_world, uniform
from truckrl.sim.vehicle import trailer_rear_offset, truck_extents

#: Per-episode metadata keys of :attr:`DockSceneBatch.info` (meaning and units there).
DOCK_INFO_KEYS: tuple[str, ...] = (
    "bay_width",
    "bay_depth",
    "num_bays",
    "target_bay",
    "apron_depth",
    "neighbours_occupied",
    "occupied_bays",
    "start_kind",
    "start_lateral_offset",
    "start_distance",
    "start_heading",
    "start_goal_distance",
    "pull_room",
    "pull_draw",
    "apron_draw",
)
#: ``start_kind`` values: drawn on the apron (generator), or pulled straight out of the bay (the
#: start curriculum, :meth:`truckrl.tasks.dock.task.DockTask.on_reset`).
START_APRON, START_PULLED = 0, 1
#: Segment slots before the walls: the dock face, the far curb.
_FIXED_SLOTS = 2


@dataclass
class DockSceneConfig:
    """Dock scene generator parameters (``env.task.scene.*``); rules in the module doc.

    Defaults fit a real truck yard (bays 3.5-4.5 m wide, 5-9 bays, an apron of 32-45 m, the
    usual rule of thumb being twice the length of the longest truck).
    """

    bay_width: tuple[float, float] = param(
        (3.5, 4.5), lo=0.5, hi=20.0, unit="m", doc="bay width W, wall to wall (one per scene)"
    )
    bay_depth: tuple[float, float] = param(
        (1.5, 4.0), lo=0.0, lo_open=True, hi=50.0, unit="m", doc="length of the bay side walls"
    )
    num_bays: tuple[int, int] = param(
        (5, 9), lo=1, hi=64, unit="-", doc="bays in the row (the target is one of them)"
    )
    occupied_prob: float = param(
        0.6, lo=0.0, hi=1.0, unit="-", doc="probability that a bay other than the target is taken"
    )
    parked_length: tuple[float, float] = param(
        (10.0, 13.6), lo=0.0, lo_open=True, hi=30.0, unit="m", doc="parked trailer length"
    )
    parked_width: tuple[float, float] = param(
        (2.45, 2.6), lo=0.0, lo_open=True, hi=10.0, unit="m", doc="parked trailer width"
    )
    parked_rear_gap: tuple[float, float] = param(
        (0.1, 0.5), lo=0.0, hi=5.0, unit="m", doc="dock face to a parked trailer's rear"
    )
    parked_lateral_jitter: float = param(
        0.3,
        lo=0.0,
        hi=5.0,
        unit="m",
        doc="largest sideways shift of a parked trailer from its bay centre; < (bay_width min - "
        "parked_width max) / 2",
    )
    apron_depth: tuple[float, float] = param(
        (32.0, 45.0),
        lo=0.0,
        lo_open=True,
        hi=500.0,
        unit="m",
        doc="dock face to far curb (raised per scene where the truck would not fit: module doc)",
    )
    yard_margin: float = param(
        40.0, lo=0.0, hi=1e4, unit="m", doc="dock face and far curb reach this beyond the end walls"
    )
    dock_gap: float = param(
        0.3,
        lo=0.0,
        lo_open=True,
        hi=5.0,
        unit="m",
        doc="goal: trailer rear-centre this far in front of the dock face",
    )
    start_clearance: float = param(
        1.0,
        lo=0.0,
        lo_open=True,
        hi=50.0,
        unit="m",
        doc="start truck to walls, parked trailers and far curb; goal truck front to far curb",
    )
    start_lateral_offset: tuple[float, float] = param(
        (-5.0, 20.0),
        lo=-200.0,
        hi=200.0,
        unit="m",
        doc="start trailer rear-centre past the bay axis, in the driving direction",
    )
    start_angle: tuple[float, float] = param(
        (-0.26, 0.52),
        lo=-math.pi / 2,
        hi=math.pi / 2,
        unit="rad",
        doc="start heading from the dock face direction, + = nose away from the building",
    )
    center_jitter: float = param(
        10.0, lo=0.0, hi=1e4, unit="m", doc="frame origin uniform in +-this square"
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.scene")
        room = 0.5 * (self.bay_width[0] - self.parked_width[1])
        if self.parked_lateral_jitter >= room:
            raise ConfigError(
                f"env.task.scene.parked_lateral_jitter = {self.parked_lateral_jitter} must be "
                f"below (bay_width min - parked_width max) / 2 = {room:g}: a parked trailer "
                "must not touch its walls"
            )

    @property
    def max_bays(self) -> int:
        return int(self.num_bays[1])

    @property
    def num_segments(self) -> int:
        """``E``: dock face, far curb, ``max_bays + 1`` walls, 4 edges per parked-trailer slot."""
        return _FIXED_SLOTS + (self.max_bays + 1) + 4 * self.max_bays


class DockSceneBatch(FramedScenes):
    """A batch of ``N`` dock scenes (world metres, radians).

    Attributes:
        segments: ``[N, E, 4]``: slot 0 the dock face, 1 the far curb, ``2 .. 2 + max_bays`` the
            walls, then 4 edges per bay slot (a parked trailer).
        mask: ``[N, E]`` bool, ``False`` = padding (walls of absent bays, free bays).
        kind: ``[N, E]`` int8, :data:`KIND_CURB` (dock face, curb, walls) or
            :data:`KIND_OBSTACLE` (parked trailers).
        start: ``[N, 3]`` start pose ``(x, y, heading)`` of the tractor rear axle, articulation 0.
        goal: ``[N, 3]`` goal pose, same convention (its trailer rear-centre at the dock).
        frame: ``[N, 3]`` the dock frame in the world: origin (target bay centre on the dock
            face) and heading of its ``y`` axis, i.e. of the bay axis out of the building
            (= the goal heading).
        info: per-episode metadata ``{key: [N]}`` (:data:`DOCK_INFO_KEYS`):

            * ``bay_width`` [m], ``bay_depth`` [m] (side wall length), ``apron_depth`` [m] (as
              used, after raising), float32;
            * ``num_bays``, ``target_bay`` (index from the row's ``-x`` end),
              ``occupied_bays`` (parked trailers), ``neighbours_occupied`` (0, 1 or 2 of the
              target's direct neighbours; a row end counts as free), int8;
            * ``start_kind``: :data:`START_APRON` or :data:`START_PULLED` (int8);
            * ``start_lateral_offset`` [m]: start trailer rear-centre past the bay axis along
              the dock face, in the truck's driving direction (0 for a pulled start);
            * ``start_distance`` [m]: start trailer rear-centre to the dock face;
            * ``start_heading`` [rad]: start trailer heading minus the goal heading, in
              ``[-pi, pi)`` (a start parallel to the dock face: about +-pi/2);
            * ``start_goal_distance`` [m]: start to goal trailer rear-centre, straight line;
            * ``pull_room`` [m]: how far the goal truck can pull straight out of the bay and
              stay ``start_clearance`` from the far curb;
            * ``pull_draw``, ``apron_draw``: uniform [0, 1) draws the start curriculum uses
              (:meth:`truckrl.tasks.dock.task.DockTask.on_reset`), stored so that it needs no
              random numbers at reset.
    """


def generate_dock_scenes(
    cfg: DockSceneConfig,
    params: dict[str, Tensor],
    generator: torch.Generator | None = None,
    device=None,
) -> DockSceneBatch:
    """Draw one random dock scene per truck (rules in the module doc).

    Args:
        cfg: generator parameters.
        params: vehicle parameters ``{key: Tensor[N]}``; the goal and start use them.
        generator: source of all randomness; its device is the output device.
        device: output device when no generator is given (default: that of ``params``).

    Returns:
        A :class:`DockSceneBatch` of ``N`` scenes.
    """
    dev, p = scene_device(params, generator, device)
    n, B = p["wheelbase"].shape[0], cfg.max_bays
    # every draw at once, in a fixed order: same seed -> same scenes
    r = torch.rand(n, 12, generator=generator, device=dev)
    rb = torch.rand(n, B, 4, generator=generator, device=dev)
    jitter = torch.rand(n, B, generator=generator, device=dev)

    row = _bay_row(cfg, r, rb, jitter)
    front, rear, hw = truck_extents(p)
    length = front + rear
    apron, y_lo, y_hi = _apron(cfg, r[:, 4], row, length, hw)
    rear_off = trailer_rear_offset(p)
    width = row.width
    goal_rear = torch.stack((torch.zeros_like(width), torch.full_like(width, cfg.dock_gap)), -1)
    goal_axle = goal_rear + torch.stack((torch.zeros_like(width), rear_off), -1)
    s, u, start_axle, start_h = _apron_start(cfg, r, y_lo, y_hi, length, rear, hw)
    start_trailer_rear = start_axle - rear_off.unsqueeze(-1) * u  # `rear_off` behind the axle
    segments, mask, kind = _dock_segments(cfg, row, apron)

    # ---- into the world: turn by the frame heading, shift by the frame origin
    frame_h = wrap_angle(2.0 * math.pi * r[:, 9])  # heading of the dock frame's x axis
    origin = (2.0 * r[:, 10:12] - 1.0) * cfg.center_jitter
    seg = segments.view(n, -1, 2, 2).reshape(n, -1, 2)
    segments = to_world(seg, frame_h, origin).view(n, -1, 4) * mask.unsqueeze(-1)
    axis = wrap_angle(frame_h + 0.5 * math.pi)  # bay axis, out of the building
    goal = torch.cat((to_world(goal_axle, frame_h, origin), axis.unsqueeze(-1)), -1)
    start_xy = to_world(start_axle, frame_h, origin)
    start = torch.cat((start_xy, wrap_angle(frame_h + start_h).unsqueeze(-1)), -1)

    info = _dock_info(row, apron)
    info.update(
        start_kind=torch.full((n,), START_APRON, dtype=torch.int8, device=dev),
        start_lateral_offset=s * start_trailer_rear[:, 0],
        start_distance=start_trailer_rear[:, 1],
        start_heading=wrap_angle(start_h - 0.5 * math.pi),
        start_goal_distance=(start_trailer_rear - goal_rear).norm(dim=-1),
        pull_room=y_hi - cfg.dock_gap - length,
        pull_draw=torch.rand(n, generator=generator, device=dev),
        apron_draw=torch.rand(n, generator=generator, device=dev),
    )
    frame = torch.cat((origin, axis.unsqueeze(-1)), -1)
    return DockSceneBatch(segments, mask, kind, start, goal, frame, info)


@dataclass
class _Row:
    """The row of bays in the dock frame (module doc: bays, walls, parked trailers)."""

    num_bays: Tensor  # [n] long
    target: Tensor  # [n] long, the target bay's index from the row's -x end
    width: Tensor  # [n] bay width W [m]
    depth: Tensor  # [n] side wall length [m]
    occupied: Tensor  # [n, B] bool: a parked trailer in the bay
    wall_x: Tensor  # [n, B + 1] wall positions along the dock face [m]
    wall_mask: Tensor  # [n, B + 1] bool: the wall exists
    walls: Tensor  # [n, B + 1, 4] wall segments
    parked: Tensor  # [n, B, 4, 4] parked trailer edges
    parked_front: Tensor  # [n] farthest front of a parked trailer from the dock face (0: none) [m]


def _bay_row(cfg: DockSceneConfig, r: Tensor, rb: Tensor, jitter: Tensor) -> _Row:
    """The bays, their walls and parked trailers from the draws ``r [n, 12]`` (columns 0-3),
    ``rb [n, B, 4]`` and ``jitter [n, B]`` (uniform in [0, 1))."""
    dev, B = r.device, cfg.max_bays
    lo_b, hi_b = cfg.num_bays
    num_bays = (lo_b + ((hi_b - lo_b + 1) * r[:, 0]).floor()).clamp(lo_b, hi_b).long()
    target = (num_bays * r[:, 1]).floor().long().clamp(max=num_bays - 1)
    width = uniform(cfg.bay_width, r[:, 2])
    depth = uniform(cfg.bay_depth, r[:, 3])
    slot = torch.arange(B, device=dev).unsqueeze(0)  # [1, B] bay index
    bay_exists = slot < num_bays.unsqueeze(-1)
    occupied = bay_exists & (slot != target.unsqueeze(-1)) & (rb[..., 0] < cfg.occupied_prob)
    bay_x = (slot - target.unsqueeze(-1)).float() * width.unsqueeze(-1)  # [n, B] bay centres

    # walls: i = 0..num_bays at x = (i - t - 1/2) W
    wall = torch.arange(B + 1, device=dev).unsqueeze(0)
    wall_x = (wall - target.unsqueeze(-1) - 0.5).float() * width.unsqueeze(-1)  # [n, B+1]
    wall_mask = wall <= num_bays.unsqueeze(-1)
    zeros_w = torch.zeros_like(wall_x)
    walls = torch.stack((wall_x, zeros_w, wall_x, zeros_w + depth.unsqueeze(-1)), -1)

    # parked trailers
    p_len = uniform(cfg.parked_length, rb[..., 1])
    p_half = 0.5 * uniform(cfg.parked_width, rb[..., 2])
    p_gap = uniform(cfg.parked_rear_gap, rb[..., 3])
    p_x = bay_x + cfg.parked_lateral_jitter * (2.0 * jitter - 1.0)
    up = torch.full_like(p_x, 0.5 * math.pi)
    parked = rectangle_segments(p_x, p_gap, up, p_len, torch.zeros_like(p_len), p_half)
    parked_front = torch.where(occupied, p_gap + p_len, 0.0).amax(-1)  # [n]
    return _Row(
        num_bays, target, width, depth, occupied, wall_x, wall_mask, walls, parked, parked_front
    )


def _apron(
    cfg: DockSceneConfig, r: Tensor, row: _Row, length: Tensor, hw: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """The apron depth (drawn from ``r [n]``, raised where the truck would not fit: module doc)
    and the start band ``y_lo, y_hi``, each ``[n]`` [m]."""
    y_lo = torch.maximum(row.depth, row.parked_front) + cfg.start_clearance
    apron = torch.maximum(
        uniform(cfg.apron_depth, r),
        torch.maximum(
            cfg.dock_gap + length + cfg.start_clearance,  # goal truck front to far curb
            y_lo + 2.0 * hw + cfg.start_clearance,  # the start band holds the truck at alpha 0
        ),
    )
    return apron, y_lo, apron - cfg.start_clearance


def _apron_start(
    cfg: DockSceneConfig,
    r: Tensor,
    y_lo: Tensor,
    y_hi: Tensor,
    length: Tensor,
    rear: Tensor,
    hw: Tensor,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The start on the apron from the draws ``r [n, 12]`` (columns 5-8): driving direction
    ``s [n]`` (+-1 along the dock face), heading vector ``u [n, 2]``, tractor rear axle ``[n,
    2]`` and heading ``[n]`` in the dock frame (module doc, "Start")."""
    s = torch.where(r[:, 5] < 0.5, 1.0, -1.0)
    band = y_hi - y_lo
    alpha_max = torch.asin(((band - 2.0 * hw) / length).clamp(0.0, 1.0))
    alpha = torch.minimum(torch.maximum(uniform(cfg.start_angle, r[:, 6]), -alpha_max), alpha_max)
    u = torch.stack((s * torch.cos(alpha), torch.sin(alpha)), -1)
    # y-extent of the truck's bounding rectangle relative to its rear-centre (rear end, rear
    # body centre): from -hw |cos| to length * sin(alpha) +- hw |cos|
    lsin, hcos = length * torch.sin(alpha), hw * torch.cos(alpha)
    rel_lo = torch.minimum(lsin, torch.zeros_like(lsin)) - hcos
    rel_hi = torch.maximum(lsin, torch.zeros_like(lsin)) + hcos
    yr_lo, yr_hi = y_lo - rel_lo, y_hi - rel_hi
    y_rear = yr_lo + (yr_hi - yr_lo).clamp_min(0.0) * r[:, 7]
    offset = uniform(cfg.start_lateral_offset, r[:, 8])
    start_rear = torch.stack((s * offset, y_rear), -1)  # rear end centre of the bounding box
    # the tractor axle is `rear` ahead of the rearmost end
    start_axle = start_rear + rear.unsqueeze(-1) * u
    return s, u, start_axle, torch.atan2(u[:, 1], u[:, 0])


def _dock_segments(cfg: DockSceneConfig, row: _Row, apron: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Segments ``[n, E, 4]`` in the dock frame (slots in :class:`DockSceneBatch`), their mask
    and kind ``[n, E]``."""
    n, B = apron.shape[0], cfg.max_bays
    x0 = row.wall_x[:, 0] - cfg.yard_margin
    x1 = torch.gather(row.wall_x, 1, row.num_bays.unsqueeze(-1)).squeeze(-1) + cfg.yard_margin
    zero = torch.zeros_like(x0)
    dock_face = torch.stack((x0, zero, x1, zero), -1)
    curb = torch.stack((x0, apron, x1, apron), -1)
    segments = torch.cat(
        (dock_face.unsqueeze(1), curb.unsqueeze(1), row.walls, row.parked.flatten(1, 2)), dim=1
    )
    ones = torch.ones(n, _FIXED_SLOTS, dtype=torch.bool, device=apron.device)
    park_mask = row.occupied.unsqueeze(-1).expand(n, B, 4).reshape(n, 4 * B)
    mask = torch.cat((ones, row.wall_mask, park_mask), dim=1)
    kind = torch.full((n, cfg.num_segments), KIND_OBSTACLE, dtype=torch.int8, device=apron.device)
    kind[:, : _FIXED_SLOTS + B + 1] = KIND_CURB
    return segments, mask, kind


def _dock_info(row: _Row, apron: Tensor) -> dict[str, Tensor]:
    """The row's metadata of :attr:`DockSceneBatch.info` (bays, apron, occupied neighbours)."""
    occupied, target, B = row.occupied, row.target, row.occupied.shape[1]
    left = torch.gather(occupied, 1, (target - 1).clamp_min(0).unsqueeze(-1)).squeeze(-1)
    left = left & (target > 0)
    right = torch.gather(occupied, 1, (target + 1).clamp(max=B - 1).unsqueeze(-1)).squeeze(-1)
    right = right & (target + 1 < row.num_bays)
    i8 = torch.int8
    return {
        "bay_width": row.width,
        "bay_depth": row.depth,
        "num_bays": row.num_bays.to(i8),
        "target_bay": target.to(i8),
        "apron_depth": apron,
        "neighbours_occupied": (left.to(i8) + right.to(i8)),
        "occupied_bays": occupied.sum(-1).to(i8),
    }
