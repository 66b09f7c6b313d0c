"""Each block's geometry against an independent numpy oracle (``network_oracle``): the curbs
lie where the block's definition puts them (``docs/networks.md``), meet the road ends at
``+-w / 2``, keep lanes ``w / 4`` off, never cross a lane, and stay within the chord-error bound.
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
    sagitta,
    socket_curb_ends,
)

from truckrl.sim.network import BLOCK_NAMES, GENERATORS, NetworkConfig
from truckrl.sim.network.blocks import _pad, slot_sizes
from truckrl.sim.network.compose import block_params

CFG = NetworkConfig()
M = 48  # blocks per type


def blocks(kind: int, seed: int = 0):
    """``M`` random blocks of type ``kind``: widths ``[M]``, params ``[M, 3]`` and the block, as
    numpy (float64)."""
    g = torch.Generator().manual_seed(seed)
    w = CFG.road_width[0] + (CFG.road_width[1] - CFG.road_width[0]) * torch.rand(M, generator=g)
    p = block_params(CFG, torch.full((M,), kind), torch.rand(M, 3, generator=g))
    b = _pad(GENERATORS[kind](CFG, w, p), slot_sizes(CFG))
    as_np = {
        k: v.double().numpy() if v.is_floating_point() else v.numpy() for k, v in vars(b).items()
    }
    return w.double().numpy(), p.double().numpy(), as_np


def rows(b, i):
    """Valid curbs ``[C, 4]``, lane segments ``[S, 4]``, lane polylines and sockets of row i."""
    curbs = b["curbs"][i][b["curb_mask"][i]]
    lanes = [b["lanes"][i, j] for j in np.flatnonzero(b["lane_mask"][i])]
    lane_segs = np.concatenate([polyline_segments(q) for q in lanes])
    return curbs, lane_segs, lanes, b["sockets"][i][b["socket_mask"][i]]


@pytest.mark.parametrize("kind", range(len(BLOCK_NAMES)), ids=BLOCK_NAMES)
def test_every_block_meets_its_road_ends_keeps_lanes_clear_and_never_crosses_them(kind):
    w, p, b = blocks(kind)
    for i in range(M):
        curbs, lane_segs, lanes, sockets = rows(b, i)
        # curb continuity: both curbs of the road end at socket +- w/2 (so a joined block's meet)
        for s in sockets:
            for end in socket_curb_ends(s, w[i]):
                assert has_endpoint(curbs, end), (BLOCK_NAMES[kind], i, s)
        # no curb crosses a lane centre-line
        assert not proper_crossings(curbs, lane_segs).any(), (BLOCK_NAMES[kind], i)
        # every lane point keeps (nearly) a quarter road width from every curb
        pts = np.concatenate(lanes)
        assert point_segment_distance(pts, curbs).min() >= 0.9 * 0.25 * w[i]
        # every socket has a lane in and a lane out of the block, w/2 apart
        for s in sockets:
            starts = np.array([q[0] for q in lanes])
            ends = np.array([q[-1] for q in lanes])
            right = np.array([np.sin(s[2]), -np.cos(s[2])]) * 0.25 * w[i]
            assert np.linalg.norm(starts - (s[:2] - right), axis=-1).min() < 1e-3  # in: its right
            assert np.linalg.norm(ends - (s[:2] + right), axis=-1).min() < 1e-3  # out


def test_straight_curbs_and_lanes_are_where_the_definition_puts_them():
    w, p, b = blocks(BLOCK_NAMES.index("straight"))
    for i in range(M):
        curbs, _, lanes, sockets = rows(b, i)
        length, h = p[i, 0], 0.5 * w[i]
        want = np.array([[0, -h, length, -h], [0, h, length, h]])
        np.testing.assert_allclose(curbs, want, atol=1e-4)
        np.testing.assert_allclose(lanes[0][[0, -1]], [[0, -h / 2], [length, -h / 2]], atol=1e-4)
        np.testing.assert_allclose(sockets, [[0, 0, math.pi], [length, 0, 0]], atol=1e-4)


def test_curve_curbs_lie_on_their_arcs_within_the_chord_error_bound():
    w, p, b = blocks(BLOCK_NAMES.index("curve"))
    for i in range(M):
        curbs, _, lanes, sockets = rows(b, i)
        radius, angle = p[i, 0], p[i, 1]
        s = 1.0 if angle >= 0 else -1.0
        centre = np.array([0.0, s * radius])
        half = len(curbs) // 2
        for piece, rho in (
            (curbs[:half], radius + s * 0.5 * w[i]),
            (curbs[half:], radius - s * 0.5 * w[i]),
        ):
            r = np.linalg.norm(piece.reshape(-1, 2) - centre, axis=-1)
            np.testing.assert_allclose(r, rho, atol=1e-3)  # vertices on the curb's arc
            assert sagitta(piece, centre, rho).max() <= CFG.chord_error + 1e-4
        for lane, rho in (
            (lanes[0], radius + s * 0.25 * w[i]),
            (lanes[1], radius - s * 0.25 * w[i]),
        ):
            np.testing.assert_allclose(np.linalg.norm(lane - centre, axis=-1), rho, atol=1e-3)
        exit_xy = [radius * math.sin(abs(angle)), s * radius * (1 - math.cos(angle))]
        np.testing.assert_allclose(sockets[1], [*exit_xy, angle], atol=1e-3)


def test_roundabout_radii_arms_and_sockets():
    w, p, b = blocks(BLOCK_NAMES.index("roundabout"))
    seen = set()
    for i in range(M):
        curbs, _, lanes, sockets = rows(b, i)
        radius, arms, arm = p[i]
        seen.add(int(arms))
        ends = curbs.reshape(-1, 2)
        r = np.linalg.norm(ends, axis=-1)
        outer, inner = radius + 0.5 * w[i], radius - 0.5 * w[i]
        on_island = np.isclose(r, inner, atol=1e-3)
        on_ring = np.isclose(r, outer, atol=1e-3)
        reach = outer + arm
        at_end = np.isclose(r, math.hypot(reach, 0.5 * w[i]), atol=1e-3)
        assert (
            on_island | on_ring | at_end
        ).all()  # every curb vertex: island, outer ring, or road end
        # the ring lane runs on the centre-line radius, counter-clockwise
        ring = lanes[0]
        np.testing.assert_allclose(np.linalg.norm(ring, axis=-1), radius, atol=1e-3)
        (ax, ay), (bx, by) = ring[1] - ring[0], ring[2] - ring[1]
        turn = ax * by - ay * bx
        assert turn > 0
        # 3 or 4 sockets, evenly spaced, at the end of each arm
        assert len(sockets) == int(arms)
        np.testing.assert_allclose(np.linalg.norm(sockets[:, :2], axis=-1), reach, atol=1e-3)
        gaps = np.diff(np.unwrap(sockets[:, 2]))
        np.testing.assert_allclose(gaps, 2 * math.pi / arms, atol=1e-4)
        # chord error of the island and the outer arcs
        island = curbs[
            np.isclose(np.linalg.norm(curbs[:, :2], axis=-1), inner, atol=1e-3)
            & np.isclose(np.linalg.norm(curbs[:, 2:], axis=-1), inner, atol=1e-3)
        ]
        assert sagitta(island, np.zeros(2), inner).max() <= CFG.chord_error + 1e-4
        ring_arcs = curbs[
            np.isclose(np.linalg.norm(curbs[:, :2], axis=-1), outer, atol=1e-3)
            & np.isclose(np.linalg.norm(curbs[:, 2:], axis=-1), outer, atol=1e-3)
        ]
        assert sagitta(ring_arcs, np.zeros(2), outer).max() <= CFG.chord_error + 1e-4
        # the island is closed: its polyline goes all the way round
        assert len(island) >= 3 and np.allclose(island[0, :2], island[-1, 2:], atol=1e-3)
    assert seen == {3, 4}


def test_crossing_and_t_junction_curbs_lie_on_their_roads_edges_outside_the_other_road():
    for name in ("crossing", "t_junction"):
        w, p, b = blocks(BLOCK_NAMES.index(name))
        for i in range(M):
            curbs, _, _, _ = rows(b, i)
            h = 0.5 * w[i]
            angle = p[i, 0] if name == "crossing" else -math.pi / 2
            roads = [np.array([1.0, 0.0]), np.array([math.cos(angle), math.sin(angle)])]
            normals = [np.array([-d[1], d[0]]) for d in roads]
            # points along every curb: both ends and three between
            f = np.linspace(0.0, 1.0, 5)[None, :, None]
            pts = curbs[:, None, :2] + f * (curbs[:, None, 2:] - curbs[:, None, :2])  # [C, 5, 2]
            dist = np.stack([np.abs(pts @ n) for n in normals])  # [road, curb, point]
            on_edge = np.isclose(dist, h, atol=1e-3).all(-1)
            assert on_edge.any(0).all(), (name, i)  # every curb along an edge line of a road
            # ... and no point of it inside the other road (the junction's surface is open)
            in_road1 = dist[1] < h - 1e-3
            if name == "t_junction":  # the stem is half a road: below the bar only
                in_road1 &= pts[..., 1] < -h + 1e-3
            in_road0 = dist[0] < h - 1e-3
            inside_other = np.where(on_edge[0][:, None], in_road1, in_road0)
            assert not inside_other.any(), (name, i)
            assert len(curbs) == (8 if name == "crossing" else 5)


def test_median_widens_the_road_by_its_width_round_an_island():
    w, p, b = blocks(BLOCK_NAMES.index("median"))
    for i in range(M):
        curbs, _, lanes, _ = rows(b, i)
        length, width = p[i, 0], p[i, 1]
        mid = length / 2
        across = np.array([[mid, -50.0, mid, 50.0]])
        hit = proper_crossings(across, curbs)[0]
        ys = []
        for c in curbs[hit]:
            t = (mid - c[0]) / (c[2] - c[0])
            ys.append(c[1] + t * (c[3] - c[1]))
        ys = np.sort(ys)  # outer curb, island, island, outer curb
        np.testing.assert_allclose(
            ys, [-(w[i] + width) / 2, -width / 2, width / 2, (w[i] + width) / 2], atol=1e-3
        )
        for lane in lanes:  # the lanes keep a quarter road width from the curbs beside them
            k = np.argmin(np.abs(lane[:, 0] - mid))
            assert abs(abs(lane[k, 1]) - (width / 2 + w[i] / 4)) < 1e-3


def test_slot_counts_keep_the_chord_error_for_the_ranges_largest_arcs():
    """The polyline piece counts come from the config's upper ends (hand-computed here)."""
    rho = CFG.curve_radius[1] + CFG.road_width[1] / 2
    step = 2 * math.acos(1 - CFG.chord_error / rho)
    assert CFG.curve_pieces() == math.ceil(CFG.curve_angle[1] / step)
    assert rho * (1 - math.cos(CFG.curve_angle[1] / CFG.curve_pieces() / 2)) <= CFG.chord_error
