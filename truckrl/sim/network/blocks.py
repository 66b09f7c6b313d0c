"""Road blocks: batched generators of each block's curbs, lanes, sockets and footprint.

Every generator takes ``[m]`` tensors (one block per row, no per-row Python) and returns a
:class:`Block` in the block's own frame; :func:`place` moves blocks into the world so that a
chosen socket sits on a given road end. Lengths in metres, angles in radians, right-hand traffic.

Terms
-----
* **Socket**: a road end ``(x, y, heading)``, the heading pointing out of the block; the road
  there is ``w`` wide (the network's road width), so its two curbs end at ``(x, y) +- (w / 2)
  n`` with ``n`` the socket's normal. Two blocks join where a socket of one sits on a socket of
  the other, headings opposed: their curbs then meet end to end.
* **Lanes**: centre-lines, two per road (one each way, ``w / 4`` right of the road's
  centre-line in its direction of travel), as polylines ``[Q, 2]`` in the direction of travel;
  metadata for routes and traffic, never collision or LiDAR.
* **Footprint**: oriented rectangles ``(cx, cy, ux, uy, half length, half width)`` covering the
  road surface, for the overlap test between blocks (:mod:`truckrl.sim.network.compose`).

The blocks (``p`` = the block's ``[m, 3]`` parameters, :data:`PARAM_NAMES`)
------------------------------------------------------------------------------
* **straight** ``(length)``: curbs along ``y = +-w / 2`` from ``x = 0`` to ``length``; sockets
  ``(0, 0, pi)`` and ``(length, 0, 0)``.
* **curve** ``(radius, angle)``: the centre-line is an arc of ``radius`` from ``(0, 0)`` heading
  ``+x``, turning by ``angle`` (> 0 left, < 0 right) round ``(0, sign * radius)``; each curb is
  a polyline of :meth:`~truckrl.sim.network.config.NetworkConfig.curve_pieces` equal chords with
  its vertices on the arc of radius ``radius -+ w / 2``, so no chord strays more than
  ``chord_error`` from it.
* **crossing** ``(angle, arm)``: today's crossing (:func:`truckrl.sim.roads.crossing_roads` and
  :func:`~truckrl.sim.roads.crossing_curbs`, unchanged): two roads through ``(0, 0)``, road 1
  turned by ``angle`` from road 0 (along ``+x``), each ``arm`` long on both sides; 8 curbs
  meeting at the corners of the crossing parallelogram; 4 sockets at the road ends.
* **t_junction** ``(arm)``: the bar along ``x`` from ``-arm`` to ``arm``, the stem from the bar
  down to ``(0, -arm)``; the bar's near curb is split where the stem's curbs meet it.
* **roundabout** ``(radius, arms, arm)``: a ring road of centre-line ``radius`` round ``(0,
  0)``: an island (closed polyline at ``radius - w / 2``), the outer curb (arcs at ``radius + w
  / 2`` between the arms) and ``arms`` (3 or 4) roads at headings ``2 pi i / arms``, each from
  the outer curb to ``arm`` beyond it. One lane on the ring, counter-clockwise along its
  centre-line; each arm's lanes end on it.
* **median** ``(length, width)``: a straight road that widens by ``width`` over ``median_taper``
  after ``median_lead`` of plain road, holds a median island (a closed rectangle ``width`` wide)
  over its wide part, and narrows again symmetrically; the lanes keep ``w / 4`` from the curbs.

A block with an entry at ``(0, 0, pi)`` (straight, curve, median) lies in ``x >= 0``; junctions
may be entered through any socket (:func:`place`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from truckrl.sim.network.config import (
    CROSSING,
    CURVE,
    MAX_SOCKETS,
    MEDIAN,
    ROUNDABOUT,
    STRAIGHT,
    T_JUNCTION,
    NetworkConfig,
)
from truckrl.sim.roads import crossing_curbs, crossing_roads

#: What the three columns of a block's parameters mean, per block type (``-``: unused).
PARAM_NAMES: tuple[tuple[str, str, str], ...] = (
    ("length", "-", "-"),
    ("radius", "angle", "-"),
    ("angle", "arm", "-"),
    ("arm", "-", "-"),
    ("radius", "arms", "arm"),
    ("length", "width", "-"),
)


@dataclass
class Block:
    """One block per row, padded: ``False`` in a mask marks an unused slot (its values are 0,
    a padded lane repeats its last point)."""

    curbs: Tensor  # [m, C, 4] curb segments (x0, y0, x1, y1)
    curb_mask: Tensor  # [m, C]
    lanes: Tensor  # [m, L, Q, 2] lane centre-lines, in the direction of travel
    lane_mask: Tensor  # [m, L]
    sockets: Tensor  # [m, S, 3] road ends (x, y, outward heading)
    socket_mask: Tensor  # [m, S]
    rects: Tensor  # [m, F, 6] footprint (cx, cy, ux, uy, half length, half width)
    rect_mask: Tensor  # [m, F]

    def sizes(self) -> tuple[int, int, int, int, int]:
        """``(C, L, Q, S, F)``."""
        return (
            self.curbs.shape[1],
            self.lanes.shape[1],
            self.lanes.shape[2],
            self.sockets.shape[1],
            self.rects.shape[1],
        )


def slot_sizes(cfg: NetworkConfig) -> tuple[int, int, int, int, int]:
    """Padded ``(C, L, Q, S, F)`` of a block under ``cfg`` (the largest of every type)."""
    curbs = max(
        2,
        2 * cfg.curve_pieces(),
        8,
        5,
        cfg.island_pieces() + 4 * cfg.outer_arc_pieces() + 2 * 4,
        10 + 4,
    )
    points = max(2, cfg.curve_pieces() + 1, cfg.ring_pieces() + 1, 6)
    rects = max(cfg.curve_footprints(), 2, 5)
    return curbs, 1 + 2 * 4, points, MAX_SOCKETS, rects


# ----------------------------------------------------------------------------------- helpers
def _mask(m: int, count: int, device) -> Tensor:
    return torch.ones(m, count, dtype=torch.bool, device=device)


def _polyline(points: Tensor) -> Tensor:
    """``[m, P + 1, 2]`` points -> ``[m, P, 4]`` segments joining them in order."""
    return torch.cat((points[:, :-1], points[:, 1:]), -1)


def _seg(x0: Tensor, y0: Tensor, x1: Tensor, y1: Tensor) -> Tensor:
    """``[m]`` coordinates -> ``[m, 4]`` segments."""
    return torch.stack((x0, y0, x1, y1), -1)


def _line(p0: Tensor, p1: Tensor) -> Tensor:
    """``[m, 2]`` ends -> a 2-point polyline ``[m, 2, 2]``."""
    return torch.stack((p0, p1), 1)


def _rect(cx: Tensor, cy: Tensor, heading: Tensor, half_len: Tensor, half_wid: Tensor) -> Tensor:
    """``[m]`` -> ``[m, 6]`` footprint rectangle."""
    return torch.stack(
        (cx, cy, torch.cos(heading), torch.sin(heading), half_len, half_wid.expand_as(cx)), -1
    )


def _arc(centre: Tensor, radius: Tensor, a0: Tensor, a1: Tensor, pieces: int) -> Tensor:
    """Points ``[m, pieces + 1, 2]`` on circles ``(centre [m, 2], radius [m])`` at polar angles
    evenly from ``a0`` to ``a1`` ``[m]`` (both included)."""
    f = torch.linspace(0.0, 1.0, pieces + 1, device=radius.device)
    a = a0.unsqueeze(-1) + (a1 - a0).unsqueeze(-1) * f
    r = radius.unsqueeze(-1)
    return centre.unsqueeze(1) + torch.stack((r * torch.cos(a), r * torch.sin(a)), -1)


def _pad_points(lanes: list[Tensor], q: int) -> Tensor:
    """Polylines ``[m, Q_i, 2]`` -> ``[m, len(lanes), q, 2]``, each padded by its last point."""
    out = []
    for lane in lanes:
        extra = q - lane.shape[1]
        out.append(torch.cat((lane, lane[:, -1:].expand(-1, extra, -1)), 1) if extra else lane)
    return torch.stack(out, 1)


def _pad(block: Block, sizes: tuple[int, int, int, int, int]) -> Block:
    """``block`` with every slot dimension padded up to ``sizes`` ``(C, L, Q, S, F)``."""
    C, L, Q, S, F = sizes
    m, dev = block.curbs.shape[0], block.curbs.device

    def rows(t: Tensor, k: int, fill: float | bool = 0) -> Tensor:
        extra = k - t.shape[1]
        if extra == 0:
            return t
        pad = torch.full((m, extra, *t.shape[2:]), fill, dtype=t.dtype, device=dev)
        return torch.cat((t, pad), 1)

    lanes = block.lanes
    if lanes.shape[2] < Q:
        extra = Q - lanes.shape[2]
        lanes = torch.cat((lanes, lanes[:, :, -1:].expand(-1, -1, extra, -1)), 2)
    return Block(
        rows(block.curbs, C),
        rows(block.curb_mask, C, False),
        rows(lanes, L),
        rows(block.lane_mask, L, False),
        rows(block.sockets, S),
        rows(block.socket_mask, S, False),
        rows(block.rects, F),
        rows(block.rect_mask, F, False),
    )


def _two_way(p0: Tensor, p1: Tensor, w: Tensor) -> list[Tensor]:
    """The two lanes of a straight road from ``p0`` to ``p1`` ``[m, 2]``: along it (``w / 4`` to
    its right) and back (``w / 4`` to its left, reversed)."""
    u = p1 - p0
    u = u / u.norm(dim=-1, keepdim=True)
    right = torch.stack((u[:, 1], -u[:, 0]), -1) * (0.25 * w).unsqueeze(-1)
    return [_line(p0 + right, p1 + right), _line(p1 - right, p0 - right)]


# ----------------------------------------------------------------------------------- blocks
def straight(cfg: NetworkConfig, w: Tensor, p: Tensor) -> Block:
    """A straight road (module doc)."""
    length, dev = p[:, 0], p.device
    z, h = torch.zeros_like(length), 0.5 * w
    curbs = torch.stack((_seg(z, -h, length, -h), _seg(z, h, length, h)), 1)
    lanes = _two_way(torch.stack((z, z), -1), torch.stack((length, z), -1), w)
    sockets = torch.stack(
        (torch.stack((z, z, z + math.pi), -1), torch.stack((length, z, z), -1)), 1
    )
    rects = _rect(0.5 * length, z, z, 0.5 * length, h).unsqueeze(1)
    m = length.shape[0]
    return Block(
        curbs, _mask(m, 2, dev), _pad_points(lanes, 2), _mask(m, 2, dev), sockets,
        _mask(m, 2, dev), rects, _mask(m, 1, dev),
    )  # fmt: skip


def _curve_points(radius: Tensor, angle: Tensor, offset: Tensor, pieces: int) -> Tensor:
    """Points ``[m, pieces + 1, 2]`` of a curve's line ``offset`` [m] left of its centre-line,
    from the entry (``t = 0``) to the exit, vertices on the arc."""
    sign = torch.where(angle >= 0.0, 1.0, -1.0)
    rho = radius - sign * offset  # distance from the arc's centre
    t = angle.abs().unsqueeze(-1) * torch.linspace(0.0, 1.0, pieces + 1, device=radius.device)
    r, s = rho.unsqueeze(-1), sign.unsqueeze(-1)
    return torch.stack((r * torch.sin(t), s * (radius.unsqueeze(-1) - r * torch.cos(t))), -1)


def curve(cfg: NetworkConfig, w: Tensor, p: Tensor) -> Block:
    """An arc of a road (module doc)."""
    radius, angle, dev = p[:, 0], p[:, 1], p.device
    m, pieces = radius.shape[0], cfg.curve_pieces()
    h, q = 0.5 * w, 0.25 * w
    curbs = torch.cat(
        (
            _polyline(_curve_points(radius, angle, -h, pieces)),
            _polyline(_curve_points(radius, angle, h, pieces)),
        ),
        1,
    )
    lanes = [
        _curve_points(radius, angle, -q, pieces),
        _curve_points(radius, angle, q, pieces).flip(1),
    ]
    exit_xy = _curve_points(radius, angle, torch.zeros_like(radius), 1)[:, 1]
    z = torch.zeros_like(radius)
    sockets = torch.stack(
        (torch.stack((z, z, z + math.pi), -1), torch.cat((exit_xy, angle.unsqueeze(-1)), -1)), 1
    )
    # footprint: one rectangle per piece of the centre-line, along its chord
    f = cfg.curve_footprints()
    centre = _curve_points(radius, angle, z, f)  # [m, f + 1, 2]
    a, b = centre[:, :-1], centre[:, 1:]
    d = b - a
    piece = angle.abs() / f
    sag = (radius * (1.0 - torch.cos(0.5 * piece))).unsqueeze(-1)
    heading = torch.atan2(d[..., 1], d[..., 0])
    mid = 0.5 * (a + b)
    rects = _rect(mid[..., 0], mid[..., 1], heading, 0.5 * d.norm(dim=-1), h.unsqueeze(-1) + sag)
    return Block(
        curbs, _mask(m, 2 * pieces, dev), _pad_points(lanes, pieces + 1), _mask(m, 2, dev),
        sockets, _mask(m, 2, dev), rects, _mask(m, f, dev),
    )  # fmt: skip


def crossing(cfg: NetworkConfig, w: Tensor, p: Tensor) -> Block:
    """Two crossing roads, today's geometry (module doc)."""
    angle, arm, dev = p[:, 0], p[:, 1], p.device
    m = angle.shape[0]
    z = torch.zeros_like(angle)
    roads = crossing_roads(
        torch.zeros(m, 2, device=dev),
        torch.stack((z, angle), -1),
        torch.stack((w, w), -1),
        angle,
    )
    # crossing_curbs spans one half extent for the whole batch: each curb's far end is moved to
    # +-arm along its road per row (a curb is straight, so its corner end stays where it is)
    curbs, _ = crossing_curbs(roads, torch.ones(m, dtype=torch.bool, device=dev), 1.0)
    curbs = curbs.view(m, 2, 2, 2, 4)  # [m, road, side, piece, 4]
    sign = torch.tensor([-1.0, 1.0], device=dev)
    ends = (sign.view(1, 1, 1, 2) * arm.view(m, 1, 1, 1)).unsqueeze(-1) * roads.dirs.view(
        m, 2, 1, 1, 2
    ) + (sign.view(1, 1, 2, 1) * 0.5 * w.view(m, 1, 1, 1)).unsqueeze(-1) * roads.normals.view(
        m, 2, 1, 1, 2
    )  # [m, road, side of the road, end (-arm, +arm), 2]
    curbs = torch.stack(
        (
            torch.cat((ends[..., 0, :], curbs[..., 0, 2:]), -1),  # far end -> first corner
            torch.cat((curbs[..., 1, :2], ends[..., 1, :]), -1),  # second corner -> far end
        ),
        3,
    ).reshape(m, 8, 4)
    lanes, sockets = [], []
    for r in range(2):
        d = roads.dirs[:, r]
        heading = torch.stack((z, angle), -1)[:, r]
        lanes += _two_way(-arm.unsqueeze(-1) * d, arm.unsqueeze(-1) * d, w)
        sockets += [
            torch.cat((-arm.unsqueeze(-1) * d, (heading + math.pi).unsqueeze(-1)), -1),
            torch.cat((arm.unsqueeze(-1) * d, heading.unsqueeze(-1)), -1),
        ]
    rects = torch.stack((_rect(z, z, z, arm, 0.5 * w), _rect(z, z, angle, arm, 0.5 * w)), 1)
    return Block(
        curbs, _mask(m, 8, dev), _pad_points(lanes, 2), _mask(m, 4, dev),
        torch.stack(sockets, 1), _mask(m, 4, dev), rects, _mask(m, 2, dev),
    )  # fmt: skip


def t_junction(cfg: NetworkConfig, w: Tensor, p: Tensor) -> Block:
    """A T-junction: a bar and a stem on its right (module doc)."""
    arm, dev = p[:, 0], p.device
    m, h, z = arm.shape[0], 0.5 * w, torch.zeros_like(arm)
    curbs = torch.stack(
        (
            _seg(-arm, h, arm, h),  # far curb of the bar, whole
            _seg(-arm, -h, -h, -h),  # near curb, before the stem
            _seg(h, -h, arm, -h),  # near curb, after the stem
            _seg(-h, -h, -h, -arm),  # the stem's curbs
            _seg(h, -h, h, -arm),
        ),
        1,
    )
    xy = lambda x, y: torch.stack((x, y), -1)  # noqa: E731
    lanes = _two_way(xy(-arm, z), xy(arm, z), w) + _two_way(xy(z, z), xy(z, -arm), w)
    sockets = torch.stack(
        (
            torch.stack((-arm, z, z + math.pi), -1),
            torch.stack((arm, z, z), -1),
            torch.stack((z, -arm, z - 0.5 * math.pi), -1),
        ),
        1,
    )
    rects = torch.stack(
        (_rect(z, z, z, arm, h), _rect(z, -0.5 * arm, z - 0.5 * math.pi, 0.5 * arm, h)), 1
    )
    return Block(
        curbs, _mask(m, 5, dev), _pad_points(lanes, 2), _mask(m, 4, dev), sockets,
        _mask(m, 3, dev), rects, _mask(m, 2, dev),
    )  # fmt: skip


def roundabout(cfg: NetworkConfig, w: Tensor, p: Tensor) -> Block:
    """A ring road with 3 or 4 arms (module doc)."""
    radius, arms, arm, dev = p[:, 0], p[:, 1].round(), p[:, 2], p.device
    m, h, z = radius.shape[0], 0.5 * w, torch.zeros_like(radius)
    origin = torch.zeros(m, 2, device=dev)
    outer, inner = radius + h, radius - h
    reach = outer + arm  # socket distance from the centre
    slot = torch.arange(4, device=dev).unsqueeze(0)  # [1, 4]
    used = slot < arms.unsqueeze(-1)  # [m, 4]
    beta = 2.0 * math.pi * slot / arms.unsqueeze(-1)  # [m, 4] arm headings
    delta = torch.asin(h / outer)  # half the angle an arm's mouth spans on the outer curb
    island = _polyline(_arc(origin, inner, z, z + 2.0 * math.pi, cfg.island_pieces()))
    pieces = cfg.outer_arc_pieces()
    arcs = [
        _polyline(_arc(origin, outer, beta[:, j] + delta, beta[:, j] + 2.0 * math.pi / arms - delta, pieces))
        for j in range(4)
    ]  # fmt: skip
    u = torch.stack((torch.cos(beta), torch.sin(beta)), -1)  # [m, 4, 2]
    n = torch.stack((-u[..., 1], u[..., 0]), -1)
    mouth = torch.sqrt(outer * outer - h * h).view(m, 1, 1, 1)  # where an arm's curb meets the ring
    side = torch.tensor([-1.0, 1.0], device=dev).view(1, 1, 2, 1)
    base = side * h.view(m, 1, 1, 1) * n.unsqueeze(2)  # [m, 4, 2 sides, 2]
    arm_curbs = torch.cat(
        (base + mouth * u.unsqueeze(2), base + reach.view(m, 1, 1, 1) * u.unsqueeze(2)), -1
    ).reshape(m, 8, 4)
    curbs = torch.cat((island, *arcs, arm_curbs), 1)
    curb_mask = torch.cat(
        (
            _mask(m, island.shape[1], dev),
            used.repeat_interleave(pieces, 1),
            used.repeat_interleave(2, 1),
        ),
        1,
    )
    # lanes: the ring counter-clockwise, then each arm's in and out lane, ending on the ring lane
    ring = _arc(origin, radius, z, z + 2.0 * math.pi, cfg.ring_pieces())
    meet = torch.sqrt(radius * radius - (0.25 * w) ** 2).view(m, 1, 1)
    lanes = [ring]
    for i in range(4):
        lanes += _two_way(reach.view(m, 1) * u[:, i], meet[:, 0] * u[:, i], w)[::-1]
    lane_mask = torch.cat((_mask(m, 1, dev), used.repeat_interleave(2, 1)), 1)
    sockets = torch.cat((reach.view(m, 1, 1) * u, beta.unsqueeze(-1)), -1)
    mid = 0.5 * (radius + reach).view(m, 1, 1) * u
    arm_rects = _rect(
        mid[..., 0], mid[..., 1], beta, 0.5 * (reach - radius).view(m, 1).expand(m, 4),
        h.view(m, 1).expand(m, 4),
    )  # fmt: skip
    rects = torch.cat((_rect(z, z, z, outer, outer).unsqueeze(1), arm_rects), 1)
    return Block(
        curbs, curb_mask, _pad_points(lanes, ring.shape[1]), lane_mask, sockets, used, rects,
        torch.cat((_mask(m, 1, dev), used), 1),
    )  # fmt: skip


def median(cfg: NetworkConfig, w: Tensor, p: Tensor) -> Block:
    """A straight road round a median island (module doc)."""
    length, width, dev = p[:, 0], p[:, 1], p.device
    m, z = length.shape[0], torch.zeros_like(length)
    lead, taper = cfg.median_lead, cfg.median_taper
    x = torch.stack(
        (z, z + lead, z + lead + taper, length - lead - taper, length - lead, length), -1
    )  # [m, 6]
    widen = torch.tensor([0.0, 0.0, 1.0, 1.0, 0.0, 0.0], device=dev) * (0.5 * width).unsqueeze(-1)
    curb_y = (0.5 * w).unsqueeze(-1) + widen
    lane_y = (0.25 * w).unsqueeze(-1) + widen
    pts = lambda y: torch.stack((x, y), -1)  # noqa: E731
    island = torch.stack(
        (
            x[:, 2], -0.5 * width, x[:, 3], -0.5 * width, x[:, 3], 0.5 * width,
            x[:, 2], 0.5 * width,
        ),
        -1,
    ).view(m, 4, 2)  # fmt: skip
    curbs = torch.cat(
        (
            _polyline(pts(-curb_y)),
            _polyline(pts(curb_y)),
            torch.cat((island, island.roll(-1, 1)), -1),
        ),
        1,
    )
    lanes = [pts(-lane_y), pts(lane_y).flip(1)]
    sockets = torch.stack(
        (torch.stack((z, z, z + math.pi), -1), torch.stack((length, z, z), -1)), 1
    )
    rects = _rect(0.5 * length, z, z, 0.5 * length, 0.5 * (w + width)).unsqueeze(1)
    return Block(
        curbs, _mask(m, 14, dev), _pad_points(lanes, 6), _mask(m, 2, dev), sockets,
        _mask(m, 2, dev), rects, _mask(m, 1, dev),
    )  # fmt: skip


#: The generator of each block type, indexed by its ``block_type`` value.
GENERATORS = (straight, curve, crossing, t_junction, roundabout, median)
assert [g.__name__ for g in GENERATORS] == [
    "straight",
    "curve",
    "crossing",
    "t_junction",
    "roundabout",
    "median",
]
assert (STRAIGHT, CURVE, CROSSING, T_JUNCTION, ROUNDABOUT, MEDIAN) == tuple(range(6))


def generate(
    cfg: NetworkConfig, types: tuple[int, ...], kind: Tensor, w: Tensor, p: Tensor
) -> Block:
    """Blocks of type ``kind [m]`` (long, each one of ``types``) with road widths ``w [m]`` and
    parameters ``p [m, 3]``, padded to :func:`slot_sizes`. Each type's generator runs once, on
    all rows of that type (finding them reads their count on the host: a scene generator's
    step, never an env step's)."""
    m, dev = kind.shape[0], kind.device
    C, L, Q, S, F = slot_sizes(cfg)
    out = Block(
        torch.zeros(m, C, 4, device=dev),
        torch.zeros(m, C, dtype=torch.bool, device=dev),
        torch.zeros(m, L, Q, 2, device=dev),
        torch.zeros(m, L, dtype=torch.bool, device=dev),
        torch.zeros(m, S, 3, device=dev),
        torch.zeros(m, S, dtype=torch.bool, device=dev),
        torch.zeros(m, F, 6, device=dev),
        torch.zeros(m, F, dtype=torch.bool, device=dev),
    )
    for t in types:
        rows = (kind == t).nonzero().squeeze(-1)
        if rows.numel() == 0:
            continue
        b = _pad(GENERATORS[t](cfg, w[rows], p[rows]), (C, L, Q, S, F))
        for f in fields(Block):
            getattr(out, f.name)[rows] = getattr(b, f.name)
    return out


def _move(xy: Tensor, angle: Tensor, shift: Tensor, *, turn_only: bool = False) -> Tensor:
    """Points ``xy [m, ..., 2]`` rotated by ``angle [m]`` about the origin, then moved by
    ``shift [m, 2]`` (directions: ``turn_only``)."""
    extra = [1] * (xy.dim() - 2)
    c, s = torch.cos(angle).view(-1, *extra), torch.sin(angle).view(-1, *extra)
    x, y = xy[..., 0], xy[..., 1]
    out = torch.stack((c * x - s * y, s * x + c * y), -1)
    return out if turn_only else out + shift.view(-1, *extra, 2)


def moved_footprint(block: Block, angle: Tensor, shift: Tensor) -> Tensor:
    """The footprint rectangles ``[m, F, 6]`` of ``block`` moved as :func:`transform` moves it."""
    return torch.cat(
        (
            _move(block.rects[..., :2], angle, shift),
            _move(block.rects[..., 2:4], angle, shift, turn_only=True),
            block.rects[..., 4:],
        ),
        -1,
    ) * block.rect_mask.unsqueeze(-1)


def transform(block: Block, angle: Tensor, shift: Tensor) -> Block:
    """``block`` rotated by ``angle [m]`` [rad] about the origin, then moved by ``shift [m, 2]``."""
    m, C = block.curbs.shape[:2]
    curbs = _move(block.curbs.view(m, C, 2, 2), angle, shift).view(m, C, 4)
    heading = (block.sockets[..., 2] + angle.unsqueeze(-1)).unsqueeze(-1)
    sockets = torch.cat((_move(block.sockets[..., :2], angle, shift), heading), -1)
    return Block(
        curbs * block.curb_mask.unsqueeze(-1), block.curb_mask, _move(block.lanes, angle, shift),
        block.lane_mask, sockets * block.socket_mask.unsqueeze(-1), block.socket_mask,
        moved_footprint(block, angle, shift), block.rect_mask,
    )  # fmt: skip


def placement(block: Block, entry: Tensor, pose: Tensor) -> tuple[Tensor, Tensor]:
    """The rotation ``[m]`` [rad] and shift ``[m, 2]`` [m] (for :func:`transform`) that put
    ``block``'s socket ``entry [m]`` (long) at ``pose [m, 3]`` ``(x, y, heading)`` facing into
    the block along ``heading``: the socket's outward heading becomes ``heading + pi``, so a road
    end at ``pose`` facing out along ``heading`` joins it."""
    rows = torch.arange(entry.shape[0], device=entry.device)
    sock = block.sockets[rows, entry]  # [m, 3]
    angle = pose[:, 2] + math.pi - sock[:, 2]
    return angle, pose[:, :2] - _move(sock[:, :2], angle, pose[:, :2], turn_only=True)


def place(block: Block, entry: Tensor, pose: Tensor) -> Block:
    """``block`` moved by :func:`placement`."""
    return transform(block, *placement(block, entry, pose))
