"""Road geometry (truckrl/sim/roads.py) against answers computed by hand."""

import math

import pytest
import torch

from truckrl.sim.roads import (
    CROSSING_CURB_SLOTS,
    crossing_curbs,
    crossing_roads,
    lane_offset,
    to_world,
    turn_exit_room,
)


def roads_of(centre, headings, widths):
    """One scene's two roads; the crossing angle is road 1's heading minus road 0's."""
    heading = torch.tensor([headings])
    return crossing_roads(
        torch.tensor([centre]), heading, torch.tensor([widths]), heading[:, 1] - heading[:, 0]
    )


def test_straight_road_curbs():
    """A road along +y through (1, 2), 4 m wide, +-10 m long: its left normal is (-1, 0), so the
    curb on side -n is x = 3 and the one on side +n is x = -1, both from y = -8 to y = 12."""
    roads = roads_of((1.0, 2.0), (math.pi / 2, math.pi), (4.0, 6.0))
    curbs, mask = crossing_curbs(roads, torch.tensor([False]), 10.0)
    assert curbs.shape == (1, CROSSING_CURB_SLOTS, 4)
    assert mask[0].tolist() == [True, True] + [False] * 6
    expected = torch.tensor([[3.0, -8.0, 3.0, 12.0], [-1.0, -8.0, -1.0, 12.0]])
    assert torch.allclose(curbs[0, :2], expected, atol=1e-5)
    assert torch.equal(curbs[0, 2:], torch.zeros(6, 4))


def test_right_angle_crossing():
    """Road 0 along +x, 4 m wide; road 1 along +y, 6 m wide, through the origin: the
    parallelogram is the rectangle |x| <= 3, |y| <= 2, counter-clockwise from (3, -2), and each
    curb stops at it."""
    roads = roads_of((0.0, 0.0), (0.0, math.pi / 2), (4.0, 6.0))
    corners = torch.tensor([[3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]])
    assert torch.allclose(roads.corners[0], corners, atol=1e-5)
    assert torch.allclose(roads.extent[0], torch.tensor([3.0, 2.0]), atol=1e-5)
    curbs, mask = crossing_curbs(roads, torch.tensor([True]), 10.0)
    assert mask.all()
    expected = torch.tensor(
        [
            [-10.0, -2.0, -3.0, -2.0],  # road 0, side -n = (0, -1): y = -2, before the crossing
            [3.0, -2.0, 10.0, -2.0],  # after it
            [-10.0, 2.0, -3.0, 2.0],  # road 0, side +n: y = 2
            [3.0, 2.0, 10.0, 2.0],
            [3.0, -10.0, 3.0, -2.0],  # road 1, side -n = (1, 0): x = 3
            [3.0, 2.0, 3.0, 10.0],
            [-3.0, -10.0, -3.0, -2.0],  # road 1, side +n: x = -3
            [-3.0, 2.0, -3.0, 10.0],
        ]
    )
    assert torch.allclose(curbs[0], expected, atol=1e-5)


def test_lane_offset():
    """Road 10 m wide, body half width 1 m: 0.5 m from the curb puts the centre 3.5 m off the
    centreline; a gap wider than the lane keeps the body in its half (1 m). A body wider than
    its half of a 3 m road stays on the road: 1.5 - 1 = 0.5 m."""
    width, gap = torch.tensor([10.0, 10.0, 3.0]), torch.tensor([0.5, 9.0, 0.5])
    assert lane_offset(width, gap, torch.ones(3)).tolist() == [3.5, 1.0, 0.5]


def test_turn_exit_room():
    """Start at the origin along +x, goal at (10, 5) along +y: the lanes meet at (10, 0), 5 m
    before the goal; a 90 deg turn's arc takes tan(45 deg) = 1 trailer wheelbase of it, so a
    2.5 m trailer wheelbase leaves 5 / 2.5 - 1 = 1."""
    room = turn_exit_room(
        torch.tensor([[0.0, 0.0]]),
        torch.tensor([[1.0, 0.0]]),
        torch.tensor([[10.0, 5.0]]),
        torch.tensor([[0.0, 1.0]]),
        torch.tensor([2.5]),
    )
    assert room.item() == pytest.approx(1.0, abs=1e-6)


def test_to_world():
    """(1, 0) in a frame at (2, 3) turned by 90 deg is (2, 4) in the world."""
    xy = to_world(
        torch.tensor([[[1.0, 0.0]]]), torch.tensor([math.pi / 2]), torch.tensor([[2.0, 3.0]])
    )
    assert torch.allclose(xy, torch.tensor([[[2.0, 4.0]]]), atol=1e-6)
