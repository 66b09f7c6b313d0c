"""A grid of random road networks for the docs (``docs/media/networks.png``).

    python docs/media/draw_networks.py                  # 6 networks, seed 0
    python docs/media/draw_networks.py --seed 3 --count 9 --out /tmp/nets.png

The curbs are drawn by the scene renderer (:func:`truckrl.viz.draw.draw_scene`) from the
networks' ``segments`` and ``mask`` alone, as the env draws any scene; the lane centre-lines
(metadata, thin blue) and the joints between blocks (yellow dots) are drawn over them here.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from truckrl.sim.network import BLOCK_NAMES, NetworkConfig, random_network
from truckrl.viz.draw import draw_scene, make_view, world_to_pixel

HERE = Path(__file__).resolve().parent
LANE = (90, 150, 255)
JOINT = (250, 210, 60)


def tile(net, i: int, px: int) -> np.ndarray:
    """Network ``i`` of ``net`` drawn into a ``[px, px, 3]`` RGB tile fitted to its curbs."""
    valid = net.mask[i]
    pts = net.segments[i][valid].reshape(-1, 2).numpy()
    lo, hi = pts.min(0), pts.max(0)
    centre, half = 0.5 * (lo + hi), 0.55 * float((hi - lo).max())
    k = int(net.num_blocks[i])
    names = [BLOCK_NAMES[int(t)] for t in net.block_type[i, :k]]
    hud = [f"#{i}: {k} blocks, {int(valid.sum())} segments", " > ".join(names)]
    img = draw_scene(
        net.segments[i], valid, net.kind[i], center=centre, size_px=px, view_half_extent=half,
        hud_lines=hud[:1],
    )  # fmt: skip
    view = make_view(px, centre, view_half_extent=half)
    for lane in net.lanes[i][net.lane_mask[i]].numpy():
        q = np.round(world_to_pixel(lane, view)).astype(np.int32)
        cv2.polylines(img, [q], False, LANE, 1, cv2.LINE_AA)
    for b in range(k - 1):
        s = net.sockets[i, b, int(net.exit[i, b])].numpy()
        q = np.round(world_to_pixel(s[:2], view)).astype(int)
        cv2.circle(img, (int(q[0]), int(q[1])), 4, JOINT, -1, cv2.LINE_AA)
    # the block sequence, small, along the bottom
    cv2.putText(
        img, hud[1], (8, px - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (245, 245, 245), 1, cv2.LINE_AA
    )
    return img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--cols", type=int, default=3)
    ap.add_argument("--px", type=int, default=420)
    ap.add_argument("--out", type=Path, default=HERE / "networks.png")
    args = ap.parse_args()
    net = random_network(NetworkConfig(), args.count, torch.Generator().manual_seed(args.seed))
    rows, border = -(-args.count // args.cols), 4
    grid = np.full(
        (rows * (args.px + border) + border, args.cols * (args.px + border) + border, 3),
        255,
        dtype=np.uint8,
    )
    for i in range(args.count):
        r, c = divmod(i, args.cols)
        y, x = border + r * (args.px + border), border + c * (args.px + border)
        grid[y : y + args.px, x : x + args.px] = tile(net, i, args.px)
    cv2.imwrite(str(args.out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    print(args.out)


if __name__ == "__main__":
    main()
