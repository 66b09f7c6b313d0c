"""Draw where a truck went: one episode's path over its scene, as an RGB array.

Pure drawing from states (:mod:`truckrl.viz.draw`): the poses come from an episode that ran
elsewhere (``evaluate_policy(..., record_paths=True)``); the bodies are placed by
:func:`truckrl.sim.vehicle.truck_corners`, as the viewer places them. Used by
``truckrl tools paths``.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import torch
from tensordict import TensorDictBase

from truckrl.sim.vehicle import truck_corners
from truckrl.viz.draw import COLORS, draw_scene, make_view, world_to_pixel

#: RGB of the rear-axle trace (the bodies keep the viewer's tractor / trailer colours).
PATH_COLOR: tuple[int, int, int] = (235, 70, 70)


def draw_path(
    start: TensorDictBase,
    path: torch.Tensor,
    *,
    label: str = "",
    every: int = 12,
    size_px: int = 360,
    view_half_extent: float = 32.0,
) -> np.ndarray:
    """One episode drawn over its scene: ``[size_px, size_px, 3]`` uint8 RGB.

    Args:
        start: one truck's start state (``TruckEnv.get_state()[i]``: segments, mask, kind, goal,
            params).
        path: ``[T + 1, 4]`` poses ``(x, y, heading, articulation)`` [m, m, rad, rad] from the
            start on (``evaluate_policy(..., record_paths=True)["path"][i]``).
        label: text written top-left.
        every: the tractor and trailer outlines are drawn every this many steps [steps], and at
            the last pose.
        size_px: image side [px].
        view_half_extent: half the side of the square shown [m], centred between the start and
            the goal.
    """
    if every < 1:
        raise ValueError(f"every = {every} must be >= 1")
    path = path.detach().cpu()
    center = (0.5 * (path[0, :2] + start["goal"][:2].cpu())).numpy()
    img = draw_scene(
        start["segments"].cpu(),
        start["mask"].cpu(),
        start["kind"].cpu(),
        goal=start["goal"].cpu(),
        center=center,
        size_px=size_px,
        view_half_extent=view_half_extent,
        hud_lines=[label] if label else None,
    )
    view = make_view(size_px, center, view_half_extent=view_half_extent)
    shown = sorted({*range(0, len(path), every), len(path) - 1})
    params = {k: v.cpu()[None].expand(len(shown), *v.shape) for k, v in start["params"].items()}
    tractor, trailer, _ = truck_corners(path[shown], params)
    for bodies, color in ((trailer, COLORS["trailer"]), (tractor, COLORS["tractor"])):
        for corners in bodies.numpy():
            px = np.round(world_to_pixel(corners, view)).astype(np.int32)
            cv2.polylines(img, [px.reshape(-1, 1, 2)], True, color, 1, cv2.LINE_AA)
    trace = np.round(world_to_pixel(path[:, :2].numpy(), view)).astype(np.int32)
    cv2.polylines(img, [trace.reshape(-1, 1, 2)], False, PATH_COLOR, 2, cv2.LINE_AA)
    return img


def grid(rows: Sequence[Sequence[np.ndarray]], gap_px: int = 4) -> np.ndarray:
    """Images of equal size in rows, ``gap_px`` white pixels between them: ``[H, W, 3]``."""
    if not rows or not rows[0]:
        raise ValueError("grid needs at least one image")
    h, w, _ = rows[0][0].shape
    cols = max(len(r) for r in rows)
    out = np.full(
        (len(rows) * h + (len(rows) - 1) * gap_px, cols * w + (cols - 1) * gap_px, 3), 255, np.uint8
    )
    for i, row in enumerate(rows):
        for j, im in enumerate(row):
            y, x = i * (h + gap_px), j * (w + gap_px)
            out[y : y + h, x : x + w] = im
    return out
