"""Trailer collision at articulation +-0.5 rad against a trailer corner worked out by hand."""

import math

import pytest
import torch

from truckrl.sim.collision import contour_collides, truck_collides
from truckrl.sim.vehicle import vehicle_outline

#: One fixed truck [m, rad] (round numbers inside the default ranges).
TRUCK = {
    "wheelbase": 4.0,
    "front_overhang": 1.4,
    "rear_overhang": 1.0,
    "tractor_width": 2.5,
    "kingpin_offset": 0.2,
    "cab_gap": 1.0,
    "trailer_wheelbase": 8.0,
    "trailer_front_overhang": 1.2,
    "trailer_rear_overhang": 2.0,
    "trailer_width": 2.6,
    "max_steer": 0.6,
    "max_articulation": 1.3,
    "max_speed": 8.0,
    "max_accel": 2.0,
    "max_jerk": 4.0,
    "max_steer_rate": 0.5,
    "max_steer_accel": 2.0,
}

# Pose (x, y, theta, phi) = (0, 0, 0, phi): tractor rear axle at the origin heading +x.
# The kingpin is kingpin_offset = 0.2 m behind the rear axle: hitch at (-0.2, 0).
# The trailer heads theta + phi = phi; its rear face is trailer_wheelbase + trailer_rear_overhang
# = 8.0 + 2.0 = 10.0 m behind the hitch, half its width 1.3 m to each side.
# phi = +0.5: cos 0.5 = 0.877583, sin 0.5 = 0.479426
#   rear centre = (-0.2 - 10 cos 0.5, -10 sin 0.5) = (-8.975826, -4.794255)
#   right of the heading is (sin 0.5, -cos 0.5) = (0.479426, -0.877583); times 1.3:
#   (0.623253, -1.140857), so the rear-right corner is (-8.352572, -5.935113)
# phi = -0.5: the mirror image in y; the rear-left corner is (-8.352572, +5.935113).
CORNERS = {0.5: (-8.352572, -5.935113), -0.5: (-8.352572, 5.935113)}


def _short_segment_at(corner, phi, offset):
    """A 0.4 m segment across the corner's outward diagonal, centred ``offset`` [m] out along it
    (negative: inside). Its nearest point to the trailer rectangle is its midpoint: along the
    diagonal both edge distances are ``|offset| / sqrt 2``."""
    back = (-math.cos(phi), -math.sin(phi))  # outward normal of the rear face
    side = (math.sin(phi), -math.cos(phi)) if phi > 0 else (-math.sin(phi), math.cos(phi))
    diag = ((back[0] + side[0]) / math.sqrt(2), (back[1] + side[1]) / math.sqrt(2))
    across = ((back[0] - side[0]) / math.sqrt(2), (back[1] - side[1]) / math.sqrt(2))
    mx, my = corner[0] + offset * diag[0], corner[1] + offset * diag[1]
    return [mx - 0.2 * across[0], my - 0.2 * across[1], mx + 0.2 * across[0], my + 0.2 * across[1]]


@pytest.mark.parametrize("phi", [0.5, -0.5])
@pytest.mark.parametrize(("offset", "hits"), [(0.01, False), (-0.01, True)])
def test_segment_one_centimetre_outside_or_inside_the_trailer_rear_corner(phi, offset, hits):
    params = {k: torch.tensor([v]) for k, v in TRUCK.items()}
    pose = torch.tensor([[0.0, 0.0, 0.0, phi]])
    segs = torch.tensor([[_short_segment_at(CORNERS[phi], phi, offset)]])
    assert bool(truck_collides(pose, params, segs)[0]) == hits
    # the segment crosses both edges at the corner, so the contour test agrees
    assert bool(contour_collides(vehicle_outline(pose, params), segs)[0]) == hits
