"""A grid of random road networks for the docs (``docs/media/networks.png``).

    python docs/media/draw_networks.py                  # 6 networks, seed 0
    python docs/media/draw_networks.py --seed 3 --count 9 --out /tmp/nets.png
    python docs/media/draw_networks.py --traffic        # networks_traffic.png: with vehicles

The curbs are drawn by the scene renderer (:func:`truckrl.viz.draw.draw_scene`) from the
networks' ``segments`` and ``mask`` alone, as the env draws any scene; the lane centre-lines
(metadata, thin blue) and the joints between blocks (yellow dots) are drawn over them here.
With ``--traffic`` the networks carry moving traffic (:mod:`truckrl.sim.network.traffic`) after
``--seconds`` of driving: the vehicles' outlines are appended to the scene
(:func:`~truckrl.sim.network.traffic.with_traffic`) and drawn by the same renderer, filled here
(cars orange, trucks red), with the junction zones as grey circles.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from truckrl.sim.network import (
    BLOCK_NAMES,
    NetworkConfig,
    TrafficConfig,
    random_network,
    spawn_traffic,
    step_traffic,
    traffic_segments,
    with_traffic,
)
from truckrl.viz.draw import draw_scene, make_view, world_to_pixel

HERE = Path(__file__).resolve().parent
LANE = (90, 150, 255)
JOINT = (250, 210, 60)
CAR, TRUCK, ZONE = (255, 150, 40), (220, 50, 50), (150, 150, 150)


def tile(net, i: int, px: int, traffic=None) -> np.ndarray:
    """Network ``i`` of ``net`` (with ``traffic``, if given) drawn into a ``[px, px, 3]`` RGB tile
    fitted to its curbs."""
    valid = net.mask[i]
    pts = net.segments[i][valid].reshape(-1, 2).numpy()
    lo, hi = pts.min(0), pts.max(0)
    centre, half = 0.5 * (lo + hi), 0.55 * float((hi - lo).max())
    k = int(net.num_blocks[i])
    names = [BLOCK_NAMES[int(t)] for t in net.block_type[i, :k]]
    hud = [f"#{i}: {k} blocks, {int(valid.sum())} segments", " > ".join(names)]
    segments, mask, kind = net.segments[i], valid, net.kind[i]
    if traffic is not None:
        count = int(traffic.present()[i].sum())
        hud[0] += f", {count} vehicles"
        segments, mask, kind = (
            t[0]
            for t in with_traffic(
                net.segments[i : i + 1], valid[None], net.kind[i : i + 1],
                type(traffic)(**{k: getattr(traffic, k)[i : i + 1] for k in vars(traffic)}),
            )
        )  # fmt: skip
    img = draw_scene(
        segments, mask, kind, center=centre, size_px=px, view_half_extent=half, hud_lines=hud[:1]
    )
    view = make_view(px, centre, view_half_extent=half)
    for lane in net.lanes[i][net.lane_mask[i]].numpy():
        q = np.round(world_to_pixel(lane, view)).astype(np.int32)
        cv2.polylines(img, [q], False, LANE, 1, cv2.LINE_AA)
    for b in range(k - 1):
        s = net.sockets[i, b, int(net.exit[i, b])].numpy()
        q = np.round(world_to_pixel(s[:2], view)).astype(int)
        cv2.circle(img, (int(q[0]), int(q[1])), 4, JOINT, -1, cv2.LINE_AA)
    if traffic is not None:
        for c, r, ok in zip(
            traffic.zone_centre[i].numpy(), traffic.zone_radius[i].numpy(),
            traffic.zone_mask[i].numpy(), strict=True,
        ):  # fmt: skip
            if ok:
                q = np.round(world_to_pixel(c, view)).astype(int)
                rad = int(round(r / view.metres_per_px))
                cv2.circle(img, (int(q[0]), int(q[1])), rad, ZONE, 1, cv2.LINE_AA)
        seg, on = traffic_segments(traffic)
        boxes = seg[i].view(-1, 4, 4)[:, :, :2].numpy()
        for box, ok, truck in zip(
            boxes, on[i].view(-1, 4)[:, 0].numpy(), traffic.truck[i].numpy(), strict=True
        ):
            if ok:
                q = np.round(world_to_pixel(box, view)).astype(np.int32)
                cv2.fillPoly(img, [q], TRUCK if truck else CAR, cv2.LINE_AA)
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
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--traffic", action="store_true", help="with moving traffic")
    ap.add_argument("--seconds", type=float, default=30.0, help="traffic driven this long [s]")
    args = ap.parse_args()
    out = args.out or HERE / ("networks_traffic.png" if args.traffic else "networks.png")
    gen = torch.Generator().manual_seed(args.seed)
    net = random_network(NetworkConfig(), args.count, gen)
    traffic = None
    if args.traffic:
        cfg = TrafficConfig(density=(2.0, 3.0))
        traffic = spawn_traffic(net, cfg, gen)
        for _ in range(int(round(args.seconds / 0.1))):
            traffic = step_traffic(traffic, cfg, 0.1)
    rows, border = -(-args.count // args.cols), 4
    grid = np.full(
        (rows * (args.px + border) + border, args.cols * (args.px + border) + border, 3),
        255,
        dtype=np.uint8,
    )
    for i in range(args.count):
        r, c = divmod(i, args.cols)
        y, x = border + r * (args.px + border), border + c * (args.px + border)
        grid[y : y + args.px, x : x + args.px] = tile(net, i, args.px, traffic)
    cv2.imwrite(str(out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    print(out)


if __name__ == "__main__":
    main()
