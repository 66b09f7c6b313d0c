"""Episodes of the ``network`` task: a chain of link and junction blocks, a route along it
through the junctions, start and goal poses on its lane centre-lines, and traffic.

Everything is batched over episodes (tensor ops over all rows; the loops run over the chain's
``K`` block indices, over redraw rounds and over the few block types, never over episodes), pure
torch, with all randomness from one ``torch.Generator``.

The chain
---------
``K = 2 J + 1`` blocks, ``J`` the most junctions any curriculum level routes through
(:attr:`CurriculumConfig.junctions`): links ``L_0, J_1, L_1, ..., J_J, L_J`` alternate, a
**link** (straight, curve or median: the ``network.block_types`` among them; the goal's link
``L_J`` never a curve where another link type is allowed) entered at its socket 0 and left at
its socket 1, a **junction** (crossing, T-junction or roundabout) entered
at a random socket and left at a random other one. Blocks are drawn and joined by
:func:`truckrl.sim.network.compose.grow` (overlap rejection as for random networks).

The route
---------
The chain read from the start of ``L_0`` to the end of ``L_J``, on the right-hand lane (``w / 4``
right of each road's centre-line in the direction of travel): on a link its forward lane; at a
crossing or T-junction straight through, the lane; at a turn, the entry lane up to ``setback``
before the corner where it meets the exit lane, a quadratic Bezier curve round the corner
(control point the corner) and the exit lane on (the network has no turning lanes; the setback
shrinks to ``0.9`` of the shorter leg where a leg is shorter); at a roundabout the entry lane up
to the ring's centre-line, counter-clockwise along it and out along the exit lane. The route
polyline is resampled to ``route.points`` points evenly spaced in arc length.

Start and goal (the feasibility rule)
--------------------------------------
Poses are the tractor rear axle on a lane centre-line facing along it, trailer aligned. The
**start on link** ``L_i`` (``i < J``) has its rear axle ``rear + start_margin`` along the lane
from the link's entry (``rear``: the truck's extent behind its rear axle), the **goal** on
``L_J`` its rear axle ``front + goal_margin`` before the chain's end (``front``: the extent
ahead). The curriculum (:meth:`~truckrl.tasks.network.task.NetworkTask.on_reset`) picks the start on ``L_{J-j}`` for a
route through ``j`` junctions. A chain is kept when every one of these poses

* touches no curb (:func:`~truckrl.sim.collision.truck_collides_sparse` on the curb window of its
  route stretch, below: every curb the truck can touch is in it),
* keeps its tractor and trailer boxes outside every junction zone (a disc
  :func:`~truckrl.sim.network.traffic.junction_zones`, reaching ``zone_margin`` beyond the
  junction's road surface),
* and the goal lies ``min_goal_gap`` or more along the route beyond every start;

and the chain has all ``K`` blocks, and no stretch of its route has more than ``window_size``
curbs in reach (below, "Curb windows"). Other chains are redrawn, up to ``rounds`` times (a
round with fewer open episodes than ``round_chains`` draws several chains for each, the first
kept wins: the same distribution in fewer rounds); a chain still failing is kept and marked
(``info["feasible"] = 0``; how often at the defaults: docs/networks.md, "The network task").
The rule thins some shapes out: curves are fewer among the kept links than among the drawn (the
goal's link is never one, and a straight truck on a tight curve touches its curb), and so are
roundabouts among the junctions (two near each other fill a window).

Curb windows
------------
The route is cut into ``window_chunks`` stretches; each holds the curb slots within the LiDAR
range plus ``window_slack`` of it (:func:`route_windows`), at most ``window_size``. The step's
LiDAR and collision read only the window of the stretch the truck's rear axle projects onto
(and every vehicle): the same ranges and contacts as all curbs of the chain while the LiDAR's
origin (the tractor's centre, a few metres ahead of the rear axle) stays within
``window_slack`` of that stretch (a curb farther from the origin than the LiDAR range is never
seen), at a fraction of the cost. A truck that leaves the road through an open road end and
drives farther than that from the route may miss far curbs in its LiDAR.
``tests/tasks/network/test_network_windows.py`` checks the windows against every curb of the
chain by brute force.

Traffic
-------
:func:`~truckrl.sim.network.traffic.spawn_traffic` on the chain with the start options in use and
the goal reserved (a disc round the truck's footprint midpoint, radius half its length plus
``traffic_clearance``), then a uniform draw per vehicle (``keep_draw``): the curriculum keeps a
vehicle where its draw is below the level's traffic share.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.collision import truck_collides_sparse
from truckrl.sim.geometry import wrap_angle
from truckrl.sim.network.compose import Network, block_params, grow, socket_count
from truckrl.sim.network.config import (
    BLOCK_NAMES,
    CROSSING,
    CURVE,
    MEDIAN,
    ROUNDABOUT,
    STRAIGHT,
    T_JUNCTION,
    NetworkConfig,
)
from truckrl.sim.network.traffic import (
    Traffic,
    TrafficConfig,
    junction_zones,
    place_vehicles,
    spawn_traffic,
)
from truckrl.sim.roads import first_valid, scene_device, uniform
from truckrl.sim.vehicle import truck_boxes, truck_extents

#: Block types a link may be (entered at socket 0, left at socket 1).
LINK_TYPES: tuple[int, ...] = (STRAIGHT, CURVE, MEDIAN)
#: Block types a junction may be (entered and left at any two different sockets).
JUNCTION_TYPES: tuple[int, ...] = (CROSSING, T_JUNCTION, ROUNDABOUT)
#: |heading change| [rad] at a junction below which the route counts as going straight on
#: (about 20 deg); beyond it a left (> 0) or right (< 0) turn.
STRAIGHT_TURN = math.radians(20.0)
#: Per-episode metadata keys (``state["route"]``, :mod:`truckrl.tasks.network.bins`): the
#: route's junctions and blocks, block types on it (0 / 1 each), turns at its junctions
#: (counts), vehicles and their density [1 / 100 m of lane], the curriculum level, whether the
#: chain met the feasibility rule, and the route's length from start to goal [m].
INFO_KEYS: tuple[str, ...] = (
    "junctions",
    "blocks",
    *(f"has_{name}" for name in BLOCK_NAMES),
    "turns_straight",
    "turns_left",
    "turns_right",
    "vehicles",
    "traffic_density",
    "level",
    "feasible",
    "route_length",
)
#: Traffic state keys (:class:`~truckrl.sim.network.traffic.Traffic` fields, prefixed
#: ``tr_``); ``lane``, ``s``, ``v`` and ``waiting`` change every step.
TRAFFIC_FIELDS: tuple[str, ...] = (
    "lanes",
    "cum",
    "lane_len",
    "pieces",
    "successor",
    "zone_centre",
    "zone_radius",
    "zone_mask",
    "lane",
    "home",
    "s",
    "v",
    "v0",
    "length",
    "width",
    "truck",
    "active",
    "waiting",
)


@dataclass
class RouteConfig:
    """The route polyline and what the observation shows of it (``env.task.route.*``)."""

    points: int = param(
        128, lo=2, hi=4096, unit="-", doc="route polyline points, evenly spaced in arc length"
    )
    setback: float = param(
        12.0,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="a turn's Bezier curve starts and ends this far from the lanes' corner",
    )
    ahead: int = param(
        4, lo=1, hi=64, unit="-", doc="route points observed ahead of the truck (x, y each)"
    )
    spacing: float = param(
        10.0, lo=0.1, hi=200.0, unit="m", doc="arc length between the observed route points"
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.route")


@dataclass
class CurriculumConfig:
    """The scene's complexity by difficulty (``env.task.curriculum.*``): level ``i`` holds from
    ``difficulty[i]`` on (the largest ``difficulty[i] <= d`` picks it); a route through
    ``junctions[i]`` junctions (so ``2 junctions[i] + 1`` blocks) and ``traffic[i]`` of the
    spawned vehicles. The tolerances shrink with difficulty as in every task."""

    difficulty: tuple[float, ...] = param(
        (0.0, 0.5, 1.0, 1.5, 2.0, 3.0), lo=0.0, hi=30.0, min_len=1, unit="-",
        doc="difficulty where each level starts (increasing, first 0)",
    )  # fmt: skip
    junctions: tuple[int, ...] = param(
        (1, 1, 1, 1, 2, 2), lo=0, hi=16, min_len=1, unit="-",
        doc="junctions on the route at each level (the chain has 2 max + 1 blocks)",
    )  # fmt: skip
    traffic: tuple[float, ...] = param(
        (0.0, 0.0, 0.5, 0.5, 0.5, 1.0), lo=0.0, hi=1.0, min_len=1, unit="-",
        doc="share of the spawned vehicles kept at each level",
    )  # fmt: skip
    distance: tuple[float, ...] = param(
        (40.0, 80.0, 120.0, 0.0, 0.0, 0.0), lo=0.0, hi=10_000.0, min_len=1, unit="m",
        doc="route arc length from the start to the goal at each level (0: the whole route)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate(self, "env.task.curriculum")
        d = self.difficulty
        sizes = (len(self.junctions), len(self.traffic), len(self.distance))
        if any(size != len(d) for size in sizes):
            raise ConfigError(
                f"env.task.curriculum: difficulty, junctions, traffic and distance must have one "
                f"value per level, got {len(d)}, {sizes[0]}, {sizes[1]} and {sizes[2]}"
            )
        if d[0] != 0.0 or any(b <= a for a, b in zip(d[:-1], d[1:], strict=True)):
            raise ConfigError(
                f"env.task.curriculum.difficulty = {list(d)}: must start at 0 and increase"
            )

    @property
    def max_junctions(self) -> int:
        return max(self.junctions)

    @property
    def starts(self) -> tuple[tuple[int, float], ...]:
        """Each level's ``(junctions, distance)``: what places its start."""
        return tuple(zip(self.junctions, self.distance, strict=True))


@dataclass
class NetworkSceneConfig:
    """Chain, route, start and goal, traffic (``env.task.*``; module doc)."""

    start_margin: float = param(
        2.0, lo=0.0, hi=100.0, unit="m", doc="the start's trailer rear this far into its link"
    )
    goal_margin: float = param(
        5.0, lo=0.0, hi=100.0, unit="m", doc="the goal's front bumper this far before the end"
    )
    min_goal_gap: float = param(
        5.0, lo=0.0, hi=1000.0, unit="m", doc="goal at least this far along the route past a start"
    )
    traffic_clearance: float = param(
        2.0, lo=0.0, hi=50.0, unit="m", doc="no vehicle spawns this near a start or goal footprint"
    )
    start_step: float = param(
        4.0, lo=0.1, hi=100.0, unit="m",
        doc="arc length between the candidate starts of a level with a distance",
    )  # fmt: skip
    start_tries: int = param(
        8, lo=0, hi=64, unit="-",
        doc="candidate starts each side of a level's distance before its link's start option",
    )  # fmt: skip
    rounds: int = param(16, lo=1, hi=256, unit="-", doc="draws of a chain that breaks the rule")
    copies: int = param(
        1, lo=1, hi=64, unit="-", doc="chains drawn per episode and round (the first kept wins)"
    )
    round_chains: int = param(
        64, lo=1, hi=100_000, unit="-",
        doc="chains a round draws at least: more copies per episode when few are open",
    )  # fmt: skip
    window_chunks: int = param(
        32, lo=1, hi=4096, unit="-", doc="stretches of the route with a curb window of their own"
    )
    window_size: int = param(
        96, lo=1, hi=100_000, unit="segments",
        doc="curbs a window holds at most (a chain with a fuller one is redrawn)",
    )  # fmt: skip
    window_slack: float = param(
        10.0, lo=0.0, hi=1000.0, unit="m",
        doc="windows hold every curb the LiDAR can reach from this far off the route",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate(self, "env.task")


@dataclass
class Chain:
    """Drawn episodes before the curriculum (:func:`generate_episodes`), ``n`` rows."""

    network: Network  # not compacted: segments [n, K C, 4]
    traffic: Traffic
    keep_draw: Tensor  # [n, M] uniform: the curriculum keeps a vehicle below its share
    route_points: Tensor  # [n, R, 2] resampled route [m]
    route_cum: Tensor  # [n, R] its arc length [m]
    turn: Tensor  # [n, K] heading change at each junction [rad] (links: 0)
    window: Tensor  # [n, chunks, window_size] int32: curb slots each route stretch may reach
    window_valid: Tensor  # [n, chunks, window_size] bool
    start_options: Tensor  # [n, J + 1, 3] start pose on link L_i (only those in use checked)
    level_starts: Tensor  # [n, V, 3] the start of each curriculum level (level_start)
    level_blocks: Tensor  # [n, V] long: the block each level's start lies on
    level_past: Tensor  # [n, V] bool: the start lies on the exit arm of the junction after it
    goal: Tensor  # [n, 3]
    feasible: Tensor  # [n] bool


# ------------------------------------------------------------------------------- the chain
def _types(cfg: NetworkConfig, allowed: tuple[int, ...], what: str, dev) -> Tensor:
    types = [BLOCK_NAMES.index(t) for t in cfg.block_types if BLOCK_NAMES.index(t) in allowed]
    if not types:
        names = [BLOCK_NAMES[t] for t in allowed]
        raise ConfigError(
            f"env.task.network.block_types = {list(cfg.block_types)}: needs a {what} ({names})"
        )
    return torch.tensor(types, device=dev)


def draw_chain(cfg: NetworkConfig, junctions: int, n: int, rand, dev) -> Network:
    """``n`` chains of ``2 junctions + 1`` alternating link and junction blocks (module doc),
    not compacted."""
    K = 2 * junctions + 1
    net_cfg = replace(cfg, num_blocks=(K, K))
    links = _types(cfg, LINK_TYPES, "link", dev)
    joints = _types(cfg, JUNCTION_TYPES, "junction", dev)
    # the goal's link is straight (or a median) where the block types allow: on a curve the
    # trailer trails the lane tangent by about L_ka / R (tens of degrees), beyond the tolerance
    # of difficulty 2.5 on
    straight = links[links != CURVE]
    last = straight if straight.numel() else links
    types = tuple(sorted(set(links.tolist()) | set(joints.tolist())))
    width = uniform(cfg.road_width, rand(n))
    heading = 2.0 * math.pi * rand(n)

    def draw(k: int, rows: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        u = rand(rows, 6)
        table = (last if k == K - 1 else links) if k % 2 == 0 else joints
        kind = table[(u[:, 0] * len(table)).long().clamp_max(len(table) - 1)]
        params = block_params(net_cfg, kind, u[:, 3:])
        if k % 2 == 0:
            zero = torch.zeros(rows, dtype=torch.long, device=dev)
            return kind, params, zero, zero + 1
        count = socket_count(kind, params)
        entry = (u[:, 1] * count).long().clamp_max(count - 1)
        return kind, params, entry, u[:, 2]

    target = torch.full((n,), K, dtype=torch.long, device=dev)
    network, _ = grow(net_cfg, types, width, heading, target, draw, cfg.rounds)
    return network


# ------------------------------------------------------------------------------- the route
def _right(heading: Tensor) -> Tensor:
    """Right-hand unit normals ``[..., 2]`` of headings ``[...]``."""
    return torch.stack((torch.sin(heading), -torch.cos(heading)), -1)


def _unit(heading: Tensor) -> Tensor:
    return torch.stack((torch.cos(heading), torch.sin(heading)), -1)


def _lerp(a: Tensor, b: Tensor, count: int) -> Tensor:
    """``count`` points from ``a`` to ``b`` ``[n, 2]``, both included: ``[n, count, 2]``."""
    f = torch.linspace(0.0, 1.0, count, device=a.device).view(1, count, 1)
    return a.unsqueeze(1) + f * (b - a).unsqueeze(1)


def _junction_route(net: Network, k: int, count: int, setback_max: float) -> tuple[Tensor, Tensor]:
    """Block ``k``'s route piece ``[n, count, 2]`` (module doc; junctions only, other rows are
    meaningless; a turn's Bezier curve starts ``setback_max`` [m] or less before the corner) and
    its heading change [rad] ``[n]``."""
    n, dev = net.block_type.shape[0], net.block_type.device
    rows = torch.arange(n, device=dev)
    w = net.road_width
    entry = net.sockets[rows, k, net.entry[:, k].clamp_min(0)]  # [n, 3]
    exit_ = net.sockets[rows, k, net.exit[:, k].clamp_min(0)]
    d_in, d_out = entry[:, 2] + math.pi, exit_[:, 2]
    p_in = entry[:, :2] + 0.25 * w.unsqueeze(-1) * _right(d_in)
    p_out = exit_[:, :2] + 0.25 * w.unsqueeze(-1) * _right(d_out)
    turn = wrap_angle(d_out - d_in)
    # crossing and T-junction: straight through, or a Bezier corner between the two lanes
    u, v = _unit(d_in), _unit(d_out)
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    safe = torch.where(cross.abs() < 1e-6, torch.ones_like(cross), cross)
    d = p_out - p_in
    a = (d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0]) / safe  # p_in -> corner along u
    b = (u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0]) / safe  # corner -> p_out along v
    corner = p_in + a.unsqueeze(-1) * u
    turning = (turn.abs() >= STRAIGHT_TURN) & (a > 0) & (b > 0)
    setback = torch.minimum(torch.full_like(a, setback_max), 0.9 * torch.minimum(a, b))
    start = corner - setback.unsqueeze(-1) * u
    end = corner + setback.unsqueeze(-1) * v
    f = torch.linspace(0.0, 1.0, count - 2, device=dev).view(1, -1, 1)
    bezier = (
        (1 - f) ** 2 * start.unsqueeze(1)
        + 2 * f * (1 - f) * corner.unsqueeze(1)
        + f**2 * end.unsqueeze(1)
    )
    bent = torch.cat((p_in.unsqueeze(1), bezier, p_out.unsqueeze(1)), 1)
    straight = _lerp(p_in, p_out, count)
    piece = torch.where(turning.view(n, 1, 1), bent, straight)
    # roundabout: in to the ring, counter-clockwise round it, out
    smask = net.socket_mask[:, k].unsqueeze(-1)
    centre = (net.sockets[:, k, :, :2] * smask).sum(1) / smask.sum(1).clamp_min(1)
    rho = net.block_params[:, k, 0]
    delta = torch.asin((0.25 * w / rho.clamp_min(1e-3)).clamp(max=1.0))
    phi_in = entry[:, 2] + delta
    sweep = torch.remainder(exit_[:, 2] - delta - phi_in, 2.0 * math.pi)
    g = torch.linspace(0.0, 1.0, count - 2, device=dev).view(1, -1)
    phi = phi_in.unsqueeze(-1) + sweep.unsqueeze(-1) * g
    ring = centre.unsqueeze(1) + rho.view(n, 1, 1) * torch.stack((phi.cos(), phi.sin()), -1)
    ring = torch.cat((p_in.unsqueeze(1), ring, p_out.unsqueeze(1)), 1)
    is_ring = (net.block_type[:, k] == ROUNDABOUT).view(n, 1, 1)
    return torch.where(is_ring, ring, piece), turn


def _cumulative(points: Tensor) -> Tensor:
    """Arc length ``[n, P]`` [m] at each point of polylines ``[n, P, 2]``."""
    step = (points[:, 1:] - points[:, :-1]).norm(dim=-1)
    return torch.cat((torch.zeros_like(step[:, :1]), step.cumsum(-1)), -1)


def point_at(points: Tensor, cum: Tensor, s: Tensor) -> tuple[Tensor, Tensor]:
    """Points ``[n, S, 2]`` and headings ``[n, S]`` at arc lengths ``s [n, S]`` along polylines
    ``points [n, P, 2]`` with arc lengths ``cum [n, P]`` (clamped to their ends; a zero-length
    piece takes the heading of the piece it belongs to, 0 where all are)."""
    P = points.shape[1]
    idx = torch.searchsorted(cum, s.contiguous(), right=True) - 1
    idx = idx.clamp(0, P - 2)
    c0, c1 = cum.gather(1, idx), cum.gather(1, idx + 1)
    p0 = points.gather(1, idx.unsqueeze(-1).expand(*idx.shape, 2))
    p1 = points.gather(1, (idx + 1).unsqueeze(-1).expand(*idx.shape, 2))
    t = ((s - c0) / (c1 - c0).clamp_min(1e-9)).clamp(0.0, 1.0).unsqueeze(-1)
    d = p1 - p0
    return p0 + t * d, torch.atan2(d[..., 1], d[..., 0])


def build_route(net: Network, cfg: RouteConfig) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The route of each chain (module doc).

    Returns:
        ``(dense [n, K Q', 2], dense_cum [n, K Q'], block_s [n, K + 1], turn [n, K],
        resampled [n, cfg.points, 2])``: the route as built from the blocks' pieces (lane
        vertices: on the lane centre-lines), its arc length, where each block begins along it,
        the heading change at each junction [rad] and the route resampled evenly.
    """
    n, K = net.block_type.shape
    L = net.lanes.shape[1] // K
    Q = net.lanes.shape[2]
    count = Q + 2
    pieces, turns = [], []
    for k in range(K):
        if k % 2 == 0:  # a link: its forward lane, padded by its last point
            lane = net.lanes[:, k * L]
            pieces.append(torch.cat((lane, lane[:, -1:].expand(n, 2, 2)), 1))
            turns.append(torch.zeros(n, device=lane.device))
        else:
            piece, turn = _junction_route(net, k, count, cfg.setback)
            pieces.append(piece)
            turns.append(turn)
    dense = torch.cat(pieces, 1)
    cum = _cumulative(dense)
    block_s = torch.cat((cum[:, ::count], cum[:, -1:]), 1)
    total = cum[:, -1:]
    f = torch.linspace(0.0, 1.0, cfg.points, device=dense.device).unsqueeze(0)
    resampled, _ = point_at(dense, cum, total * f)
    return dense, cum, block_s, torch.stack(turns, 1), resampled


def route_cumulative(points: Tensor) -> Tensor:
    """Arc length ``[n, R]`` [m] at each point of a route polyline ``[n, R, 2]``."""
    return _cumulative(points)


# --------------------------------------------------------------------------- curb windows
def chunk_pieces(points: int, chunks: int) -> int:
    """Route pieces per window stretch: ``ceil((points - 1) / chunks)``."""
    return max(1, -(-(points - 1) // chunks))


#: Integer type of the curb windows: half the bytes of int64 for a restart to copy, and an index
#: the compiled step gathers with as it is (from int16 it would convert it for every access).
WINDOW_DTYPE = torch.int32


#: Rows per block of :func:`route_windows`'s curb test.
WINDOW_ROWS = 32


def route_windows(
    points: Tensor,
    cum: Tensor,
    segments: Tensor,
    mask: Tensor,
    chunks: int,
    reach: float,
    size: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """The curbs each stretch of the route may see (module doc, "Curb windows").

    Stretch ``c`` holds the route pieces ``c G .. c G + G - 1`` (:func:`chunk_pieces`); it lies
    within half its arc length ``l`` of its chord's midpoint ``m``, so a sensor within
    ``reach - max_range`` of it sees only curbs within ``reach + l / 2`` of ``m``.

    Args:
        points, cum: the route ``[n, R, 2]`` and its arc length ``[n, R]`` [m].
        segments, mask: curbs ``[n, E, 4]`` and validity ``[n, E]``.
        reach: LiDAR range plus the slack off the route [m].
        size: slots per window (at most ``E``: then every curb fits).

    Returns:
        ``(window [n, chunks, size]`` (:data:`WINDOW_DTYPE`), ``valid [n, chunks, size],
        overflow [n])``: the curb slots of each window (valid first), which are real, and where
        a window would need more than ``size``.
    """
    n, R = cum.shape
    G = chunk_pieces(R, chunks)
    E, dev = segments.shape[1], cum.device
    first = (torch.arange(chunks, device=dev) * G).clamp_max(R - 1)
    last = (first + G).clamp_max(R - 1)
    mid = 0.5 * (points[:, first] + points[:, last])  # [n, chunks, 2]
    half = 0.5 * (cum[:, last] - cum[:, first])
    # the valid curbs first, in slot order (padding is never near): the test below runs, for
    # each block of rows, over the block's largest curb count instead of every slot
    order = torch.sort((~mask).to(torch.uint8), dim=-1, stable=True).indices
    count_valid = mask.sum(-1)
    size = min(size, E)  # a window of every curb at most
    window = torch.zeros(n, chunks, size + 1, dtype=WINDOW_DTYPE, device=dev)
    count = torch.empty(n, chunks, dtype=torch.long, device=dev)
    # blocks of rows: each block's [rows, chunks, V] pair tables stay in cache
    starts = range(0, n, WINDOW_ROWS)
    widths = torch.stack([c.max() for c in count_valid.split(WINDOW_ROWS)]).clamp_min(1)
    for r0, V in zip(starts, widths.tolist(), strict=True):  # a scene generator's host read
        rows = slice(r0, r0 + WINDOW_ROWS)
        slots = order[rows, :V]
        b = slots.shape[0]
        seg = segments[rows].gather(1, slots.unsqueeze(-1).expand(b, V, 4))
        # contiguous coordinate planes [b, 1, V] and in-place passes over the [b, chunks, V]
        # pair tables: the same operations on the same values, fewer tables allocated
        x0, y0, x1, y1 = seg.movedim(-1, 0).contiguous().unsqueeze(2)
        dx, dy = x1 - x0, y1 - y0
        length2 = (dx * dx + dy * dy).clamp_min(1e-12)
        ex, ey = mid[rows, :, :1] - x0, mid[rows, :, 1:] - y0
        t = (ex * dx).add_(ey * dy).div_(length2).clamp_(0, 1)
        # squared distances: a square root per pair costs more than the rest of the test
        fx, fy = ex.sub_(t * dx), ey.sub_(t.mul_(dy))
        near = fx.mul_(fx).add_(fy.mul_(fy)) <= (reach + half[rows].unsqueeze(-1)).square()
        near &= mask[rows].gather(1, slots).unsqueeze(1)  # [b, chunks, V]
        ranks = near.cumsum(-1)
        count[rows] = ranks[..., -1]
        # each near curb's slot to its rank among the near ones (in slot order), the rest and
        # any beyond the window's size to a spare column that is dropped
        rank = torch.where(near, ranks - 1, size).clamp_max(size)
        window[rows].scatter_(2, rank, slots.to(window.dtype).unsqueeze(1).expand(b, chunks, V))
    valid = torch.arange(size, device=dev) < count.unsqueeze(-1)
    return window[..., :size], valid, (count > size).any(-1)


def window_chunk(s: Tensor, total: Tensor, points: int, chunks: int) -> Tensor:
    """The route stretch (:func:`route_windows`) of arc length ``s [m, ...]`` [m] along routes
    of length ``total [m, 1...]`` resampled to ``points`` points: long, like ``s``."""
    piece = (s / total.clamp_min(1e-9) * (points - 1)).floor().long().clamp(0, points - 2)
    return (piece // chunk_pieces(points, chunks)).clamp_max(chunks - 1)


def window_scene(
    segments: Tensor, mask: Tensor, window: Tensor, valid: Tensor, rows: Tensor, chunk: Tensor
) -> tuple[Tensor, Tensor]:
    """The curbs of window ``chunk [m]`` (long) of the chains ``rows [m]`` (long): ``([m, W,
    4], [m, W])``, ``W`` the largest curb count among them (the windows' valid slots come
    first; a host read, for scene generation only)."""
    at = rows * window.shape[1] + chunk  # flat index_selects: far cheaper than two index tensors
    w = window.flatten(0, 1).index_select(0, at)
    v = valid.flatten(0, 1).index_select(0, at)
    cut = max(1, int(v.sum(-1).max()))
    w, v = w[:, :cut], v[:, :cut]
    flat = (rows.unsqueeze(-1) * segments.shape[1] + w).flatten()
    seg = segments.reshape(-1, 4).index_select(0, flat).view(*w.shape, 4)
    return seg, mask.reshape(-1).index_select(0, flat).view(w.shape) & v


# ----------------------------------------------------------------------- start, goal, checks
def box_disc_gap(box: tuple[Tensor, ...], centre: Tensor, radius: Tensor) -> Tensor:
    """Distance [m] from a box ``(cx, cy, heading, front, rear, half_width)`` (each ``[n]``;
    :func:`~truckrl.sim.vehicle.truck_boxes`) to discs ``centre [n, Z, 2]``, ``radius [n, Z]``:
    ``[n, Z]``, negative where they overlap."""
    cx, cy, heading, front, rear, half = (t.unsqueeze(-1) for t in box)
    dx, dy = centre[..., 0] - cx, centre[..., 1] - cy
    c, s = torch.cos(heading), torch.sin(heading)
    along, across = c * dx + s * dy, -s * dx + c * dy
    ox = (along - along.clamp(-rear, front)).abs()
    oy = (across - across.clamp(-half, half)).abs()
    return torch.hypot(ox, oy) - radius


def pose_ok(
    pose: Tensor,
    params: dict[str, Tensor],
    segments: Tensor,
    mask: Tensor,
    zones: tuple[Tensor, Tensor, Tensor],
) -> Tensor:
    """``[n]`` bool: a truck at ``pose [n, 3]`` (articulation 0) touches no curb ``segments [n,
    E, 4]`` (valid where ``mask [n, E]``) and keeps its tractor and trailer outside every
    junction zone ``(centre [n, Z, 2], radius [n, Z], valid [n, Z])``."""
    pose4 = torch.cat((pose, torch.zeros_like(pose[:, :1])), -1)
    free = ~truck_collides_sparse(pose4, params, segments, mask)
    centre, radius, zmask = zones
    tractor, trailer, _ = truck_boxes(pose4, params)
    for box in (tractor, trailer):
        free = free & ~((box_disc_gap(box, centre, radius) < 0.0) & zmask).any(-1)
    return free


def level_start(
    cfg: NetworkSceneConfig,
    dense: Tensor,
    cum: Tensor,
    link_s: Tensor,
    goal_s: Tensor,
    distance: tuple[float, ...],
    params: dict[str, Tensor],
    curbs: Callable[[Tensor, Tensor], tuple[Tensor, Tensor]],
    zones: tuple[Tensor, Tensor, Tensor],
    rows: Tensor,
) -> tuple[Tensor, Tensor]:
    """``V`` curriculum levels' starts: ``(s [n, V], pose [n, V, 3])``, their arc lengths
    along the route [m] and poses, searched on the chains ``rows`` (long; the others, to be
    redrawn, keep the option).

    For a level with ``distance`` 0, the start option of the level's first link (arc length
    ``link_s [n, V]``). Else the first of the candidates ``t, t + h, t - h, t + 2 h, t - 2 h,
    ...`` (``h = start_step``, ``start_tries`` each side; ``t = max(goal_s - distance,
    link_s)``) that lies between ``link_s`` and ``min_goal_gap`` before the goal ``goal_s [n]``
    and passes :func:`pose_ok`, the link's start option where none does; so the start is as
    feasible as the option: on the route's lane centre-line (``dense``, ``cum``: the route as
    built, on lane vertices), clear of curbs and junction zones, ``distance`` or up to
    ``start_tries h`` either side of it before the goal (farther only on the fallback).
    ``curbs(rows [m], s [m])`` gives the curbs ``([m, W, 4], [m, W])`` a pose at arc length
    ``s`` of the chains ``rows`` may touch. The levels are searched together: their candidates
    share each :func:`pose_ok` call.
    """
    n, dev = link_s.shape[0], cum.device
    xy, heading = point_at(dense, cum, link_s)
    out_s, out_pose = link_s.clone(), torch.cat((xy, heading.unsqueeze(-1)), -1)  # the options
    search = [v for v, d in enumerate(distance) if d > 0.0]
    if not search:
        return out_s, out_pose
    # the searched levels' (level, chain) pairs, level-major: pair v n + i
    B = len(search)
    d = torch.tensor([distance[v] for v in search], dtype=cum.dtype, device=dev)
    link = link_s[:, search]  # [n, B]
    target = torch.maximum(goal_s.unsqueeze(-1) - d, link)
    steps = [0] + [sign * k for k in range(1, cfg.start_tries + 1) for sign in (1, -1)]
    offsets = cfg.start_step * torch.tensor(steps, dtype=cum.dtype, device=dev)
    s = torch.cat((target.unsqueeze(-1) + offsets, link.unsqueeze(-1)), -1)  # [n, B, C + 1]
    xy, heading = point_at(dense, cum, s.view(n, -1))
    poses = torch.cat((xy, heading.unsqueeze(-1)), -1).view(n, B, -1, 3)
    gap = (goal_s - cfg.min_goal_gap).view(n, 1, 1)
    inside = (s >= link.unsqueeze(-1)) & (s <= gap)
    s, poses, inside = (t.transpose(0, 1).flatten(0, 1) for t in (s, poses, inside))
    C = len(steps)
    pick = torch.full((B * n,), C, dtype=torch.long, device=dev)  # the option
    pairs = (torch.arange(B, device=dev).unsqueeze(-1) * n + rows).flatten()
    # the candidates in groups of doubling size (1, 2, 4, ...), each group only on the pairs
    # whose earlier candidates all failed: a pair's later candidates are checked only where they
    # can change its pick, and about half of the candidates pass
    bounds = [0, 1]
    while bounds[-1] < C:
        bounds.append(min(C, 2 * bounds[-1] + 1))
    for first, last in zip(bounds[:-1], bounds[1:], strict=True):
        at = pairs[pick[pairs] == C]  # a scene generator's host read, never a step's
        if at.numel() == 0 or first >= last:
            break
        k = last - first
        rep = at.repeat_interleave(k)  # pair-major: candidates of a pair side by side
        cand = torch.arange(first, last, device=dev).repeat(at.numel())
        chain = rep % n
        sub = {key: v[chain] for key, v in params.items()}
        zone = tuple(z[chain] for z in zones)
        ok = inside[rep, cand] & pose_ok(poses[rep, cand], sub, *curbs(chain, s[rep, cand]), zone)
        ok = ok.view(-1, k)
        found = ok.any(-1)
        pick[at[found]] = first + ok.to(torch.uint8).argmax(-1)[found]
    every = torch.arange(B * n, device=dev)
    out_s[:, search] = s[every, pick].view(B, n).T
    out_pose[:, search] = poses[every, pick].view(B, n, 3).transpose(0, 1)
    return out_s, out_pose


def generate_episodes(
    cfg: NetworkSceneConfig,
    network: NetworkConfig,
    traffic: TrafficConfig,
    route: RouteConfig,
    levels: tuple[tuple[int, float], ...],
    params: dict[str, Tensor],
    generator: torch.Generator | None = None,
    device=None,
    reach: float = 60.0,
    level: int | None = None,
    vehicles: bool = True,
    settle: int | None = None,
) -> Chain:
    """``n`` episodes (module doc) for the trucks ``params {key: [n]}``, before the curriculum.

    ``levels``: each curriculum level's ``(junctions, distance)``
    (:attr:`CurriculumConfig.starts`); the chain has ``J = max`` junctions, the start options
    that the rule checks are those on the links ``L_{J - j}`` for each level's ``j``, and each
    level gets its start (:func:`level_start`; traffic avoids them all). ``reach``: the LiDAR
    range plus ``window_slack`` [m] (the curb windows').

    For episodes that start at one level only (an episode pool's refill):

    * ``level``: the one level whose start is searched; every other level gets its link's start
      option (so its start is not that level's, and traffic avoids only the starts as placed).
      ``None``: every level's.
    * ``vehicles=False``: no vehicle is placed (every slot empty, the lane tables as drawn), for
      a level that keeps none.
    * ``settle``: the rounds stop once this many rows pass the rule (the others keep a failing
      chain, marked); ``None``: every row.

    The chains, routes and the searched starts do not depend on these (a row's chain is the
    same where the rounds reach it); the random numbers of the vehicles do.
    """
    dev, params = scene_device(params, generator, device)
    n = next(iter(params.values())).shape[0]
    settle = n if settle is None else max(1, min(settle, n))

    front, rear, _ = truck_extents(params)
    todo = torch.ones(n, dtype=torch.bool, device=dev)
    chain: Chain | None = None
    for _ in range(cfg.rounds):
        rows = todo.nonzero().squeeze(-1)  # a scene generator's host read, never a step's
        if rows.numel() == 0 or n - rows.numel() >= settle:
            break
        # each open episode draws `copies` chains (copy j of row i at j m + i), more when few
        # are open: a round's fixed cost is that of a few dozen chains, so the last few open
        # episodes are settled in one round instead of one round per redraw
        copies = max(cfg.copies, -(-cfg.round_chains // rows.numel()))
        many = rows.repeat(copies)
        sub = {k: v[many] for k, v in params.items()}
        fresh = _one_round(
            cfg, network, traffic, route, levels, sub, front[many], rear[many], generator, dev,
            reach, level, vehicles,
        )  # fmt: skip
        ok, pick = first_valid(fresh.feasible.view(copies, rows.numel()))
        if copies > 1:  # one copy: pick is every row in order, and the chains are kept as drawn
            fresh = _take(fresh, pick)
        if chain is None:
            chain = fresh  # round 0 holds every row
        else:
            _assign(chain, rows, fresh)
        todo[rows] = ~ok
    return chain


def _take(chain: Chain, rows: Tensor) -> Chain:
    """The rows ``rows`` of ``chain``."""

    def pick(obj):
        return replace(obj, **{k: v[rows] for k, v in vars(obj).items() if isinstance(v, Tensor)})

    return replace(pick(chain), network=pick(chain.network), traffic=pick(chain.traffic))


def _assign(chain: Chain, rows: Tensor, fresh: Chain) -> None:
    """Rows ``rows`` of ``chain`` (in place) from ``fresh`` (``len(rows)`` rows)."""
    for obj, new in (
        (chain.network, fresh.network),
        (chain.traffic, fresh.traffic),
        (chain, fresh),
    ):
        for name, value in vars(obj).items():
            if isinstance(value, Tensor):
                value[rows] = getattr(new, name)


def _one_round(
    cfg, network, traffic, route, levels, params, front, rear, generator, dev, reach, level,
    vehicles,
) -> Chain:  # fmt: skip
    """One draw of :func:`generate_episodes` for ``n`` trucks, feasibility marked."""
    n = front.shape[0]
    J = max(j for j, _ in levels)
    used = sorted({J - j for j, _ in levels})  # the links a level's route may start on

    def rand(*shape: int) -> Tensor:
        return torch.rand(*shape, generator=generator, device=dev)

    net = draw_chain(network, J, n, rand, dev)
    dense, cum, block_s, turn, points = build_route(net, route)
    zones = junction_zones(net, traffic)
    # a start option on every link L_0 .. L_J (blocks 0, 2, ...), the goal on L_J
    s_start = block_s[:, 0 : 2 * J + 1 : 2] + (rear + cfg.start_margin).unsqueeze(-1)
    s_goal = block_s[:, -1] - front - cfg.goal_margin
    s_pose = torch.cat((s_start, s_goal.unsqueeze(-1)), 1)
    xy, heading = point_at(dense, cum, s_pose)
    poses = torch.cat((xy, heading.unsqueeze(-1)), -1)  # [n, J + 2, 3]
    checked = [*used, J + 1]
    route_cum = route_cumulative(points)
    window, valid, overflow = route_windows(
        points, route_cum, net.segments, net.mask, cfg.window_chunks, reach, cfg.window_size
    )
    feasible = (net.num_blocks == 2 * J + 1) & ~overflow
    feasible = feasible & (s_goal >= s_start[:, used].amax(-1) + cfg.min_goal_gap)
    # a pose's checks read the curb window of its route stretch, which holds every curb the
    # truck can touch while its footprint (the farthest point ``reach_truck`` from the rear
    # axle, on the route within a resampled piece ``step`` of the stretch) lies within the
    # windows' reach; every curb of the chain otherwise (a tiny LiDAR range). A chain whose
    # window overflows is redrawn whatever its poses.
    total = cum[:, -1:]
    R = points.shape[1]
    step = (total[:, 0] / (R - 1)).amax()
    reach_truck = torch.hypot(torch.maximum(front, rear), truck_extents(params)[2]).amax()
    windowed = bool(reach_truck + 2.0 * step <= reach)  # a scene generator's host read

    def curbs(rows: Tensor, s: Tensor) -> tuple[Tensor, Tensor]:
        if not windowed:
            return net.segments[rows], net.mask[rows]
        chunk = window_chunk(s, total[rows, 0], R, cfg.window_chunks)
        return window_scene(net.segments, net.mask, window, valid, rows, chunk)

    # every checked pose of every chain in one call (pose-major: pose c of chain i at c n + i)
    chain = torch.arange(n, device=dev).repeat(len(checked))
    sub = {key: v[chain] for key, v in params.items()}
    at = poses[:, checked].transpose(0, 1).flatten(0, 1)
    s_at = s_pose[:, checked].T.flatten()
    ok = pose_ok(at, sub, *curbs(chain, s_at), tuple(z[chain] for z in zones))
    feasible = feasible & ok.view(len(checked), n).all(0)
    kept = feasible.nonzero().squeeze(-1)  # a scene generator's host read, never a step's
    keys = list(dict.fromkeys(levels))  # each distinct (junctions, distance) once, in order
    link_s = torch.stack([s_start[:, J - j] for j, _ in keys], 1)
    searched = keys if level is None else [levels[level]]
    distances = tuple(d if (j, d) in searched else 0.0 for j, d in keys)
    found_s, found_pose = level_start(
        cfg, dense, cum, link_s, s_goal, distances, params, curbs, zones, kept
    )
    found = {key: (found_s[:, v], found_pose[:, v]) for v, key in enumerate(keys)}
    level_s = torch.stack([found[key][0] for key in levels], 1)  # [n, V]
    level_starts = torch.stack([found[key][1] for key in levels], 1)  # [n, V, 3]
    # the link each start lies on (an arc length in a junction's piece counts to the link
    # before it), never before the level's first link
    first = torch.tensor([2 * (J - j) for j, _ in levels], device=dev)
    inside = (torch.searchsorted(block_s.contiguous(), level_s, right=True) - 1).clamp(0, 2 * J)
    level_blocks = torch.maximum(inside - inside % 2, first)
    # a start in a junction's piece lies outside its disc, so on its entry arm or past its
    # manoeuvre on the exit arm: past where its arc length exceeds that of the piece's point
    # nearest the disc's centre (inside the disc: between the arms)
    K, count = block_s.shape[1] - 1, dense.shape[1] // (block_s.shape[1] - 1)
    near = (dense.view(n, K, count, 2) - zones[0].unsqueeze(2)).norm(dim=-1).argmin(-1)
    s_centre = cum.view(n, K, count).gather(2, near.unsqueeze(-1)).squeeze(-1)  # [n, K]
    level_past = (inside % 2 == 1) & (level_s > s_centre.gather(1, inside))
    # traffic: the start options in use, each level's start and the goal reserved
    mid = 0.5 * (front - rear)
    sel = torch.cat((poses[:, checked], torch.stack([v[1] for v in found.values()], 1)), 1)
    centre = sel[..., :2] + mid.view(n, 1, 1) * _unit(sel[..., 2])
    radius = (0.5 * (front + rear) + cfg.traffic_clearance).view(n, 1).expand(n, sel.shape[1])
    reserved = torch.cat((centre, radius.unsqueeze(-1)), -1)
    if vehicles:
        tr = spawn_traffic(net, traffic, generator, reserved)
        keep = rand(n, traffic.max_vehicles)
    else:  # every slot empty and never kept; the lane tables as drawn (a state may get a
        # vehicle by hand, set_state)
        M = traffic.max_vehicles
        zero, one = torch.zeros(n, M, device=dev), torch.ones(n, M, device=dev)
        lane = torch.zeros(n, M, dtype=torch.long, device=dev)
        tr = place_vehicles(net, traffic, lane, zero, one, one, one, active=zero.bool())
        keep = one
    return Chain(
        network=net,
        traffic=tr,
        keep_draw=keep,
        route_points=points,
        route_cum=route_cum,
        window=window,
        window_valid=valid,
        turn=turn,
        start_options=poses[:, : J + 1],
        level_starts=level_starts,
        level_blocks=level_blocks,
        level_past=level_past,
        goal=poses[:, J + 1],
        feasible=feasible,
    )
