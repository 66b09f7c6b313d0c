"""Collision of the vehicle against scene segments, batched over environments."""

from __future__ import annotations

from collections.abc import Mapping

from torch import Tensor

from truckrl.sim.geometry import segment_box_overlap, segments_intersect
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
