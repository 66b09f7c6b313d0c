"""Bird's-eye-view drawing of scenes, trucks, goals and LiDAR into RGB arrays (OpenCV, no window).

Pure drawing: inputs are world-frame geometry computed elsewhere (``truckrl.sim``); nothing here
steps physics or opens a window. The interactive viewer and training videos draw through
:func:`draw_scene`, and every world-to-pixel mapping goes through :func:`world_to_pixel`.

Screen convention: world ``x`` to the right, world ``y`` **up**; ``View.center`` is drawn at the
image centre. Pixel coordinates follow OpenCV (column, row), pixel ``j``'s centre at ``j``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

#: RGB colours of every drawn element; change them here, not at call sites.
COLORS: dict[str, tuple[int, int, int]] = {
    "background": (34, 38, 44),
    "curb": (225, 225, 225),
    "obstacle": (235, 145, 45),
    "obstacle_fill": (120, 78, 36),
    "tractor": (70, 140, 255),
    "tractor_fill": (38, 77, 140),
    "trailer": (70, 200, 185),
    "trailer_fill": (38, 110, 100),
    "goal": (110, 230, 110),
    "tolerance": (60, 130, 60),
    "lidar": (235, 215, 70),
    "hud": (245, 245, 245),
    "route": (255, 140, 200),
    "car": (245, 95, 80),
    "car_fill": (150, 45, 40),
    "traffic_truck": (230, 90, 230),
    "traffic_truck_fill": (120, 40, 120),
}

_SHIFT = 4  # sub-pixel bits for OpenCV drawing calls
_SCALE = 1 << _SHIFT
HUD_LINE_PX = 18  # [px] pitch of the HUD text lines (the first baseline at this row too)


def hud_rows(lines: int) -> int:
    """Rows ``[0, hud_rows(lines))`` [px] that ``lines`` HUD text lines cover (with outline and
    descenders): nothing a viewer must see belongs there."""
    return HUD_LINE_PX * lines + 8 if lines else 0


@dataclass(frozen=True)
class View:
    """A camera over the world: ``center`` [m] at the image centre, ``metres_per_px`` [m/px]."""

    center: tuple[float, float]
    metres_per_px: float
    width: int
    height: int


def world_to_pixel(xy, view: View) -> np.ndarray:
    """World points ``xy [..., 2]`` [m] -> float pixel coordinates ``[..., 2]`` (column, row).

    The y axis points up on screen, so larger world ``y`` gives a smaller row.
    """
    xy = np.asarray(xy, dtype=np.float64)
    col = (view.width - 1) / 2.0 + (xy[..., 0] - view.center[0]) / view.metres_per_px
    row = (view.height - 1) / 2.0 - (xy[..., 1] - view.center[1]) / view.metres_per_px
    return np.stack((col, row), axis=-1)


def _np(x) -> np.ndarray | None:
    """Torch tensor or array-like -> float64 numpy (``None`` passes through)."""
    if x is None:
        return None
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _fixed(px: np.ndarray) -> np.ndarray:
    """Float pixels -> OpenCV fixed-point int32 (``_SHIFT`` fractional bits), clipped to int range."""
    return np.clip(np.round(px * _SCALE), -(2**28), 2**28).astype(np.int32)


def _line(img, p0, p1, color, thickness=1) -> None:
    a, b = _fixed(p0), _fixed(p1)
    cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), color, thickness, cv2.LINE_AA, _SHIFT)


def _poly(img, pts: np.ndarray, color, *, fill=None, thickness=1) -> None:
    """Closed polygon ``pts [P, 2]`` in pixels: optional fill, then outline."""
    q = _fixed(pts).reshape(-1, 1, 2)
    if fill is not None:
        cv2.fillPoly(img, [q], fill, cv2.LINE_AA, _SHIFT)
    cv2.polylines(img, [q], True, color, thickness, cv2.LINE_AA, _SHIFT)


def _closed_quads(segs: np.ndarray) -> np.ndarray:
    """Corners ``[Q, 4, 2]`` of the groups of 4 consecutive segments that chain into a closed loop."""
    if len(segs) == 0 or len(segs) % 4:
        return np.zeros((0, 4, 2))
    quads = segs.reshape(-1, 4, 4)
    starts, ends = quads[..., :2], quads[..., 2:]
    closed = np.all(np.abs(np.roll(starts, -1, axis=1) - ends) < 1e-6, axis=(1, 2))
    return starts[closed]


def make_view(
    size_px: int | tuple[int, int] = 512,
    center=(0.0, 0.0),
    metres_per_px: float = 0.25,
    view_half_extent: float | None = None,
) -> View:
    """A :class:`View`; ``view_half_extent`` [m] (half the shorter side) overrides ``metres_per_px``."""
    w, h = (size_px, size_px) if isinstance(size_px, int) else (int(size_px[0]), int(size_px[1]))
    if w <= 0 or h <= 0:
        raise ValueError(f"size_px must be positive, got {size_px!r}")
    if view_half_extent is not None:
        metres_per_px = 2.0 * float(view_half_extent) / min(w, h)
    if not metres_per_px > 0:
        raise ValueError(f"metres_per_px must be > 0, got {metres_per_px!r}")
    c = _np(center).reshape(2)
    return View((float(c[0]), float(c[1])), float(metres_per_px), w, h)


# Long on purpose: one pass paints the layers in z-order (tolerance, curbs, obstacles, LiDAR,
# route, traffic, goal, bodies, HUD); split up, each piece would need the view and a dozen arrays.
def draw_scene(
    segments,
    mask=None,
    kind=None,
    *,
    tractor=None,
    trailer=None,
    goal=None,
    goal_tolerance: tuple[float, float] | None = None,
    goal_footprint=None,
    lidar_origin=None,
    lidar_ranges=None,
    lidar_angles=None,
    center=None,
    size_px: int | tuple[int, int] = 512,
    metres_per_px: float = 0.25,
    view_half_extent: float | None = None,
    hud_lines: Sequence[str] | None = None,
    arrow_length: float = 5.0,
    route=None,
    vehicles=None,
    vehicle_trucks=None,
) -> np.ndarray:
    """Draw one scene into a new RGB image. Torch tensors or numpy arrays are accepted.

    Args:
        segments: ``[E, 4]`` scene segments ``(x0, y0, x1, y1)`` [m].
        mask: ``[E]`` bool validity (``False`` = padding, not drawn) or ``None`` (all valid).
        kind: ``[E]`` int, 0 curb, 1 obstacle (filled where 4 consecutive edges close a loop), or
            ``None`` (all curbs).
        tractor: ``[4, 2]`` tractor body corners [m] or ``None``.
        trailer: ``[4, 2]`` trailer body corners [m] or ``None``.
        goal: ``[3]`` goal pose ``(x, y, heading)`` [m, rad], drawn as an arrow ``arrow_length`` long.
        goal_tolerance: ``(position [m], heading [rad])``: a circle of that radius round the goal
            and a wedge of +-heading round the goal heading.
        goal_footprint: ``[..., 4, 2]`` (or ``[P, 2]``) outline(s) of the truck at the goal [m].
        lidar_origin: ``[2]`` LiDAR position [m].
        lidar_ranges: ``[R]`` ranges [m]; non-finite ranges are not drawn.
        lidar_angles: ``[R]`` world beam directions [rad].
        center: ``[2]`` world point [m] at the image centre; default the tractor's centre, else
            the centre of the valid segments' bounding box.
        size_px: image side, or ``(width, height)`` [px].
        metres_per_px: scale [m/px]; ignored when ``view_half_extent`` [m] is given.
        hud_lines: text lines written top-left.
        arrow_length: goal arrow length [m].
        route: ``[R, 2]`` route polyline [m], drawn as a thin line, or ``None``.
        vehicles: ``[V, 4, 2]`` corners of other road users [m], drawn filled, or ``None``.
        vehicle_trucks: ``[V]`` bool, which of ``vehicles`` are trucks (drawn in the
            ``traffic_truck`` colours; the rest in the ``car`` colours), or ``None`` (all cars).

    Returns:
        ``[H, W, 3]`` uint8 RGB image.
    """
    seg = _np(segments).reshape(-1, 4)
    valid = np.ones(len(seg), dtype=bool) if mask is None else _np(mask).reshape(-1).astype(bool)
    kinds = (
        np.zeros(len(seg), dtype=np.int64)
        if kind is None
        else _np(kind).reshape(-1).astype(np.int64)
    )
    tractor, trailer = _np(tractor), _np(trailer)
    if center is None:
        if tractor is not None:
            center = tractor.reshape(-1, 2).mean(0)
        elif valid.any():
            pts = seg[valid].reshape(-1, 2)
            center = 0.5 * (pts.min(0) + pts.max(0))
        else:
            center = (0.0, 0.0)
    view = make_view(size_px, center, metres_per_px, view_half_extent)
    img = np.empty((view.height, view.width, 3), dtype=np.uint8)
    img[:] = COLORS["background"]
    px_per_m = 1.0 / view.metres_per_px

    # Goal tolerance first, so everything else draws over it.
    goal = _np(goal)
    if goal is not None and goal_tolerance is not None:
        pos_tol, ang_tol = goal_tolerance
        g = world_to_pixel(goal[:2], view)
        radius = max(1, int(round(pos_tol * px_per_m)))
        if radius < 4 * max(view.width, view.height):
            cv2.circle(
                img,
                tuple(map(int, _fixed(g))),
                radius * _SCALE,
                COLORS["tolerance"],
                1,
                cv2.LINE_AA,
                _SHIFT,
            )
        wedge = max(2.0 * arrow_length, 1.0) * px_per_m
        # screen angles run clockwise (rows grow downwards): world heading h -> -h
        h = -math.degrees(goal[2])
        half = math.degrees(min(ang_tol, math.pi))
        cv2.ellipse(
            img,
            tuple(map(int, _fixed(g))),
            (int(wedge * _SCALE), int(wedge * _SCALE)),
            0.0,
            h - half,
            h + half,
            COLORS["tolerance"],
            -1,
            cv2.LINE_AA,
            _SHIFT,
        )

    # Scene segments: obstacle fills, then all edges.
    obstacle = valid & (kinds == 1)
    for quad in _closed_quads(seg[obstacle]):
        _poly(img, world_to_pixel(quad, view), COLORS["obstacle"], fill=COLORS["obstacle_fill"])
    ends = world_to_pixel(seg[valid].reshape(-1, 2, 2), view)
    for (p0, p1), k in zip(ends, kinds[valid], strict=True):
        _line(img, p0, p1, COLORS["obstacle"] if k == 1 else COLORS["curb"], 2)

    # LiDAR beams under the truck.
    if lidar_origin is not None and lidar_ranges is not None and lidar_angles is not None:
        o = _np(lidar_origin).reshape(2)
        r, a = _np(lidar_ranges).reshape(-1), _np(lidar_angles).reshape(-1)
        ok = np.isfinite(r)
        hits = o + r[ok, None] * np.stack((np.cos(a[ok]), np.sin(a[ok])), axis=-1)
        po = world_to_pixel(o, view)
        for h_px in world_to_pixel(hits, view):
            _line(img, po, h_px, COLORS["lidar"], 1)
            cv2.circle(
                img,
                tuple(map(int, _fixed(h_px))),
                2 * _SCALE,
                COLORS["lidar"],
                -1,
                cv2.LINE_AA,
                _SHIFT,
            )

    # The route over the beams, then the traffic.
    route = _np(route)
    if route is not None and len(route) > 1:
        q = _fixed(world_to_pixel(route.reshape(-1, 2), view)).reshape(-1, 1, 2)
        cv2.polylines(img, [q], False, COLORS["route"], 1, cv2.LINE_AA, _SHIFT)
    if vehicles is not None:
        boxes = _np(vehicles).reshape(-1, 4, 2)
        trucks = (
            np.zeros(len(boxes), dtype=bool)
            if vehicle_trucks is None
            else _np(vehicle_trucks).reshape(-1).astype(bool)
        )
        for box, is_truck in zip(boxes, trucks, strict=True):
            name = "traffic_truck" if is_truck else "car"
            _poly(img, world_to_pixel(box, view), COLORS[name], fill=COLORS[f"{name}_fill"])

    # Goal footprint and arrow.
    if goal_footprint is not None:
        fp = _np(goal_footprint)
        outlines = fp.reshape(1, -1, 2) if fp.ndim == 2 else fp.reshape(-1, fp.shape[-2], 2)
        for outline in outlines:
            _poly(img, world_to_pixel(outline, view), COLORS["goal"])
    if goal is not None:
        tip = goal[:2] + arrow_length * np.array([math.cos(goal[2]), math.sin(goal[2])])
        g, t = world_to_pixel(goal[:2], view), world_to_pixel(tip, view)
        cv2.arrowedLine(
            img,
            tuple(map(int, _fixed(g))),
            tuple(map(int, _fixed(t))),
            COLORS["goal"],
            2,
            cv2.LINE_AA,
            _SHIFT,
            0.3,
        )

    # Truck: trailer below the tractor.
    for body, name in ((trailer, "trailer"), (tractor, "tractor")):
        if body is not None:
            corners = world_to_pixel(body.reshape(4, 2), view)
            _poly(img, corners, COLORS[name], fill=COLORS[f"{name}_fill"], thickness=2)

    for i, text in enumerate(hud_lines or ()):
        x, y = 8, HUD_LINE_PX * (i + 1)
        # black outline: the text shifted by one pixel each way (a thicker stroke would also
        # advance each glyph further, so the outline would drift right of the text)
        for dx, dy in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)):
            org = (x + dx, y + dy)
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(
            img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, COLORS["hud"], 1, cv2.LINE_AA
        )
    return img


#: State keys of moving traffic: ``TRAFFIC_PREFIX + f`` for each field ``f`` of
#: :class:`truckrl.sim.network.traffic.Traffic` (vehicle slots, their lanes and arc lengths).
TRAFFIC_PREFIX = "tr_"
#: State key of a route polyline ``[R, 2]`` [m] (a task that steers along a route keeps it).
ROUTE_KEY = "route_points"


def traffic_boxes(state) -> tuple[np.ndarray, np.ndarray] | None:
    """The other road users of a state, read from its traffic keys (:data:`TRAFFIC_PREFIX`).

    Args:
        state: one or more states (TensorDict, batch ``[]`` or ``[n]``); only its ``tr_`` keys
            are read.

    Returns:
        ``(corners [n, M, 4, 2] [m], truck [n, M] bool)`` of the vehicles on the road (slots that
        are empty or waiting off the network have every corner NaN), or ``None`` when the state
        keeps no traffic. Each vehicle's centre and heading are its lane's point at its arc
        length (:func:`truckrl.sim.network.traffic.lane_points`), the pose the task's LiDAR and
        collision read; nothing is stepped.
    """
    import dataclasses

    import torch

    from truckrl.sim.geometry import rectangle_corners
    from truckrl.sim.network.traffic import Traffic, lane_points

    names = [f.name for f in dataclasses.fields(Traffic)]
    if any(TRAFFIC_PREFIX + f not in state.keys() for f in names):
        return None
    s = state.unsqueeze(0) if state.batch_dims == 0 else state
    tr = Traffic(**{f: s[TRAFFIC_PREFIX + f] for f in names})
    xy, heading = lane_points(tr, tr.lane, tr.s)
    half = 0.5 * tr.length
    corners = rectangle_corners(xy[..., 0], xy[..., 1], heading, half, half, 0.5 * tr.width)
    corners = torch.where(tr.present()[..., None, None], corners, torch.nan)
    return _np(corners), _np(tr.truck).astype(bool)


def draw_state(
    state,
    lidar,
    rel_angles,
    tolerance: tuple[float, float] | None = None,
    **draw_kwargs,
) -> np.ndarray:
    """Draw one truck's state snapshot: scene, route, traffic, truck, goal, tolerance and its last
    LiDAR scan.

    Reads the state only (no physics, no scan): the beams are the ranges the env observed. A
    state with a route (:data:`ROUTE_KEY`) gets it drawn as a thin line, one with traffic
    (:data:`TRAFFIC_PREFIX` keys, :func:`traffic_boxes`) its vehicles filled, cars and trucks in
    their own colours.

    Args:
        state: one truck's state (``TruckEnv.get_state()[i]``: pose, goal, segments, mask, kind,
            params; layout in :mod:`truckrl.tasks.base`).
        lidar: ``[R]`` ranges [m] of that state (the observation's ``lidar`` times the max range).
        rel_angles: ``[R]`` beam directions relative to the tractor heading [rad].
        tolerance: ``(position [m], heading [rad])`` goal tolerance, or None.
        **draw_kwargs: passed to :func:`draw_scene` (``hud_lines``, ``size_px``, ``center``, ...);
            the view is centred on the tractor rear axle unless ``center`` is given.

    Returns:
        ``[H, W, 3]`` uint8 RGB image.
    """
    from truckrl.sim.vehicle import truck_corners
    from truckrl.tasks.base import sensor_origin

    s = state.unsqueeze(0) if state.batch_dims == 0 else state
    tractor, trailer, _ = truck_corners(s["pose"], s["params"])
    origin = sensor_origin(s["pose"], s["params"])
    kwargs = {"center": s["pose"][0, :2].cpu(), **draw_kwargs}
    if ROUTE_KEY in s.keys():
        kwargs.setdefault("route", s[ROUTE_KEY][0].cpu())
    traffic = traffic_boxes(s[:1])
    if traffic is not None:
        on = ~np.isnan(traffic[0][0]).any(axis=(-1, -2))
        kwargs.setdefault("vehicles", traffic[0][0][on])
        kwargs.setdefault("vehicle_trucks", traffic[1][0][on])
    return draw_scene(
        s["segments"][0].cpu(),
        s["mask"][0].cpu(),
        s["kind"][0].cpu(),
        tractor=tractor[0].cpu(),
        trailer=trailer[0].cpu(),
        goal=s["goal"][0].cpu(),
        goal_tolerance=tolerance,
        lidar_origin=origin[0].cpu(),
        lidar_ranges=_np(lidar).reshape(-1),
        lidar_angles=(rel_angles.to(s["pose"].device) + s["pose"][0, 2]).cpu(),
        **kwargs,
    )
