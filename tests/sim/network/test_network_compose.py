"""Random networks against the oracle's rules (``network_oracle``), and the paper's claim: a
network's segments go through today's collision and LiDAR unchanged.

Rules, for every network: joined sockets coincide, facing each other, with both blocks' curbs
ending at the shared road end; no curb crosses a lane centre-line (any block's); every lane point
keeps nearly a quarter road width from every curb; no curb of one block crosses a curb of
another; padding is zero and masked; the block count is within its range.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from network_oracle import (
    has_endpoint,
    point_segment_distance,
    polyline_segments,
    proper_crossings,
    socket_curb_ends,
)

from truckrl.sim import (
    VehicleConfig,
    beam_angles,
    lidar_scan,
    sample_vehicle_params,
    truck_collides,
)
from truckrl.sim.network import NetworkConfig, random_network
from truckrl.sim.network.layout import network_from_blocks


def violations(net, cfg: NetworkConfig) -> list[str]:
    """Every broken rule of every network in ``net`` (module doc), as readable lines."""
    seg, mask = net.segments.double().numpy(), net.mask.numpy()
    lanes, lane_mask = net.lanes.double().numpy(), net.lane_mask.numpy()
    sockets, owner = net.sockets.double().numpy(), net.segment_block.numpy()
    entry, exit_, count = net.entry.numpy(), net.exit.numpy(), net.num_blocks.numpy()
    width = net.road_width.double().numpy()
    bad = []
    for i in range(len(net)):
        curbs, who = seg[i][mask[i]], owner[i][mask[i]]
        if np.abs(seg[i][~mask[i]]).max(initial=0.0) > 0 or (owner[i][~mask[i]] != -1).any():
            bad.append(f"{i}: padding not zero")
        if not 1 <= count[i] <= cfg.num_blocks[1] or not net.block_mask[i, : count[i]].all():
            bad.append(f"{i}: {count[i]} blocks")
        for k in range(count[i] - 1):
            a, b = sockets[i, k, exit_[i, k]], sockets[i, k + 1, entry[i, k + 1]]
            facing = math.cos(a[2] - b[2]) < -1 + 1e-6
            if np.linalg.norm(a[:2] - b[:2]) > 1e-3 or not facing:
                bad.append(f"{i}: blocks {k}, {k + 1} do not meet")
            for end in socket_curb_ends(a, width[i]):
                for j in (k, k + 1):
                    if not has_endpoint(curbs[who == j], end):
                        bad.append(f"{i}: block {j}'s curb does not end at joint {k}")
        polylines = [lanes[i, j] for j in np.flatnonzero(lane_mask[i])]
        lane_segs = np.concatenate([polyline_segments(q) for q in polylines])
        if proper_crossings(curbs, lane_segs).any():
            bad.append(f"{i}: a curb crosses a lane")
        points = np.unique(lane_segs.reshape(-1, 2), axis=0)
        near = point_segment_distance(points, curbs).min()
        if near < 0.9 * 0.25 * width[i]:
            bad.append(f"{i}: a lane point {near:.2f} m from a curb")
        crossing = proper_crossings(curbs, curbs)
        if (crossing & (who[:, None] != who[None, :])).any():
            bad.append(f"{i}: curbs of two blocks cross")
    return bad


def test_1000_random_networks_break_no_rule():
    cfg = NetworkConfig()
    net = random_network(cfg, 1000, torch.Generator().manual_seed(1))
    assert violations(net, cfg) == []
    # every type is drawn, and overlap rejection rarely ends a chain before its drawn length
    assert set(net.block_type[net.block_mask].unique().tolist()) == set(range(6))
    assert (net.num_blocks >= cfg.num_blocks[0]).float().mean() > 0.97


@pytest.mark.slow
def test_100000_random_networks_break_no_rule():
    cfg = NetworkConfig()
    for seed in range(100):
        net = random_network(cfg, 1000, torch.Generator().manual_seed(1000 + seed))
        assert violations(net, cfg) == [], seed


def test_random_loops_are_redrawn():
    """Quarter-circle curves close loops often; a random network of only those never keeps an
    overlap (rules above) and still grows, redrawing (turning the other way) instead."""
    cfg = NetworkConfig(
        block_types=("curve",), curve_angle=(math.pi / 2, math.pi / 2), num_blocks=(6, 6)
    )
    net = random_network(cfg, 100, torch.Generator().manual_seed(2))
    assert violations(net, cfg) == []
    assert net.num_blocks.float().mean() > 4


def test_same_seed_same_networks():
    cfg = NetworkConfig()
    a = random_network(cfg, 16, torch.Generator().manual_seed(5))
    b = random_network(cfg, 16, torch.Generator().manual_seed(5))
    assert torch.equal(a.segments, b.segments) and torch.equal(a.lanes, b.lanes)


# ------------------------------------------------------------------ the paper's claim, tested
def straight_network(width: float = 9.0):
    return network_from_blocks(
        {"road_width": width, "blocks": [{"type": "straight", "length": 60.0}]}
    )


def test_a_network_goes_through_todays_collision_unchanged():
    net = straight_network()
    params = sample_vehicle_params(VehicleConfig(), 2, torch.Generator().manual_seed(0))
    # rear axle on the forward lane (y = -w/4) heading along it; then the same truck turned
    # across the road, its body over the curb at y = -w/2
    pose = torch.tensor([[30.0, -9.0 / 4, 0.0, 0.0], [30.0, -9.0 / 4, math.pi / 2, 0.0]])
    seg = net.segments.expand(2, -1, -1)
    hit = truck_collides(pose, params, seg, net.mask.expand(2, -1))
    assert hit.tolist() == [False, True]


def test_a_network_goes_through_todays_lidar_unchanged():
    """On a straight road 9 m wide, a sensor on the forward lane (w/4 = 2.25 m left of the right
    curb) sees the right curb at 2.25 m, the left one at 6.75 m, nothing ahead or behind."""
    net = straight_network(9.0)
    ranges = lidar_scan(
        torch.tensor([[30.0, -2.25]]), torch.tensor([0.0]), net.segments, net.mask,
        beam_angles(4), max_range=25.0,
    )  # fmt: skip
    # beams at -pi (back), -pi/2 (right), 0 (ahead), pi/2 (left)
    torch.testing.assert_close(ranges, torch.tensor([[25.0, 2.25, 25.0, 6.75]]))


def test_a_crossing_network_truck_through_the_junction_is_clear_and_across_a_corner_is_not():
    net = network_from_blocks(
        {"road_width": 10.0, "blocks": [{"type": "crossing", "angle_deg": 90, "arm": 30}]}
    )
    params = sample_vehicle_params(VehicleConfig(), 2, torch.Generator().manual_seed(0))
    # entered at the origin heading +x: the junction centre is at x = 30
    pose = torch.tensor([[33.0, -2.5, 0.0, 0.0], [25.0, 5.0, math.pi / 4, 0.0]])
    hit = truck_collides(pose, params, net.segments.expand(2, -1, -1), net.mask.expand(2, -1))
    assert hit.tolist() == [False, True]
