"""Collision of the vehicle against scene segments, batched over environments."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from truckrl.sim.geometry import (
    box_clip,
    heading_frame,
    rotated,
    segment_box_overlap,
    segments_intersect,
)
from truckrl.sim.vehicle import truck_boxes


def contour_collides(contour: Tensor, segments: Tensor, mask: Tensor | None = None) -> Tensor:
    """Whether any segment of an arbitrary contour touches any valid scene segment.

    Args:
        contour: ``[N, C, 4]`` contour segments [m].
        segments: ``[N, E, 4]`` scene segments [m].
        mask: ``[N, E]`` scene validity (``False`` = padding) or ``None``.

    Returns:
        ``[N]`` bool.
    """
    return segments_intersect(contour, segments, b_mask=mask).flatten(-2).any(-1)


def truck_collides(
    pose: Tensor, params: dict[str, Tensor], segments: Tensor, mask: Tensor | None = None
) -> Tensor:
    """Whether the tractor or trailer body touches any valid scene segment.

    The bodies are filled rectangles, so this is the contour test of :func:`contour_collides`
    on the vehicle outline plus segments lying wholly inside a body (a short segment the truck
    jumped onto within one step), at a quarter of the pair count: one clip per body and segment.

    Args:
        pose: ``[N, 4]`` = ``(x, y, theta, phi)`` tractor rear-axle pose and articulation.
        params: per-env vehicle parameters ``{key: Tensor[N]}``.
        segments: ``[N, E, 4]`` scene segments [m].
        mask: ``[N, E]`` validity or ``None``.

    Returns:
        ``[N]`` bool.
    """
    tractor, trailer, _ = truck_boxes(pose, params)
    hit = segment_box_overlap(segments, *tractor, mask=mask) | segment_box_overlap(
        segments, *trailer, mask=mask
    )
    return hit.any(-1)


#: [m] added to the bounding circles' reach in :func:`truck_collides_sparse`: far above the
#: float32 round-off of coordinates within kilometres of the origin and the clip's 1e-6 slack,
#: so the cull never drops a pair that touches.
CULL_MARGIN = 0.05


def truck_collides_sparse(
    pose: Tensor, params: dict[str, Tensor], segments: Tensor, mask: Tensor | None = None
) -> Tensor:
    """:func:`truck_collides`, bit for bit, for many poses against many segments of which few
    lie near each body (scene generation): the clip runs only on the body and segment pairs
    whose bounding circles come within :data:`CULL_MARGIN`, taken out of the batch (a host read
    of their count: never in an env step). The pairs' arithmetic is the dense test's, element
    for element: each body's frame is rotated as there, once per pose.

    Shapes as :func:`truck_collides`: ``pose [N, 4]``, ``segments [N, E, 4]``, ``mask [N, E]``;
    returns ``[N]`` bool.
    """
    tractor, trailer, _ = truck_boxes(pose, params)
    hit = torch.zeros(pose.shape[0], dtype=torch.bool, device=pose.device)
    # segment bounding circles, from contiguous coordinate planes (reductions over a last
    # dimension of 2 are slow on a CPU)
    x0, y0, x1, y1 = segments.movedim(-1, 0).contiguous()  # [N, E] each
    mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    dx, dy = x1 - x0, y1 - y0
    half_len = 0.5 * (dx * dx + dy * dy).sqrt()
    for cx, cy, heading, front, rear, half in (tractor, trailer):
        c, s = heading_frame(heading)  # [N, 1] each: the dense test's frame
        # the box's bounding circle: centred midway between its ends, reaching its corners
        along = 0.5 * (front - rear)
        ox, oy = (cx + along * c[:, 0]).unsqueeze(-1), (cy - along * s[:, 0]).unsqueeze(-1)
        reach = torch.hypot(0.5 * (front + rear), half).unsqueeze(-1) + CULL_MARGIN
        gx, gy, r = mx - ox, my - oy, half_len + reach
        near = gx * gx + gy * gy <= r * r
        if mask is not None:
            near = near & mask
        row, col = near.nonzero(as_tuple=True)
        if row.numel() == 0:
            continue
        seg = segments[row, col]  # [P, 4]
        px, py = cx[row], cy[row]
        cr, sr = c[row, 0], s[row, 0]
        a = rotated(cr, sr, seg[:, 0] - px, seg[:, 1] - py)
        b = rotated(cr, sr, seg[:, 2] - px, seg[:, 3] - py)
        touch = box_clip(*a, *b, front[row], rear[row], half[row])
        hit[row[touch]] = True
    return hit


def touching(
    pose: Tensor,
    params: dict[str, Tensor],
    segments: Tensor,
    mask: Tensor | None = None,
    along: float | Tensor = 0.0,
    across: float | Tensor = 0.0,
) -> tuple[Tensor, Tensor]:
    """Which segments each body touches, with the bodies lengthened by ``along`` [m] at both
    ends and widened by ``across`` [m] on both sides (floats or ``[N]``): grown by one step's
    travel, a pose just before a collision step touches what the step hits.

    Returns:
        ``(tractor [N, E], trailer [N, E])`` bool: segment ``e`` overlaps that body.
    """
    tractor, trailer, _ = truck_boxes(pose, grown(params, along, across))
    return (
        segment_box_overlap(segments, *tractor, mask=mask),
        segment_box_overlap(segments, *trailer, mask=mask),
    )


def widened(params: Mapping[str, Tensor], margin: float) -> dict[str, Tensor]:
    """Vehicle parameters whose bodies are ``margin`` [m] larger on every side (for a clearance
    test with :func:`truck_collides`)."""
    return grown(params, margin, margin)


def grown(
    params: Mapping[str, Tensor], along: float | Tensor, across: float | Tensor
) -> dict[str, Tensor]:
    """Vehicle parameters whose bodies are ``along`` [m] longer at each end and ``across`` [m]
    wider on each side (floats or ``[N]``)."""
    out = dict(params.items())
    for key in ("tractor_width", "trailer_width"):
        out[key] = params[key] + 2.0 * across
    for key in (
        "front_overhang",
        "rear_overhang",
        "trailer_front_overhang",
        "trailer_rear_overhang",
    ):
        out[key] = params[key] + along
    return out
