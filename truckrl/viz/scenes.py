"""Render a grid of random scenes, with the truck at its start pose and the goal, to a PNG.

Examples::

    python -m truckrl.viz.scenes --count 4 --seed 0 --out docs/scenes.png
    python -m truckrl.viz.scenes --time 4096          # also time generating 4,096 scenes
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from truckrl.sim.vehicle import VehicleConfig, sample_vehicle_params, truck_corners
from truckrl.tasks.intersection.scene import SceneBatch, SceneConfig, generate_scenes
from truckrl.viz.draw import draw_scene


def render_grid(
    batch: SceneBatch,
    params: dict[str, torch.Tensor],
    *,
    cols: int,
    tile_px: int,
    view_half_extent: float,
    border_px: int = 4,
) -> np.ndarray:
    """Draw every scene of ``batch`` into one ``[H, W, 3]`` uint8 RGB grid, ``cols`` tiles wide.

    Each tile is centred between start and goal and spans ``+-view_half_extent`` metres.
    """
    n = len(batch)
    zeros = torch.zeros(n, 1, device=batch.device)
    start_tractor, start_trailer, _ = truck_corners(torch.cat((batch.start, zeros), -1), params)
    goal_tractor, goal_trailer, _ = truck_corners(torch.cat((batch.goal, zeros), -1), params)
    rows = -(-n // cols)
    grid = np.full(
        (rows * (tile_px + border_px) + border_px, cols * (tile_px + border_px) + border_px, 3),
        255,
        dtype=np.uint8,
    )
    for i in range(n):
        obstacles = int(batch.mask[i, 8:].sum()) // 4
        dist = float((batch.goal[i, :2] - batch.start[i, :2]).norm())
        hud = [
            f"#{i}: {'crossing' if batch.crossing[i] else 'straight road'}",
            f"goal {dist:.1f} m, {obstacles} obstacles",
        ]
        tile = draw_scene(
            batch.segments[i],
            batch.mask[i],
            batch.kind[i],
            tractor=start_tractor[i],
            trailer=start_trailer[i],
            goal=batch.goal[i],
            goal_footprint=torch.stack((goal_tractor[i], goal_trailer[i])),
            center=0.5 * (batch.start[i, :2] + batch.goal[i, :2]),
            size_px=tile_px,
            view_half_extent=view_half_extent,
            hud_lines=hud,
        )
        r, c = divmod(i, cols)
        y0 = border_px + r * (tile_px + border_px)
        x0 = border_px + c * (tile_px + border_px)
        grid[y0 : y0 + tile_px, x0 : x0 + tile_px] = tile
    return grid


def time_generation(n: int, device: str, repeats: int = 5) -> list[float]:
    """Wall seconds of ``repeats`` calls generating ``n`` default scenes (after one warm-up)."""
    g = torch.Generator(device=device).manual_seed(0)
    params = sample_vehicle_params(VehicleConfig(), n, generator=g, device=device)
    cfg = SceneConfig()
    generate_scenes(cfg, params, generator=g)
    out = []
    for _ in range(repeats):
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        generate_scenes(cfg, params, generator=g)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        out.append(time.perf_counter() - t0)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m truckrl.viz.scenes",
        description="Render random truckrl scenes (default scene and vehicle configs) to a PNG grid.",
    )
    parser.add_argument("--count", type=int, default=4, help="number of scenes (default 4)")
    parser.add_argument("--seed", type=int, default=0, help="generator seed (default 0)")
    parser.add_argument("--out", type=Path, default=Path("scenes.png"), help="output PNG path")
    parser.add_argument("--cols", type=int, default=2, help="tiles per row (default 2)")
    parser.add_argument("--tile", type=int, default=400, help="tile side in pixels (default 400)")
    parser.add_argument(
        "--half-extent", type=float, default=50.0, help="view half-extent per tile [m] (default 50)"
    )
    parser.add_argument("--device", default="cpu", help="torch device (default cpu)")
    parser.add_argument(
        "--time", type=int, default=0, metavar="N", help="also time generating N scenes"
    )
    args = parser.parse_args(argv)
    if args.count < 1 or args.cols < 1 or args.tile < 16:
        parser.error("--count and --cols must be >= 1 and --tile >= 16")

    g = torch.Generator(device=args.device).manual_seed(args.seed)
    params = sample_vehicle_params(VehicleConfig(), args.count, generator=g, device=args.device)
    batch = generate_scenes(SceneConfig(), params, generator=g)
    grid = render_grid(
        batch,
        params,
        cols=min(args.cols, args.count),
        tile_px=args.tile,
        view_half_extent=args.half_extent,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR)):
        raise SystemExit(f"could not write {args.out}")
    print(f"wrote {args.out} ({args.count} scenes, seed {args.seed})")
    if args.time > 0:
        secs = time_generation(args.time, args.device)
        print(
            f"generate_scenes: {args.time} scenes on {args.device} "
            f"({torch.get_num_threads()} threads): best {min(secs):.3f} s, "
            f"median {sorted(secs)[len(secs) // 2]:.3f} s over {len(secs)} runs"
        )


if __name__ == "__main__":
    main()
