"""A grid of scenes, each with the truck at its start pose and the goal, as one RGB image.

``truckrl tools scenes`` (:mod:`truckrl.tools.scenes`) samples the scenes of a task and writes
the grid to a PNG.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from truckrl.sim.vehicle import truck_corners
from truckrl.viz.draw import (
    ROUTE_KEY,
    draw_scene,
    hud_rows,
    make_view,
    traffic_boxes,
    world_to_pixel,
)

#: Text lines at the top of each tile (index and title; goal distance and segment count).
TILE_HUD_LINES = 2


def tile_center(
    start_xy: np.ndarray,
    truck: np.ndarray,
    goal_xy: np.ndarray,
    tile_px: int,
    view_half_extent: float,
) -> np.ndarray:
    """World point [m] at a tile's centre: midway between the start ``start_xy [2]`` (the
    tractor's rear axle) and the goal ``goal_xy [2]`` when the whole start truck (corners
    ``truck [P, 2]``) then lies inside the tile below its text lines
    (:func:`~truckrl.viz.draw.hud_rows`) and the goal inside it; else the start (a goal too far
    away for one tile: the truck's neighbourhood is shown, as the viewer follows the truck)."""
    mid = 0.5 * (start_xy + goal_xy)
    view = make_view(tile_px, mid, view_half_extent=view_half_extent)
    px = world_to_pixel(np.concatenate((truck, goal_xy[None])), view)
    inside = (px >= 0).all() and (px <= tile_px - 1).all()
    clear = (px[:-1, 1] >= hud_rows(TILE_HUD_LINES)).all()
    return mid if inside and clear else start_xy


def render_grid(
    state: Mapping[str, Any],
    *,
    cols: int,
    tile_px: int,
    view_half_extent: float,
    border_px: int = 4,
    title: str = "",
) -> np.ndarray:
    """Draw every episode start of ``state`` (a task's :meth:`~truckrl.tasks.Task.sample`: pose,
    goal, segments, mask, kind, params) into one ``[H, W, 3]`` uint8 RGB grid, ``cols`` tiles
    wide. Each tile spans ``+-view_half_extent`` metres round :func:`tile_center` (between start
    and goal, or on the truck when the goal lies too far); its first line is ``#<index>`` and
    ``title``. A state's route and traffic (:func:`~truckrl.viz.draw.draw_state`'s keys) are drawn
    too.
    """
    pose, goal, params = state["pose"], state["goal"], state["params"]
    n = pose.shape[0]
    zeros = torch.zeros(n, 1, device=goal.device)
    start_tractor, start_trailer, _ = truck_corners(pose, params)
    goal_tractor, goal_trailer, _ = truck_corners(torch.cat((goal, zeros), -1), params)
    traffic = traffic_boxes(state) if hasattr(state, "batch_dims") else None
    rows = -(-n // cols)
    grid = np.full(
        (rows * (tile_px + border_px) + border_px, cols * (tile_px + border_px) + border_px, 3),
        255,
        dtype=np.uint8,
    )
    for i in range(n):
        dist = float((goal[i, :2] - pose[i, :2]).norm())
        segments = int(state["mask"][i].sum())
        hud = [f"#{i}: {title}".rstrip(": "), f"goal {dist:.1f} m, {segments} segments"]
        truck = torch.cat((start_tractor[i], start_trailer[i])).double().cpu().numpy()
        start_xy, goal_xy = (x[i, :2].double().cpu().numpy() for x in (pose, goal))
        centre = tile_center(start_xy, truck, goal_xy, tile_px, view_half_extent)
        extra: dict[str, Any] = {}
        if ROUTE_KEY in state.keys():
            extra["route"] = state[ROUTE_KEY][i]
        if traffic is not None:
            on = ~np.isnan(traffic[0][i]).any(axis=(-1, -2))
            extra.update(vehicles=traffic[0][i][on], vehicle_trucks=traffic[1][i][on])
        tile = draw_scene(
            state["segments"][i],
            state["mask"][i],
            state["kind"][i],
            tractor=start_tractor[i],
            trailer=start_trailer[i],
            goal=goal[i],
            goal_footprint=torch.stack((goal_tractor[i], goal_trailer[i])),
            center=centre,
            size_px=tile_px,
            view_half_extent=view_half_extent,
            hud_lines=hud,
            **extra,
        )
        r, c = divmod(i, cols)
        y0 = border_px + r * (tile_px + border_px)
        x0 = border_px + c * (tile_px + border_px)
        grid[y0 : y0 + tile_px, x0 : x0 + tile_px] = tile
    return grid
