"""Road geometry scene generators build on: one straight road or two crossing roads, their curbs,
lanes, boxes parked along the curbs, and the draw helpers the generators share.

Everything is batched over ``n`` scenes, pure torch, in world metres and radians; nothing here
draws a random number except :func:`curb_boxes`, through the ``rand`` it is given.

Roads (:class:`Roads`, :func:`crossing_roads`)
----------------------------------------------
Both roads of a scene pass through its centre ``P`` along unit directions ``d_r`` (road 1 is
road 0 turned by the crossing angle, in ``(0, pi)``); their curbs are the lines at ``+-width_r /
2`` along the left normal ``n_r``, from ``-half_extent`` to ``+half_extent`` along ``d_r`` (open
ends). The four curb-curb crossing points are the corners of the crossing parallelogram
(counter-clockwise); ``e_r`` is its extent along ``d_r`` (largest ``|(corner - P) . d_r|``). A
straight road is road 0 alone.

Curbs (:func:`crossing_curbs`)
------------------------------
Each curb line of a crossing is split at its two corners and the part inside the other road is
dropped, so the 8 curb segments meet exactly at the 4 corners. A straight road has 2 curb
segments; the other 6 slots are padding.

Boxes along the curbs (:func:`curb_boxes`)
------------------------------------------
Up to ``count`` rectangles aligned with their road. Slot ``k`` sits on curb line ``k mod C``
(``C = 4`` curb lines at a crossing, 2 on a straight road), alternating between the two arms of
the line (the two sides of ``P``). Slots are ``spacing`` long and start ``crossing_clearance``
beyond the parallelogram along their road (at ``P`` on a straight road); each holds one box with
``min_gap / 2`` to spare at both ends and is occupied with ``keep_prob``. A box lies
``curb_offset`` inside its curb. Its position in the slot is drawn by rejection against keep-out
intervals on given lanes and against the road ends, for ``rounds`` rounds; a box still failing
is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from truckrl.sim.geometry import rectangle_segments, rotate

#: Curb segment slots of a crossing: 2 roads x 2 curbs x 2 pieces (a straight road uses the first 2).
CROSSING_CURB_SLOTS = 8


def scene_device(
    params: dict[str, Tensor], generator: torch.Generator | None, device
) -> tuple[torch.device, dict[str, Tensor]]:
    """The device a scene generator draws on (the generator's, else ``device``, else that of
    ``params``) and the vehicle parameters there as float32 ``{key: [n]}``."""
    if generator is not None:
        dev = generator.device
    elif device is not None:
        dev = torch.device(device)
    else:
        dev = next(iter(params.values())).device
    return dev, {k: v.to(dev, torch.float32) for k, v in params.items()}


def uniform(bounds: tuple[float, float], u: Tensor) -> Tensor:
    """``u`` in ``[0, 1)`` mapped linearly onto ``[bounds[0], bounds[1])``."""
    return bounds[0] + (bounds[1] - bounds[0]) * u


def lane_offset(width: Tensor, gap: Tensor, half_width: Tensor) -> Tensor:
    """Offset [m] of a body of half width ``half_width`` from the centreline of a road ``width``
    wide: its curb-side edge ``gap`` from the curb, kept within its half of the road."""
    lat = torch.maximum(0.5 * width - gap - half_width, half_width)
    return torch.minimum(lat, 0.5 * width - half_width)


def right_normal(u: Tensor) -> Tensor:
    """Right-hand normal of unit directions ``u [..., 2]``."""
    return torch.stack((u[..., 1], -u[..., 0]), dim=-1)


def pick_road(t: Tensor, idx: Tensor) -> Tensor:
    """``t[i, idx[i]]`` for ``t [n, 2, ...]`` and ``idx [n]`` (0 or 1: road selection)."""
    return torch.where((idx == 0).view(-1, *([1] * (t.dim() - 2))), t[:, 0], t[:, 1])


def repeat_rounds(t: Tensor, k: int) -> Tensor:
    """``t [n, ...]`` stacked ``k`` times along its first dimension: ``[k n, ...]`` (row ``j n +
    i`` is round ``j`` of scene ``i``)."""
    return t.repeat(k, *([1] * (t.dim() - 1)))


def first_valid(valid: Tensor) -> tuple[Tensor, Tensor]:
    """For ``valid [k, ...]`` (rounds first): whether any round is valid ``[...]``, and the
    flat index ``round * numel + position`` of the first valid one (of round 0 where none is)."""
    ok = valid.any(0)
    first = valid.to(torch.uint8).argmax(0)  # the first maximum: the earliest valid round
    position = torch.arange(ok.numel(), device=valid.device).view(ok.shape)
    return ok, first * ok.numel() + position


def to_world(xy: Tensor, heading: Tensor, origin: Tensor) -> Tensor:
    """Points ``xy [n, ..., 2]`` of a frame at ``origin [n, 2]`` with heading ``heading [n]``
    [rad] into the world."""
    extra = [1] * (xy.dim() - 2)
    return rotate(xy, heading.view(-1, *extra).expand(xy.shape[:-1])) + origin.view(-1, *extra, 2)


@dataclass
class Roads:
    """Both roads of every scene (road 1 only counts where the scene is a crossing)."""

    centre: Tensor  # [n, 2] scene centre P: both centrelines pass through it
    heading: Tensor  # [n, 2]
    width: Tensor  # [n, 2]
    dirs: Tensor  # [n, 2, 2] unit direction d_r
    normals: Tensor  # [n, 2, 2] left normal n_r
    corners: Tensor  # [n, 4, 2] crossing parallelogram, counter-clockwise
    extent: Tensor  # [n, 2] e_r, the parallelogram's extent along d_r from P
    angle: Tensor  # [n] crossing angle: road 1 is road 0 turned by it

    def table(self) -> Tensor:
        """``[n, 2, 4]`` per road ``(centre x, centre y, heading, width)``."""
        n = self.centre.shape[0]
        return torch.cat(
            (
                self.centre.unsqueeze(1).expand(n, 2, 2),
                self.heading.unsqueeze(-1),
                self.width.unsqueeze(-1),
            ),
            -1,
        )


def crossing_roads(centre: Tensor, heading: Tensor, width: Tensor, angle: Tensor) -> Roads:
    """Two roads through ``centre [n, 2]`` with headings ``heading [n, 2]``, widths ``width [n,
    2]`` [m] and ``angle [n]`` (in ``(0, pi)``) from road 0 to road 1, and their parallelogram."""
    dirs = torch.stack((torch.cos(heading), torch.sin(heading)), dim=-1)
    normals = torch.stack((-dirs[..., 1], dirs[..., 0]), dim=-1)
    # Corner with offsets (o0, o1) from the two centrelines: solve n0.x = o0, n1.x = o1.
    n0, n1 = normals[:, 0], normals[:, 1]
    det = (n0[:, 0] * n1[:, 1] - n0[:, 1] * n1[:, 0]).unsqueeze(-1)  # sin(angle) > 0
    signs = torch.tensor([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]], device=centre.device)
    o0 = signs[:, 0] * 0.5 * width[:, :1]  # [n, 4]
    o1 = signs[:, 1] * 0.5 * width[:, 1:]
    corners = centre.unsqueeze(1) + torch.stack(
        (
            (n1[:, 1:2] * o0 - n0[:, 1:2] * o1) / det,
            (-n1[:, 0:1] * o0 + n0[:, 0:1] * o1) / det,
        ),
        dim=-1,
    )  # counter-clockwise: the map x -> (n0.x, n1.x) keeps orientation (det > 0)
    along = torch.einsum("nkc,nrc->nrk", corners - centre.unsqueeze(1), dirs)  # [n, 2, 4]
    return Roads(centre, heading, width, dirs, normals, corners, along.abs().amax(-1), angle)


def crossing_curbs(roads: Roads, crossing: Tensor, half_extent: float) -> tuple[Tensor, Tensor]:
    """Curb segments ``[n, 8, 4]`` and mask ``[n, 8]`` (module doc, "Curbs").

    Slot ``4 r + 2 side + piece``: road ``r``, curb on side ``-n_r`` (0) or ``+n_r`` (1), piece
    before (0) or after (1) the crossing along ``d_r``. Where ``crossing [n]`` is ``False``, slots
    0 and 1 hold the two whole curbs of road 0 and the rest is masked.
    """
    n = crossing.shape[0]
    half = 0.5 * roads.width.unsqueeze(-1)  # [n, 2, 1]
    mid = roads.centre.view(n, 1, 1, 2) + torch.stack(
        (-half, half), dim=2
    ) * roads.normals.unsqueeze(2)
    line_a = mid - half_extent * roads.dirs.unsqueeze(2)  # [n, road, side, 2]
    line_b = mid + half_extent * roads.dirs.unsqueeze(2)
    # corners on each curb line: road 0 side -/+ -> (0, 3) / (1, 2); road 1 -> (0, 1) / (3, 2)
    idx = torch.tensor([[[0, 3], [1, 2]], [[0, 1], [3, 2]]], device=crossing.device)
    cj = roads.corners[:, idx]  # [n, road, side, 2 corners, 2]
    sj = torch.einsum("nrsjc,nrc->nrsj", cj - roads.centre.view(n, 1, 1, 1, 2), roads.dirs)
    first = (sj[..., 0] <= sj[..., 1]).unsqueeze(-1)
    c_lo = torch.where(first, cj[..., 0, :], cj[..., 1, :])
    c_hi = torch.where(first, cj[..., 1, :], cj[..., 0, :])
    cross_curbs = torch.stack(
        (torch.cat((line_a, c_lo), -1), torch.cat((c_hi, line_b), -1)), dim=3
    ).reshape(n, CROSSING_CURB_SLOTS, 4)
    straight_curbs = torch.zeros_like(cross_curbs)
    straight_curbs[:, :2] = torch.cat((line_a[:, 0], line_b[:, 0]), -1)
    curbs = torch.where(crossing.view(n, 1, 1), cross_curbs, straight_curbs)
    mask = torch.ones(n, CROSSING_CURB_SLOTS, dtype=torch.bool, device=crossing.device)
    mask[:, 2:] = crossing.unsqueeze(-1)
    return curbs, mask


def lane_interval(
    pose: Tensor, roads: Roads, t0: Tensor, t1: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The lane of a pose and an interval on it.

    Args:
        pose: ``[n, 4]`` (x, y, heading, road index).
        roads: the scene roads.
        t0, t1: ``[n]`` interval ends [m] ahead of the pose's rear axle (negative = behind).

    Returns:
        ``road [n]``, ``side [n]`` (+-1 along ``n_r``: the pose's half of the road) and ``lo, hi
        [n]``: the interval in along-road coordinates [m] from the scene centre along ``d_r``.
    """
    road = pose[:, 3].long()
    d = pick_road(roads.dirs, road)
    u = torch.stack((torch.cos(pose[:, 2]), torch.sin(pose[:, 2])), dim=-1)
    k = torch.where((u * d).sum(-1) >= 0.0, 1.0, -1.0)  # driving along (+1) or against d_r
    s = ((pose[:, :2] - roads.centre) * d).sum(-1)
    a, b = s + k * t0, s + k * t1
    return road, -k, torch.minimum(a, b), torch.maximum(a, b)


@dataclass(frozen=True)
class BoxRule:
    """How :func:`curb_boxes` parks boxes along the curbs (module doc, "Boxes along the curbs");
    lengths in metres, ranges drawn uniformly per box."""

    count: int  # box slots per scene
    spacing: float  # slot length along a curb
    crossing_clearance: float  # first slot this far beyond the crossing parallelogram
    keep_prob: float  # probability that a slot holds a box
    length: tuple[float, float]  # along the curb
    width: tuple[float, float]  # across the curb
    curb_offset: tuple[float, float]  # curb to box
    min_gap: float  # spare room in a slot, half at each end
    rounds: int  # rejection rounds for a box's place in its slot
    half_extent: float  # road ends: +-this along d_r from the scene centre


def curb_boxes(
    rule: BoxRule,
    rand,
    roads: Roads,
    crossing: Tensor,
    zones: list[tuple[Tensor, Tensor, Tensor, Tensor]],
) -> tuple[Tensor, Tensor]:
    """Box edges ``[n, 4 count, 4]`` and mask ``[n, 4 count]`` (module doc, "Boxes along the
    curbs").

    Args:
        rule: slot layout and draw ranges.
        rand: ``rand(*shape)`` uniform in ``[0, 1)``; draws the slots' occupancy ``[n, count]``,
            then each round's ``[n, count, 4]`` (length, width, curb offset, place in the slot).
        roads: the scene roads; ``crossing [n]`` tells which scenes use road 1.
        zones: keep-out intervals ``(road, side, lo, hi)``, each ``[n]`` (:func:`lane_interval`):
            no box on that lane overlaps ``[lo, hi]`` along the road.
    """
    n, dev, K = crossing.shape[0], crossing.device, rule.count
    if K == 0:
        return torch.zeros(n, 0, 4, device=dev), torch.zeros(n, 0, dtype=torch.bool, device=dev)
    slot = torch.arange(K, device=dev).unsqueeze(0)  # [1, K]
    n_lines = torch.where(crossing, 4, 2).unsqueeze(-1)  # [n, 1]
    line = slot % n_lines
    rank = torch.div(slot, n_lines, rounding_mode="floor")
    arm = torch.where(rank % 2 == 0, 1.0, -1.0)
    road = torch.div(line, 2, rounding_mode="floor")  # [n, K]
    side = torch.where(line % 2 == 0, -1.0, 1.0)
    rows = torch.arange(n, device=dev).unsqueeze(-1)
    first = torch.where(
        crossing.unsqueeze(-1), roads.extent[rows, road] + rule.crossing_clearance, 0.0
    )
    slot_lo = first + torch.div(rank, 2, rounding_mode="floor") * rule.spacing
    keep = rand(n, K) < rule.keep_prob

    # All rounds at once, rounds first ([k, n, K]); drawn round by round as a loop would.
    k = rule.rounds
    r = torch.stack([rand(n, K, 4) for _ in range(k)])  # [k, n, K, 4]
    half_len = 0.5 * uniform(rule.length, r[..., 0])
    room = rule.spacing - 2.0 * half_len - rule.min_gap
    along = slot_lo + 0.5 * rule.min_gap + half_len + room * r[..., 3]
    valid = along + half_len <= rule.half_extent
    s_r = arm * along
    for road_p, side_p, lo, hi in zones:
        same_lane = (road == road_p.unsqueeze(-1)) & (side == side_p.unsqueeze(-1))
        overlap = (s_r + half_len > lo.unsqueeze(-1)) & (s_r - half_len < hi.unsqueeze(-1))
        valid = valid & ~(same_lane & overlap)
    drawn = torch.stack(
        (half_len, 0.5 * uniform(rule.width, r[..., 1]), uniform(rule.curb_offset, r[..., 2])),
        dim=-1,
    )  # [k, n, K, 3]: half length, half width, curb offset
    # each slot takes its first valid round; a slot without one stays zero (and is masked)
    ok, index = first_valid(valid)
    s = torch.where(ok, s_r.flatten()[index], 0.0)
    dims = torch.where(ok.unsqueeze(-1), drawn.flatten(0, 2)[index], 0.0)
    half_len, half_wid, offset = dims.unbind(-1)
    lateral = side * (0.5 * roads.width[rows, road] - offset - half_wid)
    xy = (
        roads.centre.unsqueeze(1)
        + s.unsqueeze(-1) * roads.dirs[rows, road]
        + lateral.unsqueeze(-1) * roads.normals[rows, road]
    )
    edges = rectangle_segments(
        xy[..., 0], xy[..., 1], roads.heading[rows, road], half_len, half_len, half_wid
    )
    mask = (keep & ok).unsqueeze(-1).expand(n, K, 4).reshape(n, 4 * K)
    return edges.flatten(1, 2), mask


def turn_exit_room(
    start: Tensor, u_start: Tensor, goal: Tensor, u_goal: Tensor, trailer_wheelbase: Tensor
) -> Tensor:
    """How much straight lane a turn leaves the trailer after its arc, in trailer wheelbases.

    With ``corner`` the point where the start lane (the line through ``start`` along
    ``u_start``) meets the goal lane (through ``goal`` along ``u_goal``), and ``turn`` the
    heading change between them, this is ``|goal - corner| / trailer_wheelbase - tan(turn / 2)``:
    an arc of kingpin radius ``R`` tangent to both lanes leaves the goal lane ``R tan(turn / 2)``
    past the corner, and a truck whose articulation limit keeps ``R`` above about one trailer
    wheelbase then needs the rest of the lane to bring the trailer straight (its heading error
    decays like ``exp(-s / trailer_wheelbase)`` along a straight lane).

    Args:
        start, goal: ``[n, 2]`` rear-axle positions [m].
        u_start, u_goal: ``[n, 2]`` unit headings (not parallel).
        trailer_wheelbase: ``[n]`` [m].

    Returns:
        ``[n]`` [trailer wheelbases].
    """
    cross = u_start[:, 0] * u_goal[:, 1] - u_start[:, 1] * u_goal[:, 0]  # sin(turn)
    cos_turn = (u_start * u_goal).sum(-1)
    d = goal - start
    # corner = goal - before * u_goal; solve start + ahead * u_start = corner for before
    safe = torch.where(cross.abs() < 1e-9, torch.ones_like(cross), cross)
    before = (u_start[:, 0] * d[:, 1] - u_start[:, 1] * d[:, 0]) / safe
    tan_half = cross.abs() / (1.0 + cos_turn).clamp_min(1e-9)  # tan(|turn| / 2)
    return before / trailer_wheelbase - tan_half


@dataclass
class FramedScenes:
    """A batch of ``N`` scenes built in a local frame and placed in the world (world metres,
    radians); a task's scene batch subclasses it and documents its slots and metadata.

    Attributes:
        segments: ``[N, E, 4]`` scene segments, zeros where masked.
        mask: ``[N, E]`` bool, ``False`` = padding.
        kind: ``[N, E]`` int8, :data:`~truckrl.sim.geometry.KIND_CURB` or ``KIND_OBSTACLE``.
        start: ``[N, 3]`` start pose (rear axle x, y, heading), articulation 0.
        goal: ``[N, 3]`` goal pose, same convention.
        frame: ``[N, 3]`` the local frame in the world: origin x, y and heading.
        info: ``{key: [N]}`` per-episode metadata.
    """

    segments: Tensor
    mask: Tensor
    kind: Tensor
    start: Tensor
    goal: Tensor
    frame: Tensor
    info: dict[str, Tensor]

    def __len__(self) -> int:
        return self.segments.shape[0]

    def to(self, device: torch.device | str) -> FramedScenes:
        """A copy on ``device`` (the same subclass)."""
        out = {f.name: getattr(self, f.name).to(device) for f in fields(self) if f.name != "info"}
        return type(self)(**out, info={k: v.to(device) for k, v in self.info.items()})
