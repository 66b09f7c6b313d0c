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
from truckrl.viz.draw import draw_scene


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
    wide. Each tile is centred between start and goal and spans ``+-view_half_extent`` metres;
    its first line is ``#<index>`` and ``title``.
    """
    pose, goal, params = state["pose"], state["goal"], state["params"]
    n = pose.shape[0]
    zeros = torch.zeros(n, 1, device=goal.device)
    start_tractor, start_trailer, _ = truck_corners(pose, params)
    goal_tractor, goal_trailer, _ = truck_corners(torch.cat((goal, zeros), -1), params)
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
        tile = draw_scene(
            state["segments"][i],
            state["mask"][i],
            state["kind"][i],
            tractor=start_tractor[i],
            trailer=start_trailer[i],
            goal=goal[i],
            goal_footprint=torch.stack((goal_tractor[i], goal_trailer[i])),
            center=0.5 * (pose[i, :2] + goal[i, :2]),
            size_px=tile_px,
            view_half_extent=view_half_extent,
            hud_lines=hud,
        )
        r, c = divmod(i, cols)
        y0 = border_px + r * (tile_px + border_px)
        x0 = border_px + c * (tile_px + border_px)
        grid[y0 : y0 + tile_px, x0 : x0 + tile_px] = tile
    return grid
