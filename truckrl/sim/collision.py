"""Collision of vehicle contours against scene segments, batched over environments."""

from __future__ import annotations

from torch import Tensor

from truckrl.sim.geometry import segments_intersect


def contour_collides(contour: Tensor, segments: Tensor, mask: Tensor | None = None) -> Tensor:
    """Whether any contour segment touches any valid scene segment.

    Args:
        contour: ``[N, C, 4]`` vehicle contour segments [m].
        segments: ``[N, E, 4]`` scene segments [m].
        mask: ``[N, E]`` scene validity (``False`` = padding) or ``None``.

    Returns:
        ``[N]`` bool.
    """
    return segments_intersect(contour, segments, b_mask=mask).flatten(-2).any(-1)
