"""An independent numpy oracle for road-network geometry: plain segment tests, written here from
the definitions, calling nothing of ``truckrl.sim``.

Every function takes float64 numpy arrays: segments ``[E, 4]`` (x0, y0, x1, y1), points
``[P, 2]``.
"""

from __future__ import annotations

import numpy as np


def cross(ax, ay, bx, by):
    return ax * by - ay * bx


def proper_crossings(a: np.ndarray, b: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """``[A, B]`` bool: segment ``a[i]`` and ``b[j]`` cross at a point more than ``tol`` m from
    every end of both (ends of each strictly on opposite sides of the other's line). Segments
    that only meet at an end (joined curbs, float round-off there included) do not cross."""
    ax0, ay0, ax1, ay1 = (a[:, k, None] for k in range(4))
    bx0, by0, bx1, by1 = (b[None, :, k] for k in range(4))
    d1 = cross(bx1 - bx0, by1 - by0, ax0 - bx0, ay0 - by0)
    d2 = cross(bx1 - bx0, by1 - by0, ax1 - bx0, ay1 - by0)
    d3 = cross(ax1 - ax0, ay1 - ay0, bx0 - ax0, by0 - ay0)
    d4 = cross(ax1 - ax0, ay1 - ay0, bx1 - ax0, by1 - ay0)
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = d1 / (d1 - d2)  # where the crossing lies along a (0 at its start, 1 at its end)
        u = d3 / (d3 - d4)
    la = np.hypot(ax1 - ax0, ay1 - ay0)
    lb = np.hypot(bx1 - bx0, by1 - by0)
    inner = (np.minimum(t, 1 - t) * la > tol) & (np.minimum(u, 1 - u) * lb > tol)
    return hit & inner


def point_segment_distance(p: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``[P, E]`` distances [m] from points to segments."""
    a, b = s[None, :, :2], s[None, :, 2:]
    d = b - a
    t = ((p[:, None] - a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)
    q = a + np.clip(t, 0.0, 1.0)[..., None] * d
    return np.linalg.norm(p[:, None] - q, axis=-1)


def polyline_segments(points: np.ndarray) -> np.ndarray:
    """``[Q, 2]`` -> its ``Q - 1`` segments, zero-length ones (padding) dropped."""
    s = np.concatenate((points[:-1], points[1:]), -1)
    return s[np.linalg.norm(s[:, 2:] - s[:, :2], axis=-1) > 1e-9]


def socket_curb_ends(socket: np.ndarray, width: float) -> np.ndarray:
    """``[2, 2]``: where a road ``width`` wide ends at ``socket`` (x, y, outward heading) has its
    two curbs end: the socket point +- width / 2 along its normal."""
    n = np.array([-np.sin(socket[2]), np.cos(socket[2])])
    return np.stack((socket[:2] + 0.5 * width * n, socket[:2] - 0.5 * width * n))


def has_endpoint(segments: np.ndarray, point: np.ndarray, tol: float = 1e-3) -> bool:
    """Some segment starts or ends within ``tol`` m of ``point``."""
    ends = segments.reshape(-1, 2)
    return bool((np.linalg.norm(ends - point, axis=-1) < tol).any())


def sagitta(segments: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """``[E]``: how far each chord's midpoint lies inside the circle ``(centre, radius)`` (the
    largest gap between a chord with both ends on the circle and its arc)."""
    mid = 0.5 * (segments[:, :2] + segments[:, 2:])
    return radius - np.linalg.norm(mid - centre, axis=-1)
