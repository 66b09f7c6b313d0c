"""Segment geometry: the one implementation of every geometric query in truckrl.

Everything in the world is a line segment ``[..., E, 4]`` holding ``(x0, y0, x1, y1)`` in world
metres, with an optional boolean validity mask ``[..., E]`` (``False`` = padding, ignored).
Leading dimensions broadcast, so the same call serves one scene or a batch of N scenes.

Collision, placement distances, LiDAR and rendering all go through these functions.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

#: Tolerance on cross products [m^2] below which two directions count as parallel / a point as
#: collinear. Scene coordinates are O(100 m), so float32 round-off on cross products is ~1e-5.
PARALLEL_EPS = 1e-6

#: ``kind`` values of scene segments (drawing tells curbs from obstacles; physics does not).
KIND_CURB, KIND_OBSTACLE = 0, 1


def wrap_angle(angle: Tensor) -> Tensor:
    """Wrap angles [rad] to ``[-pi, pi)``. Any shape."""
    return torch.remainder(angle + math.pi, 2.0 * math.pi) - math.pi


def cross2(ax: Tensor, ay: Tensor, bx: Tensor, by: Tensor) -> Tensor:
    """z-component of the 2-D cross product ``a x b``. Broadcasts."""
    return ax * by - ay * bx


def rotate(xy: Tensor, angle: Tensor) -> Tensor:
    """Rotate points ``xy [..., 2]`` counter-clockwise by ``angle [...]`` [rad] about the origin."""
    c, s = torch.cos(angle), torch.sin(angle)
    return torch.stack(rotated(c, s, xy[..., 0], xy[..., 1]), dim=-1)


def to_local(xy: Tensor, origin: Tensor, heading: Tensor) -> Tensor:
    """World points ``xy [..., P, 2]`` into the frame at ``origin [..., 2]``, ``heading [...]``.

    The same arithmetic as ``rotate(xy - origin, -heading)``, with the cosine and sine of each
    heading computed once (``_once``): under ``torch.compile`` inductor otherwise recomputes
    them for every one of the ``P`` points it rotates.
    """
    c, s = heading_frame(heading)
    p = xy - origin.unsqueeze(-2)
    return torch.stack(rotated(c, s, p[..., 0], p[..., 1]), dim=-1)


def segments_to_local(
    segments: Tensor, origin: Tensor, heading: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Segments ``[..., E, 4]`` into the frame at ``origin [..., 2]``, ``heading [...]`` [rad].

    Returns ``(x0, y0, x1, y1)``, each ``[..., E]`` [m]: the same values as :func:`to_local` of
    the ends, bit for bit, as four coordinate tensors instead of one ``[..., 2E, 2]`` tensor.
    Under ``torch.compile`` the interleaved form is written out by a kernel of its own, a scalar
    loop with strided stores; separate coordinates fuse into the body clips instead, and the LiDAR
    stacks them coordinate-major with contiguous stores.
    """
    c, s = heading_frame(heading)
    ox, oy = origin[..., 0:1], origin[..., 1:2]  # [..., 1]
    x0, y0 = rotated(c, s, segments[..., 0] - ox, segments[..., 1] - oy)
    x1, y1 = rotated(c, s, segments[..., 2] - ox, segments[..., 3] - oy)
    return x0, y0, x1, y1


def unit_vectors(angles: Tensor) -> Tensor:
    """``(cos, sin)`` of ``angles [...]`` [rad] as ``[..., 2]``, computed once under
    ``torch.compile`` (``_once``) instead of inlined into every consumer."""
    return _once(torch.stack((torch.cos(angles), torch.sin(angles)), dim=-1))


def heading_frame(heading: Tensor) -> tuple[Tensor, Tensor]:
    """Cosine and sine ``[..., 1]`` of ``-heading [...]`` (:func:`unit_vectors`)."""
    cs = unit_vectors(-heading.unsqueeze(-1))
    return cs[..., 0], cs[..., 1]


def rotated(c: Tensor, s: Tensor, x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """``(x, y)`` rotated by the angle of cosine ``c`` and sine ``s`` (broadcasting)."""
    return c * x - s * y, s * x + c * y


def _once(t: Tensor) -> Tensor:
    """``t [..., 2]`` unchanged, as a tensor that ``torch.compile`` materialises.

    Inductor inlines cheap pointwise producers into their consumers, so a per-truck value read
    by a per-segment loop is recomputed per segment. A matrix product is an external kernel that
    it cannot inline, and the product with the 2 x 2 identity is exact for finite values
    (``a * 1 + b * 0 = a``), so eager results are bit-identical to ``t``.
    """
    return t @ torch.eye(2, dtype=t.dtype, device=t.device)


def polygon_segments(points: Tensor) -> Tensor:
    """Closed polygon ``points [..., P, 2]`` -> its ``P`` edges ``[..., P, 4]`` (last wraps to first)."""
    return torch.cat((points, torch.roll(points, shifts=-1, dims=-2)), dim=-1)


def rectangle_corners(
    cx: Tensor, cy: Tensor, heading: Tensor, front: Tensor, rear: Tensor, half_width: Tensor
) -> Tensor:
    """Corners ``[..., 4, 2]`` (counter-clockwise) of an oriented rectangle.

    The rectangle spans ``front`` metres ahead of and ``rear`` metres behind the reference point
    ``(cx, cy)`` along ``heading`` [rad], and ``half_width`` metres to each side. All inputs ``[...]``.
    """
    c, s = torch.cos(heading), torch.sin(heading)
    # front-right, front-left, rear-left, rear-right: counter-clockwise with y to the left
    lx = torch.stack((front, front, -rear, -rear), dim=-1)
    ly = torch.stack((-half_width, half_width, half_width, -half_width), dim=-1)
    x = cx.unsqueeze(-1) + c.unsqueeze(-1) * lx - s.unsqueeze(-1) * ly
    y = cy.unsqueeze(-1) + s.unsqueeze(-1) * lx + c.unsqueeze(-1) * ly
    return torch.stack((x, y), dim=-1)


def rectangle_segments(
    cx: Tensor, cy: Tensor, heading: Tensor, front: Tensor, rear: Tensor, half_width: Tensor
) -> Tensor:
    """The 4 edges ``[..., 4, 4]`` of the rectangle of :func:`rectangle_corners`."""
    return polygon_segments(rectangle_corners(cx, cy, heading, front, rear, half_width))


def _on_segment(px: Tensor, py: Tensor, s: Tensor) -> Tensor:
    """Whether a point known to be collinear with segment ``s [..., 4]`` lies within its extent."""
    eps = 1e-6
    return (
        (px >= torch.minimum(s[..., 0], s[..., 2]) - eps)
        & (px <= torch.maximum(s[..., 0], s[..., 2]) + eps)
        & (py >= torch.minimum(s[..., 1], s[..., 3]) - eps)
        & (py <= torch.maximum(s[..., 1], s[..., 3]) + eps)
    )


def segments_intersect(
    a: Tensor, b: Tensor, a_mask: Tensor | None = None, b_mask: Tensor | None = None
) -> Tensor:
    """Pairwise closed-segment intersection test.

    Args:
        a: ``[..., A, 4]`` segments [m].
        b: ``[..., B, 4]`` segments [m]; leading dims broadcast with ``a``'s.
        a_mask: ``[..., A]`` validity (``False`` = padding) or ``None``.
        b_mask: ``[..., B]`` validity or ``None``.

    Returns:
        ``[..., A, B]`` bool: the segments share at least one point (touching endpoints and
        collinear overlaps count). Pairs involving padding are ``False``.
    """
    sa = a.unsqueeze(-2)  # [..., A, 1, 4]
    sb = b.unsqueeze(-3)  # [..., 1, B, 4]
    ax0, ay0, ax1, ay1 = sa.unbind(-1)
    bx0, by0, bx1, by1 = sb.unbind(-1)
    dax, day = ax1 - ax0, ay1 - ay0
    dbx, dby = bx1 - bx0, by1 - by0
    d1 = cross2(dbx, dby, ax0 - bx0, ay0 - by0)  # side of a0 relative to b
    d2 = cross2(dbx, dby, ax1 - bx0, ay1 - by0)
    d3 = cross2(dax, day, bx0 - ax0, by0 - ay0)  # side of b0 relative to a
    d4 = cross2(dax, day, bx1 - ax0, by1 - ay0)
    eps = PARALLEL_EPS
    z1, z2, z3, z4 = (d.abs() <= eps for d in (d1, d2, d3, d4))
    proper = ((d1 > eps) & (d2 < -eps) | (d1 < -eps) & (d2 > eps)) & (
        (d3 > eps) & (d4 < -eps) | (d3 < -eps) & (d4 > eps)
    )
    touch = (
        (z1 & _on_segment(ax0, ay0, sb))
        | (z2 & _on_segment(ax1, ay1, sb))
        | (z3 & _on_segment(bx0, by0, sa))
        | (z4 & _on_segment(bx1, by1, sa))
    )
    hit = proper | touch
    if a_mask is not None:
        hit = hit & a_mask.unsqueeze(-1)
    if b_mask is not None:
        hit = hit & b_mask.unsqueeze(-2)
    return hit


def point_segment_distance(points: Tensor, segments: Tensor, mask: Tensor | None = None) -> Tensor:
    """Euclidean distance from each point to each segment.

    Args:
        points: ``[..., P, 2]`` [m].
        segments: ``[..., E, 4]`` [m]; leading dims broadcast with ``points``'.
        mask: ``[..., E]`` validity or ``None``; padding gives ``+inf``.

    Returns:
        ``[..., P, E]`` distances [m]. Degenerate (zero-length) segments act as points.
    """
    p = points.unsqueeze(-2)  # [..., P, 1, 2]
    s = segments.unsqueeze(-3)  # [..., 1, E, 4]
    x0, y0, x1, y1 = s.unbind(-1)
    dx, dy = x1 - x0, y1 - y0
    px, py = p[..., 0], p[..., 1]
    len2 = dx * dx + dy * dy
    t = ((px - x0) * dx + (py - y0) * dy) / len2.clamp_min(1e-12)
    t = t.clamp(0.0, 1.0)
    d = torch.hypot(px - (x0 + t * dx), py - (y0 + t * dy))
    if mask is not None:
        d = d.masked_fill(~mask.unsqueeze(-2), math.inf)
    return d


def segment_segment_distance(
    a: Tensor, b: Tensor, a_mask: Tensor | None = None, b_mask: Tensor | None = None
) -> Tensor:
    """Pairwise minimum distance between segments ``a [..., A, 4]`` and ``b [..., B, 4]``.

    Returns:
        ``[..., A, B]`` distances [m]: ``0`` where they intersect, else the smallest
        endpoint-to-segment distance. Pairs involving padding are ``+inf``.
    """
    a_end = a.unflatten(-1, (2, 2))  # [..., A, 2, 2]
    b_end = b.unflatten(-1, (2, 2))
    # endpoints of a vs segments of b: [..., A*2, B] -> [..., A, B]
    da = point_segment_distance(a_end.flatten(-3, -2), b)
    da = da.unflatten(-2, (a.shape[-2], 2)).amin(-2)
    db = point_segment_distance(b_end.flatten(-3, -2), a)
    db = db.unflatten(-2, (b.shape[-2], 2)).amin(-2).transpose(-1, -2)
    d = torch.minimum(da, db)
    d = d.masked_fill(segments_intersect(a, b), 0.0)
    if a_mask is not None:
        d = d.masked_fill(~a_mask.unsqueeze(-1), math.inf)
    if b_mask is not None:
        d = d.masked_fill(~b_mask.unsqueeze(-2), math.inf)
    return d


#: Half-width of a LiDAR beam for :func:`ray_segment_distance` at a segment end, in machine
#: epsilons of the inputs' dtype times that end's coordinate scale ``|x| + |y|`` relative to the
#: ray origin. The float32 round-off of a signed distance to the beam's line through the world ->
#: sensor frame change, the beam direction and the cross product measured up to 2.1 eps (against
#: float64 from the same float32 inputs; ``tests/reliability/test_lidar_float32.py``); 16 leaves a
#: wide margin. It is 1.9e-6 * scale in float32 (~2e-5 m at 10 m), 3.6e-15 * scale in float64.
RAY_TOLERANCE_ULPS = 16.0


def ray_tolerance(px: Tensor, py: Tensor, eps: float) -> Tensor:
    """Beam half-width [m] of :func:`ray_segment_distance` at points ``(px, py)``.

    ``px, py`` are relative to the ray origin (any shape); ``eps`` is the machine epsilon of the
    dtype the inputs were rounded to. Seen from the origin the half-width subtends at most
    ``sqrt(2) * RAY_TOLERANCE_ULPS * eps`` radians (2.7e-6 in float32).
    """
    return (RAY_TOLERANCE_ULPS * eps) * (px.abs() + py.abs())


def ray_segment_distance(
    origin: Tensor,
    angles: Tensor,
    segments: Tensor,
    mask: Tensor | None = None,
    eps: float | None = None,
) -> Tensor:
    """Distance along each ray to each segment (dense ray x segment form).

    Args:
        origin: ``[..., 2]`` ray origin [m].
        angles: ``[..., R]`` world ray directions [rad].
        segments: ``[..., E, 4]`` [m].
        mask: ``[..., E]`` validity or ``None``.
        eps: machine epsilon of the precision the inputs carry; ``None`` = that of their dtype.
            Pass ``torch.finfo(torch.float32).eps`` to judge float32 inputs in float64.

    Returns:
        ``[..., R, E]`` distance [m] from ``origin`` to the first point of each segment on each
        ray, ``+inf`` where the ray misses or the segment is padding. A ray through a vertex hits
        it; a segment collinear with a ray is hit at its nearest point at or ahead of the origin.

    Everything is computed relative to the origin, from the two ends' signed distances to the
    ray's line, ``s = d x p``, and their ranges along it, ``t = d . p``. The ray is a beam whose
    half-width is a few round-offs of the coordinates (:func:`ray_tolerance` at each end,
    linear in between): the segment is hit where it crosses the line, interpolated between its
    ends (``u = s0 / (s0 - s1)``, so never off the segment), or at an end lying within the beam;
    when both ends lie within it (the ray runs along the segment, to round-off) at its nearest
    point ahead. No threshold on a determinant is involved, so a ray nearly along a segment
    cannot report a hit where there is none.
    """
    ox = origin[..., 0].unsqueeze(-1).unsqueeze(-1)  # [..., 1, 1]
    oy = origin[..., 1].unsqueeze(-1).unsqueeze(-1)
    x0, y0, x1, y1 = segments.unsqueeze(-3).unbind(-1)  # [..., 1, E]
    return ray_distance_from_origin(
        torch.cos(angles).unsqueeze(-1),  # [..., R, 1]
        torch.sin(angles).unsqueeze(-1),
        (x0 - ox, y0 - oy, x1 - ox, y1 - oy),  # ends relative to the origin
        mask,
        torch.finfo(segments.dtype).eps if eps is None else eps,
    )


def ray_distance_from_origin(
    dx: Tensor,
    dy: Tensor,
    ends: tuple[Tensor, Tensor, Tensor, Tensor],
    mask: Tensor | None,
    eps: float,
) -> Tensor:
    """:func:`ray_segment_distance` for rays from ``(0, 0)``: its arithmetic, bit for bit.

    Args:
        dx, dy: ray directions (unit vectors), broadcastable to ``[..., R, 1]``.
        ends: ``(x0, y0, x1, y1)`` segment ends relative to the ray origin [m], broadcastable
            to ``[..., 1, E]``.
        mask: ``[..., E]`` validity or ``None``.
        eps: machine epsilon of the precision the inputs carry.

    Returns:
        ``[..., R, E]`` distances [m], ``+inf`` where a ray misses or the segment is padding.
    """
    p0x, p0y, p1x, p1y = ends
    tol0, tol1 = ray_tolerance(p0x, p0y, eps), ray_tolerance(p1x, p1y, eps)  # [..., 1, E]
    s0, s1 = cross2(dx, dy, p0x, p0y), cross2(dx, dy, p1x, p1y)  # signed distances to the line
    t0, t1 = dx * p0x + dy * p0y, dx * p1x + dy * p1y  # ranges along the ray
    in0, in1 = s0.abs() <= tol0, s1.abs() <= tol1  # ends within the beam
    crosses = s0 * s1 <= 0.0  # the segment meets the beam's line
    # Position along the segment: the crossing point, else the end within the beam. The NaN of
    # 0 / 0 (s0 == s1 == 0) is never used: the ray then runs along the segment.
    u = torch.where(crosses, (s0 / (s0 - s1)).clamp(0.0, 1.0), (~in0).to(s0.dtype))
    t = t0 + u * (t1 - t0)
    along = in0 & in1  # the ray runs along the segment: its nearest point ahead
    t_near = torch.where(along, torch.minimum(t0, t1), t)
    t_far = torch.where(along, torch.maximum(t0, t1), t)
    hit = (crosses | in0 | in1) & (t_far >= -torch.maximum(tol0, tol1))
    dist = torch.where(hit, t_near.clamp_min(0.0), torch.full_like(t, math.inf))
    if mask is not None:
        dist = dist.masked_fill(~mask.unsqueeze(-2), math.inf)
    return dist


def box_clip(
    x0: Tensor, y0: Tensor, x1: Tensor, y1: Tensor, front: Tensor, rear: Tensor, half_width: Tensor
) -> Tensor:
    """Whether each segment ``(x0, y0)-(x1, y1)``, in a box's frame (its reference point at the
    origin, its heading along +x), shares a point with the filled box ``-rear <= x <= front``,
    ``|y| <= half_width`` [m] (Liang-Barsky clip; closed sets, touching counts). Every argument
    broadcasts to the segments' shape; the result is bool of that shape."""
    dx, dy = x1 - x0, y1 - y0
    eps = 1e-6  # [m] closed-set slack, as in segments_intersect

    def slab(p0: Tensor, d: Tensor, lo: Tensor, hi: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        # Parameter interval [t_in, t_out] of the segment inside lo - eps <= p <= hi + eps, and
        # whether a segment parallel to the slab lies outside it (then there is no interval).
        # A parallel segment inside gets the neutral (-inf, +inf); masked_fill writes the same
        # values as a where against scalars, with fewer and cheaper passes.
        lo, hi = lo - eps, hi + eps
        flat = d.abs() <= 1e-9
        safe = d.masked_fill(flat, 1.0)
        t1, t2 = (lo - p0) / safe, (hi - p0) / safe
        t_in = torch.minimum(t1, t2).masked_fill_(flat, -math.inf)
        t_out = torch.maximum(t1, t2).masked_fill_(flat, math.inf)
        outside = flat & ~((p0 >= lo) & (p0 <= hi))
        return t_in, t_out, outside

    tx_in, tx_out, x_out = slab(x0, dx, -rear, front)
    ty_in, ty_out, y_out = slab(y0, dy, -half_width, half_width)
    t_in = torch.maximum(tx_in, ty_in).clamp_min_(0.0)
    t_out = torch.minimum(tx_out, ty_out).clamp_max_(1.0)
    return (t_in <= t_out) & ~(x_out | y_out)


def segment_box_overlap(
    segments: Tensor,
    cx: Tensor,
    cy: Tensor,
    heading: Tensor,
    front: Tensor,
    rear: Tensor,
    half_width: Tensor,
    mask: Tensor | None = None,
) -> Tensor:
    """Whether each segment shares a point with a filled oriented rectangle (Liang-Barsky clip).

    The rectangle is the one of :func:`rectangle_corners`: ``front`` metres ahead of and ``rear``
    behind ``(cx, cy)`` along ``heading`` [rad], ``half_width`` to each side. Unlike a contour test
    (:func:`segments_intersect` against the 4 edges) a segment lying wholly inside counts too, and
    it costs one clip per segment instead of four edge pairs.

    Args:
        segments: ``[..., E, 4]`` [m].
        cx, cy, heading, front, rear, half_width: ``[...]`` rectangle parameters.
        mask: ``[..., E]`` validity or ``None``; padding gives ``False``.

    Returns:
        ``[..., E]`` bool (closed sets: touching counts).
    """
    x0, y0, x1, y1 = segments_to_local(segments, torch.stack((cx, cy), -1), heading)  # [..., E]
    extents = (t.unsqueeze(-1) for t in (front, rear, half_width))
    hit = box_clip(x0, y0, x1, y1, *extents)
    if mask is not None:
        hit = hit & mask
    return hit
