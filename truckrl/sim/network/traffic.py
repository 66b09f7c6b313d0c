"""Moving traffic on a road network: cars and trucks as oriented boxes driving along lanes.

Every network of a batch holds up to ``M`` vehicles (slots; ``active`` marks the used ones),
each an oriented box ``length x width`` whose centre sits on a lane centre-line
(:attr:`~truckrl.sim.network.compose.Network.lanes`) at arc length ``s`` and faces along it.
One step (:func:`step_traffic`) moves all ``n x M`` vehicles with tensor ops only (no loop over
networks or vehicles, no host sync), in four parts:

1. **Car following**: the Intelligent Driver Model (Treiber, Hennecke and Helbing 2000,
   Phys. Rev. E 62, 1805) with desired speed ``v0`` (per vehicle), time gap ``time_gap``,
   least gap ``min_gap``, acceleration ``max_accel`` and comfortable deceleration
   ``comfort_decel``. The leader is the nearest of: the vehicle ahead on the same lane or on the
   lane it continues onto (bumper-to-bumper gap along the lanes); any other vehicle or ego box
   whose centre lies ahead in the vehicle's corridor (its width plus the other's, plus
   ``corridor_margin``, within ``look_ahead``); and the edge of a junction zone another vehicle
   occupies (below). Speeds stay in ``[0, v0]``.
2. **Junction yield**: each crossing, T-junction and roundabout is a zone, a disc round its
   centre reaching ``zone_margin`` beyond its road surface. A vehicle is in a zone when its
   centre is nearer than the zone's radius plus its half length. A vehicle may enter a zone
   only while no other vehicle and no ego box (the truck's tractor or trailer, its centre nearer
   than the zone's radius plus its half length) is in it and no vehicle of lower slot index
   enters it in the same step (one the safety filter holds anyway, or one that cannot reappear
   yet, enters nothing); otherwise it holds where it is (and the IDM has braked it towards the
   edge). Without the truck in the rule a car entered a junction the truck was
   crossing and stopped in its swept path, where the truck could not avoid it.
3. **Lane ends**: a vehicle passing its lane's end continues on the lane that starts there
   (the next block's lane across a joint); where none does (an open road end of the network, or
   an arm's in-lane ending on a roundabout ring) it leaves the road (``waiting``: no box, no
   segments) and reappears at rest at the start of the lane it was spawned on (its home lane),
   its box just inside the lane, as soon as the home lane's first ``length + min_gap`` is clear,
   no ego box (the truck's) reaches within ``appear_clearance`` of that spot (a truck cannot
   stop for a vehicle that appears a few metres before it) and the rules below let it.
   Nothing drives round a ring.
4. **Safety filter**: a vehicle's move is kept only if its new box (grown by ``safety_margin``)
   overlaps no other vehicle's box before or after the step and no ego box, and, of two
   vehicles whose new boxes would overlap, only the one of lower slot index may move; a held
   vehicle stops (``v = 0``). By induction from a spawn without overlaps, no two vehicles ever
   overlap.

:func:`traffic_segments` emits the boxes as 4 segments each, and :func:`with_traffic` appends
them to a scene's ``segments``/``mask``/``kind``, so today's LiDAR sees them and
:func:`~truckrl.sim.collision.truck_collides` reports touching one, unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import KIND_OBSTACLE, rectangle_segments
from truckrl.sim.network.compose import Network
from truckrl.sim.network.config import CROSSING, ROUNDABOUT, T_JUNCTION

#: Where a traffic config sits in the env config (the ``network`` task's ``env.task.traffic``),
#: the prefix of its fields in error messages.
WHERE = "env.task.traffic"


@dataclass
class TrafficConfig:
    """Traffic density, vehicle sizes and the driving rule's constants (module doc).

    Lengths in metres, speeds in m/s; ranges are drawn uniformly (density per network, sizes
    and desired speeds per vehicle).
    """

    max_vehicles: int = param(8, lo=0, hi=64, unit="-", doc="vehicle slots per network M")
    density: tuple[float, float] = param(
        (0.5, 2.0),
        lo=0.0,
        hi=20.0,
        unit="1/100 m",
        doc="vehicles per 100 m of lane, per network (capped by max_vehicles and free slots)",
    )
    truck_share: float = param(0.25, lo=0.0, hi=1.0, unit="-", doc="share of trucks")
    car_length: tuple[float, float] = param((4.0, 5.0), lo=1.0, hi=8.0, unit="m", doc="car length")
    car_width: tuple[float, float] = param((1.7, 2.0), lo=0.5, hi=3.0, unit="m", doc="car width")
    truck_length: tuple[float, float] = param(
        (8.0, 12.0), lo=2.0, hi=20.0, unit="m", doc="traffic truck length"
    )
    truck_width: tuple[float, float] = param(
        (2.3, 2.55), lo=0.5, hi=3.0, unit="m", doc="traffic truck width"
    )
    speed: tuple[float, float] = param(
        (5.0, 12.0), lo=0.0, hi=40.0, unit="m/s", doc="desired speed v0, per vehicle"
    )
    max_accel: float = param(
        1.5, lo=0.1, hi=10.0, unit="m/s^2", doc="IDM acceleration a", source="Treiber et al. 2000"
    )
    comfort_decel: float = param(
        2.0, lo=0.1, hi=10.0, unit="m/s^2", doc="IDM comfortable deceleration b",
        source="Treiber et al. 2000",
    )  # fmt: skip
    min_gap: float = param(
        2.0, lo=0.1, hi=20.0, unit="m", doc="IDM least bumper gap s0", source="Treiber et al. 2000"
    )
    time_gap: float = param(
        1.5, lo=0.0, hi=5.0, unit="s", doc="IDM time gap T", source="Treiber et al. 2000"
    )
    look_ahead: float = param(
        40.0, lo=1.0, hi=500.0, unit="m", doc="reach of the corridor and zone-edge leaders"
    )
    corridor_margin: float = param(
        0.5, lo=0.0, hi=5.0, unit="m", doc="added to the corridor's half width"
    )
    zone_margin: float = param(
        2.0, lo=0.0, hi=20.0, unit="m", doc="junction zone reach beyond its road surface"
    )
    safety_margin: float = param(
        0.1, lo=0.0, hi=2.0, unit="m", doc="growth of a box in the safety filter"
    )
    appear_clearance: float = param(
        30.0,
        lo=0.0,
        hi=1000.0,
        unit="m",
        doc="a vehicle reappears only where every ego box's end is at least this far",
    )

    def __post_init__(self) -> None:
        validate(self, WHERE)
        if self.max_vehicles > 0 and self.speed[1] <= 0.0:
            raise ConfigError(f"{WHERE}.speed = {list(self.speed)}: max must be > 0")

    def spacing(self) -> float:
        """Spawn slot pitch along a lane [m]: the longest vehicle plus ``min_gap`` plus 1 m."""
        return max(self.car_length[1], self.truck_length[1]) + self.min_gap + 1.0


@dataclass
class Traffic:
    """The traffic of ``n`` networks, ``M`` vehicle slots each (``P = K L`` lane slots)."""

    lanes: Tensor  # [n, P, Q, 2] the network's lane centre-lines [m]
    cum: Tensor  # [n, P, Q] arc length at each lane point [m]
    lane_len: Tensor  # [n, P] [m]
    pieces: Tensor  # [n, P] long: last non-empty piece of each lane
    successor: Tensor  # [n, P] long: the lane starting where a lane ends (-1: none)
    zone_centre: Tensor  # [n, K, 2] junction zones [m]
    zone_radius: Tensor  # [n, K] [m]
    zone_mask: Tensor  # [n, K]
    lane: Tensor  # [n, M] long: the lane each vehicle drives on
    home: Tensor  # [n, M] long: the lane it was spawned on (reappears there)
    s: Tensor  # [n, M] arc length of its centre along its lane [m]
    v: Tensor  # [n, M] speed [m/s], in [0, v0]
    v0: Tensor  # [n, M] desired speed [m/s]
    length: Tensor  # [n, M] [m]
    width: Tensor  # [n, M] [m]
    truck: Tensor  # [n, M] bool: a truck (else a car)
    active: Tensor  # [n, M] bool: the slot holds a vehicle
    waiting: Tensor  # [n, M] bool: off the network, waiting to reappear on its home lane

    def __len__(self) -> int:
        return self.s.shape[0]

    def present(self) -> Tensor:
        """``[n, M]`` bool: the vehicles on the road (active and not waiting)."""
        return self.active & ~self.waiting


# --------------------------------------------------------------------------------- geometry
def _take(t: Tensor, idx: Tensor) -> Tensor:
    """``t [n, P, ...]`` gathered along dim 1 by ``idx [n, M]``: ``[n, M, ...]``."""
    shape = (*idx.shape, *t.shape[2:])
    return torch.gather(t, 1, idx.view(*idx.shape, *([1] * (t.dim() - 2))).expand(shape))


def lane_points(traffic: Traffic, lane: Tensor, s: Tensor) -> tuple[Tensor, Tensor]:
    """Points ``[n, M, 2]`` [m] and headings ``[n, M]`` [rad] at arc lengths ``s [n, M]`` along
    lanes ``lane [n, M]`` (beyond a lane's ends: along its first or last piece)."""
    n, P, Q = traffic.cum.shape
    rows = torch.arange(n, device=lane.device).unsqueeze(1) * P + lane  # [n, M] flat lane rows
    cum = traffic.cum.reshape(n * P, Q)[rows]  # [n, M, Q]
    idx = torch.searchsorted(cum, s.unsqueeze(-1).contiguous(), right=True).squeeze(-1) - 1
    idx = torch.minimum(idx.clamp_min(0), traffic.pieces.reshape(-1)[rows])
    flat = rows * Q + idx
    pts, arc = traffic.lanes.reshape(-1, 2), traffic.cum.reshape(-1)
    p0, p1, c0, c1 = pts[flat], pts[flat + 1], arc[flat], arc[flat + 1]
    d = p1 - p0
    t = ((s - c0) / (c1 - c0).clamp_min(1e-9)).unsqueeze(-1)
    return p0 + t * d, torch.atan2(d[..., 1], d[..., 0])


def boxes(traffic: Traffic) -> Tensor:
    """The vehicles as boxes ``[n, M, 6]`` ``(cx, cy, cos, sin, half length, half width)``."""
    xy, heading = lane_points(traffic, traffic.lane, traffic.s)
    return _boxes(xy, heading, traffic.length, traffic.width)


def _boxes(xy: Tensor, heading: Tensor, length: Tensor, width: Tensor) -> Tensor:
    return torch.stack(
        (xy[..., 0], xy[..., 1], torch.cos(heading), torch.sin(heading), 0.5 * length, 0.5 * width),
        -1,
    )


def boxes_overlap(a: Tensor, b: Tensor, margin: float = 0.0) -> Tensor:
    """Whether box ``a [..., A, 6]`` overlaps box ``b [..., B, 6]`` (each grown by ``margin``
    [m] on every side): ``[..., A, B]`` bool, by the separating-axis test on the 4 edge normals
    (boxes that only touch do not overlap)."""
    a, b = a.unsqueeze(-2), b.unsqueeze(-3)
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    ua, la, wa = (a[..., 2], a[..., 3]), a[..., 4] + margin, a[..., 5] + margin
    ub, lb, wb = (b[..., 2], b[..., 3]), b[..., 4] + margin, b[..., 5] + margin
    apart = torch.zeros_like(dx, dtype=torch.bool)
    axes = ((ua[0], ua[1]), (-ua[1], ua[0]), (ub[0], ub[1]), (-ub[1], ub[0]))
    for ex, ey in axes:
        reach = (
            la * (ua[0] * ex + ua[1] * ey).abs()
            + wa * (-ua[1] * ex + ua[0] * ey).abs()
            + lb * (ub[0] * ex + ub[1] * ey).abs()
            + wb * (-ub[1] * ex + ub[0] * ey).abs()
        )
        apart = apart | ((dx * ex + dy * ey).abs() >= reach)
    return ~apart


def ego_boxes(tractor: tuple[Tensor, ...], trailer: tuple[Tensor, ...]) -> Tensor:
    """The truck's tractor and trailer (as :func:`~truckrl.sim.vehicle.truck_boxes` gives them:
    ``(cx, cy, heading, front, rear, half_width)`` each ``[n]``) as boxes ``[n, 2, 6]``."""
    out = []
    for cx, cy, heading, front, rear, half_width in (tractor, trailer):
        c, s = torch.cos(heading), torch.sin(heading)
        mid = 0.5 * (front - rear)
        out.append(
            torch.stack((cx + c * mid, cy + s * mid, c, s, 0.5 * (front + rear), half_width), -1)
        )
    return torch.stack(out, 1)


# ------------------------------------------------------------------------------------ setup
def junction_zones(net: Network, cfg: TrafficConfig) -> tuple[Tensor, Tensor, Tensor]:
    """Each junction block's zone (module doc): centres ``[n, K, 2]``, radii ``[n, K]`` and mask.

    A crossing's or T-junction's centre is the midpoint of its sockets 0 and 1 (the ends of its
    road 0 or bar); a roundabout's the mean of its sockets (evenly spaced arms). The radius
    covers the road surface there: a crossing's parallelogram corner ``(w / 2) sqrt(2 + 2 |cos
    a|) / sin a`` from its centre, a T-junction's square corner ``(w / 2) sqrt 2``, a
    roundabout's outer curb ``radius + w / 2``; plus ``zone_margin``."""
    t, p, w = net.block_type, net.block_params, net.road_width.unsqueeze(-1)
    sock, smask = net.sockets[..., :2], net.socket_mask.unsqueeze(-1)
    mid01 = 0.5 * (sock[:, :, 0] + sock[:, :, 1])
    mean = (sock * smask).sum(2) / smask.sum(2).clamp_min(1)
    centre = torch.where((t == ROUNDABOUT).unsqueeze(-1), mean, mid01)
    a = p[..., 0]
    cross = (
        0.5 * w * torch.sqrt(2.0 + 2.0 * torch.cos(a).abs()) / torch.sin(a).abs().clamp_min(1e-3)
    )
    radius = torch.where(
        t == CROSSING,
        cross,
        torch.where(t == T_JUNCTION, 0.5 * w * math.sqrt(2.0), p[..., 0] + 0.5 * w),
    )
    mask = net.block_mask & ((t == CROSSING) | (t == T_JUNCTION) | (t == ROUNDABOUT))
    return centre, (radius + cfg.zone_margin) * mask, mask


def lane_tables(net: Network) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Arc lengths ``[n, P, Q]``, lengths ``[n, P]``, last non-empty piece ``[n, P]``, the
    successor of each lane ``[n, P]`` (the usable lane whose start lies within 1 cm of its end,
    -1 where none) and which lanes are usable ``[n, P]`` (valid and not a roundabout ring)."""
    lanes = net.lanes
    step = (lanes[:, :, 1:] - lanes[:, :, :-1]).norm(dim=-1)  # [n, P, Q - 1]
    cum = torch.cat((torch.zeros_like(step[..., :1]), step.cumsum(-1)), -1)
    nonempty = step > 1e-6
    Qm1 = step.shape[-1]
    idx = torch.arange(Qm1, device=lanes.device)
    pieces = torch.where(nonempty, idx, -1).amax(-1).clamp_min(0)
    L = net.lanes.shape[1] // net.block_type.shape[1]
    ring = (_take(net.block_type, net.lane_block) == ROUNDABOUT) & (
        torch.arange(lanes.shape[1], device=lanes.device) % L == 0
    )
    usable = net.lane_mask & ~ring
    end = torch.gather(lanes, 2, (pieces + 1).view(*pieces.shape, 1, 1).expand(-1, -1, 1, 2))
    # [n, P (end), P (start)], per coordinate: contiguous pair tables from contiguous ends, the
    # same values as one [..., 2] table read through strided views at a fraction of the cost
    end_x, end_y = end[:, :, 0].movedim(-1, 0).contiguous()
    start_x, start_y = lanes[:, :, 0].movedim(-1, 0).contiguous()
    gap_x = end_x.unsqueeze(2) - start_x.unsqueeze(1)
    gap_y = end_y.unsqueeze(2) - start_y.unsqueeze(1)
    near = gap_x * gap_x + gap_y * gap_y < 1e-4  # within 1 cm (squared: no root per pair)
    near = near & usable.unsqueeze(1) & usable.unsqueeze(2)
    near = near & ~torch.eye(lanes.shape[1], dtype=torch.bool, device=lanes.device)
    successor = torch.where(near.any(-1), near.to(torch.uint8).argmax(-1), -1)
    return cum, cum[..., -1], pieces, successor, usable


def place_vehicles(
    net: Network,
    cfg: TrafficConfig,
    lane: Tensor,
    s: Tensor,
    length: Tensor,
    width: Tensor,
    v0: Tensor,
    active: Tensor | None = None,
    truck: Tensor | None = None,
) -> Traffic:
    """Traffic with vehicles exactly where given (all ``[n, M]``: lane slot, arc length of the
    centre [m], length, width [m], desired speed [m/s]), at rest; no overlap check (a scene
    built by hand, as a test's)."""
    cum, lane_len, pieces, successor, _ = lane_tables(net)
    centre, radius, zmask = junction_zones(net, cfg)
    z = torch.zeros_like(s)
    return Traffic(
        lanes=net.lanes, cum=cum, lane_len=lane_len, pieces=pieces, successor=successor,
        zone_centre=centre, zone_radius=radius, zone_mask=zmask, lane=lane, home=lane.clone(),
        s=s, v=z, v0=v0, length=length, width=width,
        truck=truck if truck is not None else length > cfg.car_length[1],
        active=active if active is not None else torch.ones_like(lane, dtype=torch.bool),
        waiting=torch.zeros_like(lane, dtype=torch.bool),
    )  # fmt: skip


def _lane_slots(lanes: Tensor, cum: Tensor, pieces: Tensor, s: Tensor) -> Tensor:
    """Points ``[n, P, J, 2]`` [m] at arc lengths ``s [n, P, J]`` along each of the lanes
    ``lanes [n, P, Q, 2]`` (arc lengths ``cum [n, P, Q]``, last non-empty piece ``pieces [n,
    P]``): :func:`lane_points` of every lane at ``J`` arc lengths, the same operations on the
    same values, without gathering a lane's arc lengths once per point."""
    n, P, J = s.shape
    idx = torch.searchsorted(cum, s.contiguous(), right=True) - 1
    idx = torch.minimum(idx.clamp_min(0), pieces.unsqueeze(-1))
    pts = idx.unsqueeze(-1).expand(n, P, J, 2)
    p0, p1 = lanes.gather(2, pts), lanes.gather(2, pts + 1)
    c0, c1 = cum.gather(2, idx), cum.gather(2, idx + 1)
    t = ((s - c0) / (c1 - c0).clamp_min(1e-9)).unsqueeze(-1)
    return p0 + t * (p1 - p0)


def spawn_traffic(
    net: Network,
    cfg: TrafficConfig,
    generator: torch.Generator | None = None,
    reserved: Tensor | None = None,
) -> Traffic:
    """Random traffic on ``net`` (all networks at once), at rest.

    Each usable lane is cut into slots ``cfg.spacing()`` long; a slot is free when its centre
    lies outside every junction zone and every reserved disc by half a slot. Each network draws
    a density and takes ``min(M, round(density x lane length / 100), free slots)`` free slots
    at random; a vehicle (a truck with odds ``truck_share``) sits centred in each. A vehicle
    whose box overlaps an earlier one's (curved lanes) is dropped, so no two overlap.

    Args:
        reserved: ``[n, R, 3]`` discs ``(x, y, radius)`` [m] no vehicle may occupy (a start and
            a goal pose with the truck's reach), or ``None``.
    """
    n, dev, M = len(net), net.lanes.device, cfg.max_vehicles
    cum, lane_len, pieces, successor, usable = lane_tables(net)
    centre, radius, zmask = junction_zones(net, cfg)

    def rand(*shape: int) -> Tensor:
        return torch.rand(*shape, generator=generator, device=dev)

    pitch = cfg.spacing()
    P = lane_len.shape[1]
    J = max(1, int((lane_len * usable).max() // pitch))  # setup step: one host read
    j = torch.arange(J, device=dev)
    slot_s = ((j + 0.5) * pitch).expand(n, P, J)
    ok = usable.unsqueeze(-1) & ((j + 1) * pitch <= lane_len.unsqueeze(-1))
    lanes = torch.arange(P, device=dev).view(1, P, 1).expand(n, P, J)
    probe = Traffic(
        lanes=net.lanes, cum=cum, lane_len=lane_len, pieces=pieces, successor=successor,
        zone_centre=centre, zone_radius=radius, zone_mask=zmask, lane=lanes.reshape(n, -1),
        home=lanes.reshape(n, -1), s=slot_s.reshape(n, -1), v=slot_s.reshape(n, -1),
        v0=slot_s.reshape(n, -1), length=slot_s.reshape(n, -1), width=slot_s.reshape(n, -1),
        truck=ok.reshape(n, -1), active=ok.reshape(n, -1), waiting=~ok.reshape(n, -1),
    )  # fmt: skip
    xy = _lane_slots(net.lanes, cum, pieces, slot_s).reshape(n, P * J, 2)
    ok = ok.reshape(n, -1)
    # contiguous coordinates: the pair tables below broadcast far faster than strided views
    x, y = (xy[..., i].contiguous().unsqueeze(2) for i in (0, 1))  # [n, P J, 1]
    cx, cy = (centre[..., i].contiguous().unsqueeze(1) for i in (0, 1))  # [n, 1, K]
    # a slot centre within half a slot of a disc (squared distances: no root per pair)
    gx, gy = x - cx, y - cy
    inside = gx * gx + gy * gy < (radius.unsqueeze(1) + 0.5 * pitch).square()
    ok = ok & ~(zmask.unsqueeze(1) & inside).any(-1)
    if reserved is not None and reserved.shape[1] > 0:
        rx, ry, rr = (reserved[..., i].contiguous().unsqueeze(1) for i in (0, 1, 2))
        gx, gy = x - rx, y - ry
        ok = ok & ~(gx * gx + gy * gy < (rr + 0.5 * pitch).square()).any(-1)
    total = (lane_len * usable).sum(1)
    density = cfg.density[0] + (cfg.density[1] - cfg.density[0]) * rand(n)
    want = (density * total / 100.0).round().long().clamp_max(M)
    score = torch.where(ok, rand(*ok.shape), -1.0)
    k = min(M, ok.shape[1])
    top, pick = score.topk(k, dim=1)
    if k < M:
        top = torch.cat((top, torch.full((n, M - k), -1.0, device=dev)), 1)
        pick = torch.cat((pick, torch.zeros(n, M - k, dtype=torch.long, device=dev)), 1)
    active = (top >= 0.0) & (torch.arange(M, device=dev) < want.unsqueeze(-1))
    u = rand(n, M, 4)
    truck = u[..., 0] < cfg.truck_share
    length = torch.where(
        truck,
        cfg.truck_length[0] + (cfg.truck_length[1] - cfg.truck_length[0]) * u[..., 1],
        cfg.car_length[0] + (cfg.car_length[1] - cfg.car_length[0]) * u[..., 1],
    )
    width = torch.where(
        truck,
        cfg.truck_width[0] + (cfg.truck_width[1] - cfg.truck_width[0]) * u[..., 2],
        cfg.car_width[0] + (cfg.car_width[1] - cfg.car_width[0]) * u[..., 2],
    )
    v0 = cfg.speed[0] + (cfg.speed[1] - cfg.speed[0]) * u[..., 3]
    traffic = replace(
        probe,
        lane=_take(probe.lane, pick),
        home=_take(probe.lane, pick),
        s=_take(probe.s, pick),
        v=torch.zeros(n, M, device=dev),
        v0=v0,
        length=length,
        width=width,
        truck=truck,
        active=active,
        waiting=torch.zeros_like(active),
    )
    # drop any vehicle overlapping an earlier one (boxes on curves may reach past their slot)
    hit = boxes_overlap(boxes(traffic), boxes(traffic), cfg.safety_margin)
    pair = hit & active.unsqueeze(1) & active.unsqueeze(2)
    earlier = torch.ones(M, M, dtype=torch.bool, device=dev).tril(-1)  # [i, j]: j < i
    traffic.active = active & ~(pair & earlier).any(-1)
    return traffic


# ------------------------------------------------------------------------------------- step
def _idm(cfg: TrafficConfig, v: Tensor, v0: Tensor, gap: Tensor, dv: Tensor) -> Tensor:
    """IDM acceleration [m/s^2] (module doc) at speed ``v``, desired ``v0``, bumper gap ``gap``
    [m] to the leader and closing speed ``dv`` [m/s] (``gap = inf``: free road)."""
    a, b = cfg.max_accel, cfg.comfort_decel
    free = 1.0 - (v / v0.clamp_min(1e-6)) ** 4
    want = cfg.min_gap + (v * cfg.time_gap + v * dv / (2.0 * math.sqrt(a * b))).clamp_min(0.0)
    return a * (free - (want / gap.clamp_min(1e-3)) ** 2)


def _points_t(tr: Traffic, lane: Tensor, s: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`lane_points` in the step's vehicle-major layout: ``lane``, ``s`` ``[M, n]`` give
    ``x``, ``y`` [m] and the heading [rad], each ``[M, n]`` (the same operations, so the same
    values)."""
    n, P, Q = tr.cum.shape
    rows = torch.arange(n, device=lane.device) * P + lane  # [M, n] flat lane rows
    cum = tr.cum.reshape(n * P, Q)[rows].contiguous()  # [M, n, Q]
    idx = torch.searchsorted(cum, s.unsqueeze(-1).contiguous(), right=True).squeeze(-1) - 1
    idx = torch.minimum(idx.clamp_min(0), tr.pieces.reshape(-1)[rows])
    flat = rows * Q + idx
    pts, arc = tr.lanes.reshape(-1, 2), tr.cum.reshape(-1)
    p0, p1, c0, c1 = pts[flat], pts[flat + 1], arc[flat], arc[flat + 1]
    d = p1 - p0
    t = ((s - c0) / (c1 - c0).clamp_min(1e-9)).unsqueeze(-1)
    xy = p0 + t * d
    return xy[..., 0], xy[..., 1], torch.atan2(d[..., 1], d[..., 0])


def _computed_once(*fields: Tensor) -> tuple[Tensor, ...]:
    """The same ``fields`` (float, each ``[F, n]``-shaped alike), computed into memory once,
    contiguous: a cumulative sum over a dimension of size 1 (exact), which a compiled step runs
    as a kernel of its own. Without it, inductor inlines the fields' gathers and trigonometry
    into every pair loop that reads them (``M`` times per vehicle, more with
    ``realize_opcount_threshold`` raised for the LiDAR, :mod:`truckrl.sim.compiled`), and lays
    the pair loops out along the fields' own ``[n, M]`` strides, ``M = 8`` innermost."""
    return tuple(torch.stack(fields, 0).unsqueeze(0).cumsum(0).squeeze(0).unbind(0))


def _overlap_t(a: tuple[Tensor, ...], b: tuple[Tensor, ...], margin: float) -> Tensor:
    """Whether boxes ``a`` (fields ``(cx, cy, cos, sin, half length, half width)``, each
    ``[A, 1, n]``) overlap boxes ``b`` (each ``[1, B, n]``), both grown by ``margin`` [m]:
    ``[A, B, n]`` bool. The separating-axis test of :func:`boxes_overlap` on the same 4 axes,
    written with the boxes' relative rotation ``|cos|``, ``|sin|`` shared by all four (a unit
    axis projects a box's own half extents exactly)."""
    ax, ay, ac, as_, al, aw = a
    bx, by, bc, bs, bl, bw = b
    al, aw, bl, bw = al + margin, aw + margin, bl + margin, bw + margin
    dx, dy = bx - ax, by - ay
    c = (ac * bc + as_ * bs).abs()
    s = (ac * bs - as_ * bc).abs()
    return (
        ((dx * ac + dy * as_).abs() < al + bl * c + bw * s)
        & ((dy * ac - dx * as_).abs() < aw + bl * s + bw * c)
        & ((dx * bc + dy * bs).abs() < bl + al * c + aw * s)
        & ((dy * bc - dx * bs).abs() < bw + al * s + aw * c)
    )


def step_traffic(
    traffic: Traffic, cfg: TrafficConfig, dt: float, ego: Tensor | None = None
) -> Traffic:
    """All vehicles one step of ``dt`` [s] on (module doc). ``ego``: ``[n, B, 6]`` boxes the
    vehicles treat as obstacles (:func:`ego_boxes` of the truck), or ``None``. Tensor ops only,
    no host sync.

    Computed vehicle-major: every ``[n, M]`` field is read as ``[M, n]`` and every pair table
    is ``[M, M, n]``, the networks innermost, so a compiled step runs its pair loops over
    contiguous rows of ``n`` (vectorised) rather than over rows of ``M = 8``."""
    tr = traffic
    n, M = tr.s.shape
    dev = tr.s.device
    lane, home, s, v, v0 = tr.lane.T, tr.home.T, tr.s.T, tr.v.T, tr.v0.T  # [M, n]
    length, width, act, waiting = tr.length.T, tr.width.T, tr.active.T, tr.waiting.T
    on = act & ~waiting
    x, y, heading = _points_t(tr, lane, s)
    my_len = torch.gather(tr.lane_len.T, 0, lane)
    succ = torch.gather(tr.successor.T, 0, lane)
    half = 0.5 * length
    hw = 0.5 * width
    # what the pair loops read, [M, n] in memory (floats: lane slots and flags are exact)
    x, y, c, sn, half, hw, width, s_p, v_p, len_p, lane_p, succ_p, on_p = _computed_once(
        x, y, torch.cos(heading), torch.sin(heading), half, hw, width, s, v, my_len,
        lane.float(), succ.float(), on.float(),
    )  # fmt: skip
    on_p = on_p > 0.5
    eye = torch.eye(M, dtype=torch.bool, device=dev).unsqueeze(-1)  # [i, j, 1]
    lower = torch.ones(M, M, dtype=torch.bool, device=dev).tril(-1).unsqueeze(-1)  # j < i
    other = on_p.unsqueeze(1) & on_p.unsqueeze(0) & ~eye  # [i, j, n] both on the road
    # ---- leaders along the lane: same lane ahead, or on the lane this one continues onto
    si, sj = s_p.unsqueeze(1), s_p.unsqueeze(0)  # [i, 1, n], [1, j, n]
    same = lane_p.unsqueeze(1) == lane_p.unsqueeze(0)
    ahead = torch.where(
        same & (sj > si), sj - si,
        torch.where(
            (succ_p.unsqueeze(1) == lane_p.unsqueeze(0)) & (succ_p.unsqueeze(1) >= 0),
            len_p.unsqueeze(1) - si + sj, math.inf,
        ),
    )  # fmt: skip
    lane_gap = (ahead - half.unsqueeze(1) - half.unsqueeze(0)).masked_fill(~other, math.inf)
    on_lane = torch.isfinite(ahead)
    # ---- anything else ahead in the corridor: other vehicles' and the ego's boxes
    o_ok = other & ~on_lane & ~same
    ox, oy, oc, os_, ol, ow = x, y, c, sn, half, hw
    v_obst = v_p
    if ego is not None:
        e = ego.permute(2, 1, 0)  # [6, B, n]
        ox, oy, oc, os_ = (torch.cat((a, b), 0) for a, b in zip((x, y, c, sn), e[:4], strict=True))
        ol, ow = torch.cat((half, e[4]), 0), torch.cat((hw, e[5]), 0)
        v_obst = torch.cat((v_p, torch.zeros_like(e[0])), 0)
        o_ok = torch.cat((o_ok, torch.ones(M, ego.shape[1], n, dtype=torch.bool, device=dev)), 1)
    ci, si_ = c.unsqueeze(1), sn.unsqueeze(1)
    oc, os_, ol, ow = oc.unsqueeze(0), os_.unsqueeze(0), ol.unsqueeze(0), ow.unsqueeze(0)
    dx, dy = ox.unsqueeze(0) - x.unsqueeze(1), oy.unsqueeze(0) - y.unsqueeze(1)
    fwd, lat = ci * dx + si_ * dy, -si_ * dx + ci * dy
    cos_rel, sin_rel = ci * oc + si_ * os_, -si_ * oc + ci * os_
    along = ol * cos_rel.abs() + ow * sin_rel.abs()
    across = ol * sin_rel.abs() + ow * cos_rel.abs()
    in_corridor = (
        o_ok
        & (fwd > 0.0)
        & (fwd < cfg.look_ahead)
        & (lat.abs() < 0.5 * width.unsqueeze(1) + across + cfg.corridor_margin)
    )
    corridor_gap = (fwd - half.unsqueeze(1) - along).masked_fill(~in_corridor, math.inf)
    v_along = v_obst.unsqueeze(0) * cos_rel
    # ---- junction zones: inside now, and the edge of a zone someone else occupies
    zcx, zcy, zr, zmask = _computed_once(
        tr.zone_centre[..., 0].T, tr.zone_centre[..., 1].T, tr.zone_radius.T, tr.zone_mask.T.float()
    )  # [Z, n]
    zcx, zcy, zmask = zcx.unsqueeze(0), zcy.unsqueeze(0), zmask.unsqueeze(0) > 0.5
    zd = torch.stack((x.unsqueeze(1) - zcx, y.unsqueeze(1) - zcy), -1).norm(dim=-1)  # [M, Z, n]
    reach = zr.unsqueeze(0) + half.unsqueeze(1)
    zm = zmask & on_p.unsqueeze(1)
    inside = zm & (zd < reach)
    held_by = inside.sum(0) > inside.long()  # [i, Z, n]: another vehicle is in
    if ego is not None:  # or the truck: its box's centre within the zone's radius + half length
        zd_e = torch.hypot(e[0].unsqueeze(1) - zcx, e[1].unsqueeze(1) - zcy)  # [B, Z, n]
        ego_in = (zmask & (zd_e < zr.unsqueeze(0) + e[4].unsqueeze(1))).any(0)  # [Z, n]
        held_by = held_by | ego_in.unsqueeze(0)
    toward = (zcx - x.unsqueeze(1)) * c.unsqueeze(1) + (zcy - y.unsqueeze(1)) * sn.unsqueeze(1)
    zone_ahead = zm & ~inside & held_by & (toward > 0.0) & (zd - reach < cfg.look_ahead)
    zone_gap = (zd - reach).masked_fill(~zone_ahead, math.inf).amin(1)
    # ---- IDM towards the nearest leader
    gaps = torch.cat((lane_gap, corridor_gap, zone_gap.unsqueeze(1)), 1)
    lead_v = torch.cat(
        (v_p.unsqueeze(0).expand(M, M, n), v_along, torch.zeros_like(zone_gap).unsqueeze(1)), 1
    )
    gap, k = gaps.min(1)
    dv = v - torch.gather(lead_v, 1, k.unsqueeze(1)).squeeze(1)
    acc = _idm(cfg, v, v0, gap, torch.where(torch.isfinite(gap), dv, 0.0))
    v_new = torch.minimum((v + acc * dt).clamp_min(0.0), v0)
    # ---- move, continue onto the successor lane, or leave and reappear on the home lane
    s_new = s + v_new * dt
    past = on & (s_new > my_len)
    leaving = past & (succ < 0)  # off the network: waits, then reappears
    appear = act & waiting  # tries to reappear at its home lane's start
    lane_new = torch.where(past & (succ >= 0), succ, torch.where(leaving | appear, home, lane))
    s_new = torch.where(
        past & (succ >= 0), s_new - my_len, torch.where(leaving | appear, half, s_new)
    )
    there = (on & ~leaving) | appear  # the vehicles on the road after the move
    # reappearing needs the home lane's first length + min_gap clear of other vehicles
    on_home = (lane_p.unsqueeze(0) == home.float().unsqueeze(1)) & on_p.unsqueeze(0) & ~eye
    tail = (s_p - half).unsqueeze(0)  # [1, j, n] rear of each vehicle along its lane
    crowded = (on_home & (tail < (length + cfg.min_gap).unsqueeze(1))).any(1)
    xn, yn, hn = _points_t(tr, lane_new, s_new)
    xn, yn, cn, snn = _computed_once(xn, yn, torch.cos(hn), torch.sin(hn))
    if ego is not None:  # nor where the truck is near: it could not stop for it
        gap = torch.hypot(xn.unsqueeze(1) - e[0].unsqueeze(0), yn.unsqueeze(1) - e[1].unsqueeze(0))
        crowded = crowded | (gap < e[4].unsqueeze(0) + cfg.appear_clearance).any(1)
    # ---- safety filter (module doc), the parts that hold a vehicle whatever the others do
    g = cfg.safety_margin
    new_i = tuple(f.unsqueeze(1) for f in (xn, yn, cn, snn, half, hw))
    hit_now = (
        _overlap_t(new_i, tuple(f.unsqueeze(0) for f in (x, y, c, sn, half, hw)), g)
        & on_p.unsqueeze(0)
        & ~eye
    )
    stuck = hit_now.any(1) | (appear & crowded)
    if ego is not None:
        stuck = stuck | _overlap_t(new_i, tuple(f.unsqueeze(0) for f in e), g).any(1)
    # ---- junction yield: enter a zone only when it is empty and no lower slot enters it; a
    # vehicle held anyway is no rival (one waiting to reappear at a lane start inside a zone
    # would otherwise hold every higher slot at that zone for as long as it waits: a gridlock)
    zd_new = torch.stack((xn.unsqueeze(1) - zcx, yn.unsqueeze(1) - zcy), -1).norm(dim=-1)
    enters = zmask & there.unsqueeze(1) & (zd_new < reach) & ~inside  # [M, Z, n]
    going = (enters & ~stuck.unsqueeze(1)).long()
    rival = going.cumsum(0) > going  # a lower slot enters the same zone
    wait = (enters & (held_by | rival)).any(1)
    both = there.unsqueeze(1) & there.unsqueeze(0) & ~eye
    hit_new = _overlap_t(new_i, tuple(f.unsqueeze(0) for f in (xn, yn, cn, snn, half, hw)), g)
    hit_new = hit_new & both
    blocked = (stuck | wait) & there
    # i moves only if, for every j its new box meets, i < j or j is held anyway
    lose = (hit_new & ~(lower.transpose(0, 1) | blocked.unsqueeze(0))).any(1)
    hold = ~act | blocked | lose
    return replace(
        tr,
        lane=torch.where(hold, lane, lane_new).T,
        s=torch.where(hold, s, s_new).T,
        v=torch.where(hold | leaving | appear, 0.0, v_new).T,
        waiting=torch.where(hold, waiting, leaving).T,
    )


# --------------------------------------------------------------------------------- segments
def traffic_segments(traffic: Traffic) -> tuple[Tensor, Tensor]:
    """The vehicles' outlines: ``[n, 4 M, 4]`` segments [m] (4 per box) and their mask."""
    xy, heading = lane_points(traffic, traffic.lane, traffic.s)
    half = 0.5 * traffic.length
    seg = rectangle_segments(xy[..., 0], xy[..., 1], heading, half, half, 0.5 * traffic.width)
    n, M = traffic.s.shape
    mask = traffic.present().repeat_interleave(4, 1)
    # computed into memory once (_computed_once): the LiDAR and collision loops read every
    # segment once per beam or truck box, and would recompute its lane point and trigonometry
    (seg,) = _computed_once(seg.reshape(n, 4 * M, 4) * mask.unsqueeze(-1))
    return seg, mask


def with_traffic(
    segments: Tensor, mask: Tensor, kind: Tensor, traffic: Traffic
) -> tuple[Tensor, Tensor, Tensor]:
    """A scene's ``segments [n, E, 4]``, ``mask [n, E]`` and ``kind [n, E]`` with the vehicles'
    outlines appended (``E + 4 M`` slots, kind ``KIND_OBSTACLE``): what LiDAR and collision
    read."""
    seg, m = traffic_segments(traffic)
    k = torch.full(m.shape, KIND_OBSTACLE, dtype=kind.dtype, device=kind.device)
    return torch.cat((segments, seg), 1), torch.cat((mask, m), 1), torch.cat((kind, k), 1)


__all__ = [
    "Traffic",
    "TrafficConfig",
    "boxes",
    "boxes_overlap",
    "ego_boxes",
    "junction_zones",
    "lane_points",
    "lane_tables",
    "place_vehicles",
    "spawn_traffic",
    "step_traffic",
    "traffic_segments",
    "with_traffic",
]
