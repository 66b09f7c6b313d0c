"""Road networks: blocks joined socket to socket, overlaps rejected, padded for the batch.

A network is a chain of up to ``K`` blocks (``K = num_blocks[1]``): block 0's entry socket sits
at the origin, facing into it along a random heading; block ``k + 1``'s entry socket sits on
block ``k``'s exit socket (:func:`~truckrl.sim.network.blocks.place`), so curbs meet end to end.
A junction's other sockets stay open road ends, as the roads of today's scenes end.

Growing (:func:`random_network`), all networks of the batch at once, one block index at a time:
each network draws ``rounds`` candidates for its next block (type, shape, entry and exit socket)
and keeps the first whose footprint does not overlap any of its earlier blocks'; a network whose
candidates all overlap ends there (``num_blocks`` is then below its drawn target, the way
MetaDrive's block composition gives up after its tries). Blocks overlap where their footprint
rectangles do (:func:`rects_overlap`), each padded by ``clearance / 2`` all round, so the roads
of two blocks keep ``clearance`` apart; a block and its parent (the block it joins) are tested
with their rectangles padded across but shortened by ``socket_slack`` along instead, so their
joint is no overlap.

The output (:class:`Network`) has the scene layout the env's collision and LiDAR read:
``segments [n, E, 4]`` (zero where padding), ``mask [n, E]`` and ``kind [n, E]`` (all curbs),
with ``E`` the batch's largest count of valid segments (:func:`compact`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from truckrl.sim.geometry import KIND_CURB
from truckrl.sim.network.blocks import (
    Block,
    generate,
    moved_footprint,
    placement,
    slot_sizes,
    transform,
)
from truckrl.sim.network.config import (
    BLOCK_NAMES,
    CROSSING,
    ROUNDABOUT,
    SOCKETS,
    T_JUNCTION,
    NetworkConfig,
)
from truckrl.sim.roads import first_valid, uniform


@dataclass
class Network:
    """``n`` road networks of up to ``K`` blocks (``L``, ``Q``, ``S``: lane, point and socket
    slots per block, :func:`~truckrl.sim.network.blocks.slot_sizes`)."""

    segments: Tensor  # [n, E, 4] curbs (x0, y0, x1, y1) [m], zero where padding
    mask: Tensor  # [n, E] bool validity
    kind: Tensor  # [n, E] int8, KIND_CURB
    segment_block: Tensor  # [n, E] long: the block a segment belongs to (-1: padding)
    lanes: Tensor  # [n, K L, Q, 2] lane centre-lines [m] in the direction of travel
    lane_mask: Tensor  # [n, K L]
    lane_block: Tensor  # [n, K L] long: the block of each lane slot
    block_type: Tensor  # [n, K] long: index into BLOCK_NAMES (-1 where absent)
    block_params: Tensor  # [n, K, 3] (blocks.PARAM_NAMES)
    block_mask: Tensor  # [n, K]
    sockets: Tensor  # [n, K, S, 3] road ends (x, y, outward heading) [m, rad]
    socket_mask: Tensor  # [n, K, S]
    entry: Tensor  # [n, K] long: the socket joined to the previous block (block 0: the start)
    exit: Tensor  # [n, K] long: the socket the next block joins (-1: none)
    road_width: Tensor  # [n] [m]
    num_blocks: Tensor  # [n] long

    def __len__(self) -> int:
        return self.segments.shape[0]


#: Candidates a redraw round of :func:`grow` tests at least: where fewer networks are open, each
#: takes its next several candidates at once (the same first fitting one, in fewer rounds).
ROUND_CANDIDATES = 32


def rects_overlap(
    a: Tensor, b: Tensor, a_mask: Tensor, b_mask: Tensor, pad: float, slack: float
) -> Tensor:
    """Whether any rectangle of ``a [M, A, 6]`` overlaps any of ``b [M, B, 6]`` in the same row
    (rectangles ``(cx, cy, ux, uy, half length, half width)``), each widened by ``pad`` and
    shortened by ``slack`` [m] at both ends: ``[M]`` bool. Separating-axis test on the 4 edge
    normals, run only on the pairs whose bounding circles meet (finding them reads their count
    on the host); rectangles that only touch do not overlap; masked ones (``False``) never do."""
    M, dev = a.shape[0], a.device
    if a.shape[1] == 0 or b.shape[1] == 0:
        return torch.zeros(M, dtype=torch.bool, device=dev)

    def grown(r: Tensor) -> Tensor:
        return torch.cat((r[..., :4], (r[..., 4:5] - slack).clamp_min(0.0), r[..., 5:6] + pad), -1)

    a, b = grown(a), grown(b)
    ra = torch.hypot(a[..., 4], a[..., 5]).unsqueeze(-1)
    rb = torch.hypot(b[..., 4], b[..., 5]).unsqueeze(-2)
    gx = b[..., 0].unsqueeze(-2) - a[..., 0].unsqueeze(-1)
    gy = b[..., 1].unsqueeze(-2) - a[..., 1].unsqueeze(-1)
    # squared distances: a square root per pair costs more than the rest of the cull
    near = a_mask.unsqueeze(-1) & b_mask.unsqueeze(-2) & (gx * gx + gy * gy < (ra + rb).square())
    row, i, j = near.nonzero(as_tuple=True)
    cx, cy, ux, uy, la, wa = a[row, i].unbind(-1)
    dx, dy, vx, vy, lb, wb = b[row, j].unbind(-1)
    dx, dy = dx - cx, dy - cy
    apart = torch.zeros_like(dx, dtype=torch.bool)
    for ex, ey in ((ux, uy), (-uy, ux), (vx, vy), (-vy, vx)):
        reach = (
            la * (ux * ex + uy * ey).abs()
            + wa * (-uy * ex + ux * ey).abs()
            + lb * (vx * ex + vy * ey).abs()
            + wb * (-vy * ex + vx * ey).abs()
        )
        apart = apart | ((dx * ex + dy * ey).abs() >= reach)
    out = torch.zeros(M, dtype=torch.bool, device=dev)
    out[row[~apart]] = True
    return out


def block_params(cfg: NetworkConfig, kind: Tensor, u: Tensor) -> Tensor:
    """Random shape parameters ``[m, 3]`` of blocks of type ``kind [m]`` from ``u [m, 3]``
    uniform in ``[0, 1)`` (:data:`~truckrl.sim.network.blocks.PARAM_NAMES`; a curve turns left
    where ``u[:, 2] < 0.5``)."""
    lo, hi = cfg.roundabout_arms
    arms = (lo + (u[:, 1] * (hi - lo + 1)).floor()).clamp(lo, hi)
    turn = torch.where(u[:, 2] < 0.5, 1.0, -1.0)
    table = torch.stack(
        (
            torch.stack((uniform(cfg.straight_length, u[:, 0]), 0 * u[:, 0], 0 * u[:, 0]), -1),
            torch.stack(
                (
                    uniform(cfg.curve_radius, u[:, 0]),
                    turn * uniform(cfg.curve_angle, u[:, 1]),
                    0 * u[:, 0],
                ),
                -1,
            ),
            torch.stack(
                (
                    uniform(cfg.crossing_angle, u[:, 0]),
                    uniform(cfg.junction_arm, u[:, 1]),
                    0 * u[:, 0],
                ),
                -1,
            ),
            torch.stack((uniform(cfg.junction_arm, u[:, 0]), 0 * u[:, 0], 0 * u[:, 0]), -1),
            torch.stack(
                (
                    uniform(cfg.roundabout_radius, u[:, 0]),
                    arms,
                    uniform(cfg.roundabout_arm, u[:, 2]),
                ),
                -1,
            ),
            torch.stack(
                (
                    uniform(cfg.median_length, u[:, 0]),
                    uniform(cfg.median_width, u[:, 1]),
                    0 * u[:, 0],
                ),
                -1,
            ),
        ),
        1,
    )  # [m, types, 3]
    return table[torch.arange(kind.shape[0], device=kind.device), kind]


def socket_count(kind: Tensor, params: Tensor) -> Tensor:
    """Sockets of blocks of type ``kind [m]`` with parameters ``params [m, 3]`` (a roundabout
    has one per arm): ``[m]`` long."""
    counts = torch.tensor(SOCKETS, device=kind.device)[kind]
    return torch.where(kind == ROUNDABOUT, params[:, 1].round().long(), counts)


def pick_socket(open_: Tensor, u: Tensor) -> Tensor:
    """The ``floor(u * count)``-th ``True`` of each row of ``open_ [m, S]`` (``count`` its number
    of ``True``), ``u [m]`` in ``[0, 1)``: ``[m]`` long (0 where a row has none)."""
    count = open_.sum(-1)
    rank = (u * count).floor().long().clamp_max((count - 1).clamp_min(0))
    hit = open_ & (open_.long().cumsum(-1) - 1 == rank.unsqueeze(-1))
    return hit.long().argmax(-1)


def grow(
    cfg: NetworkConfig,
    types: tuple[int, ...],
    width: Tensor,
    heading: Tensor,
    target: Tensor,
    draw,
    rounds: int,
) -> tuple[Network, Tensor]:
    """Chains of blocks, one block index at a time (module doc).

    Args:
        cfg: ranges and slot counts.
        types: the block types ``draw`` may return (each is generated for every candidate).
        width: ``[n]`` road width [m]; ``heading``: ``[n]`` block 0's heading [rad].
        target: ``[n]`` long, blocks wanted (at most ``cfg.num_blocks[1]``).
        draw: ``draw(k, rows)`` -> ``(kind [rows] long, params [rows, 3], entry [rows] long,
            exit [rows])``: block ``k``'s candidates for ``rows = rounds * n`` (round ``j`` of
            network ``i`` in row ``j n + i``); ``exit`` is a socket index (long) or a draw in
            ``[0, 1)`` (float) picking one of the sockets other than the entry.
        rounds: candidates per block.

    Returns:
        The networks (not yet compacted) and ``overlapped [n, K]``: where block ``k`` was wanted
        but every candidate overlapped an earlier block.
    """
    n, dev, K = width.shape[0], width.device, cfg.num_blocks[1]
    C, L, Q, S, F = slot_sizes(cfg)
    pose = torch.cat((torch.zeros(n, 2, device=dev), heading.unsqueeze(-1)), -1)
    alive = torch.ones(n, dtype=torch.bool, device=dev)
    rects = torch.zeros(n, 0, 6, device=dev)
    rect_mask = torch.zeros(n, 0, dtype=torch.bool, device=dev)
    kept: list[tuple[Block, Tensor, Tensor, Tensor, Tensor, Tensor]] = []
    overlapped = []
    every = torch.arange(n, device=dev)
    for k in range(K):
        R = 1 if k == 0 else rounds
        kind, params, entry, exit_ = draw(k, R * n)
        # candidates are generated and tested round by round, each round only for the networks
        # whose earlier candidates all overlapped: the same first fitting candidate as testing
        # all R at once (round 0's where none fits), at the cost of about one round. Where few
        # networks are open, a round takes their next several candidates at once (at least
        # ROUND_CANDIDATES in all): a round's fixed cost is that of dozens of candidates
        first = torch.zeros(n, dtype=torch.long, device=dev)
        ok = torch.zeros(n, dtype=torch.bool, device=dev)
        rows = every
        j = 0
        while j < R:
            if j > 0:
                rows = (~ok).nonzero().squeeze(-1)  # a scene generator's host read
                if rows.numel() == 0:
                    break
            m = rows.numel()
            c = 1 if j == 0 else min(R - j, -(-ROUND_CANDIDATES // m))
            # candidate j + i of open network rows[r] in row i m + r
            net = rows.repeat(c)
            cand = (j + torch.arange(c, device=dev).repeat_interleave(m)) * n + net
            block_j = generate(cfg, types, kind[cand], width[net], params[cand])
            angle_j, shift_j = placement(block_j, entry[cand], pose[net])
            exit_j = exit_[cand]
            if exit_j.is_floating_point():
                others = block_j.socket_mask & (
                    torch.arange(S, device=dev).unsqueeze(0) != entry[cand].unsqueeze(-1)
                )
                exit_j = pick_socket(others, exit_j)
            # against its parent: shortened by socket_slack at the ends, so the joint is no
            # overlap; against older blocks: padded by clearance / 2 all round
            fp, F0 = moved_footprint(block_j, angle_j, shift_j), rects.shape[1] - F
            hit = rects_overlap(
                fp, rects[net, F0:], block_j.rect_mask, rect_mask[net, F0:],
                0.5 * cfg.clearance, cfg.socket_slack,
            ) | rects_overlap(
                fp, rects[net, :F0], block_j.rect_mask, rect_mask[net, :F0],
                0.5 * cfg.clearance, -0.5 * cfg.clearance,
            )  # fmt: skip
            if j == 0:  # round 0 fills every network (kept where no round fits)
                block, angle, shift, exits = block_j, angle_j, shift_j, exit_j
                ok = ~hit
                j = 1
                continue
            fit, src = first_valid(~hit.view(c, m))  # the first fitting of each open network
            won, src = rows[fit], src[fit]
            for f in fields(Block):
                getattr(block, f.name)[won] = getattr(block_j, f.name)[src]
            angle[won], shift[won], exits[won] = angle_j[src], shift_j[src], exit_j[src]
            first[won] = j + src // m
            ok[won] = True
            j += c
        row = first * n + every
        wanted = alive & (k < target)
        placed = wanted & ok
        overlapped.append(wanted & ~ok)
        # only the kept candidate of each network is moved whole
        block = transform(block, angle, shift)
        kept.append((block, kind[row], params[row], entry[row], exits, placed))
        rects = torch.cat((rects, block.rects), 1)
        rect_mask = torch.cat((rect_mask, block.rect_mask & placed.unsqueeze(-1)), 1)
        pose = block.sockets[every, exits]
        alive = placed
    blocks, kinds, params, entries, exits, placed = zip(*kept, strict=True)
    present = torch.stack(placed, 1)  # [n, K]
    nxt = torch.cat((present[:, 1:], torch.zeros(n, 1, dtype=torch.bool, device=dev)), 1)
    curb_mask = torch.stack([b.curb_mask for b in blocks], 1) & present.unsqueeze(-1)
    segments = torch.stack([b.curbs for b in blocks], 1) * curb_mask.unsqueeze(-1)
    block_index = torch.arange(K, device=dev).view(1, K, 1).expand(n, K, C)
    lane_mask = torch.stack([b.lane_mask for b in blocks], 1) & present.unsqueeze(-1)
    network = Network(
        segments=segments.reshape(n, K * C, 4),
        mask=curb_mask.reshape(n, K * C),
        kind=torch.full((n, K * C), KIND_CURB, dtype=torch.int8, device=dev),
        segment_block=torch.where(curb_mask, block_index, -1).reshape(n, K * C),
        lanes=torch.stack([b.lanes for b in blocks], 1).reshape(n, K * L, Q, 2),
        lane_mask=lane_mask.reshape(n, K * L),
        lane_block=torch.arange(K, device=dev).repeat_interleave(L).expand(n, K * L).clone(),
        block_type=torch.where(present, torch.stack(kinds, 1), -1),
        block_params=torch.stack(params, 1) * present.unsqueeze(-1),
        block_mask=present,
        sockets=torch.stack([b.sockets for b in blocks], 1),
        socket_mask=torch.stack([b.socket_mask for b in blocks], 1) & present.unsqueeze(-1),
        entry=torch.where(present, torch.stack(entries, 1), -1),
        exit=torch.where(nxt, torch.stack(exits, 1), -1),
        road_width=width,
        num_blocks=present.sum(1),
    )
    return network, torch.stack(overlapped, 1)


def compact(network: Network) -> Network:
    """``network`` with each row's valid segments first (in their order) and the segment slots
    trimmed to the batch's largest count. Reads that count on the host: a scene generator's
    step, never an env step's."""
    order = torch.sort((~network.mask).to(torch.uint8), dim=1, stable=True).indices
    keep = max(1, int(network.mask.sum(1).max()))
    idx = order[:, :keep]

    def take(t: Tensor) -> Tensor:
        return torch.gather(
            t, 1, idx.view(*idx.shape, *([1] * (t.dim() - 2))).expand(-1, -1, *t.shape[2:])
        )

    return Network(
        **{
            f.name: take(getattr(network, f.name))
            if f.name in ("segments", "mask", "kind", "segment_block")
            else getattr(network, f.name)
            for f in fields(Network)
        }
    )


def random_network(
    cfg: NetworkConfig, n: int, generator: torch.Generator | None = None, device=None
) -> Network:
    """``n`` random networks (module doc): block count from ``num_blocks``, types uniform over
    ``block_types``, shapes uniform in their ranges, a random entry socket at junctions and a
    random exit among the others. All randomness from ``generator`` (same seed, same networks,
    on its device)."""
    dev = generator.device if generator is not None else torch.device(device or "cpu")

    def rand(*shape: int) -> Tensor:
        return torch.rand(*shape, generator=generator, device=dev)

    types = tuple(BLOCK_NAMES.index(t) for t in cfg.block_types)
    table = torch.tensor(types, device=dev)
    lo, hi = cfg.num_blocks
    target = (lo + (rand(n) * (hi - lo + 1)).floor().long()).clamp(lo, hi)
    width = uniform(cfg.road_width, rand(n))
    heading = 2.0 * math.pi * rand(n)

    def draw(k: int, rows: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        u = rand(rows, 6)
        kind = table[(u[:, 0] * len(types)).long().clamp_max(len(types) - 1)]
        params = block_params(cfg, kind, u[:, 3:])
        junction = (kind == CROSSING) | (kind == T_JUNCTION) | (kind == ROUNDABOUT)
        count = socket_count(kind, params)
        entry = torch.where(junction, (u[:, 1] * count).long().clamp_max(count - 1), 0)
        return kind, params, entry, u[:, 2]

    network, _ = grow(cfg, types, width, heading, target, draw, cfg.rounds)
    return compact(network)
