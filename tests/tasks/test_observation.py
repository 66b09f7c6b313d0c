"""Every observation index against a hand-built pose and hand-computed values (no reuse of the
observation code): goal frame and signs, normalisations, the LiDAR origin and beam order."""

import math

import pytest
import torch

from truckrl.env import TruckEnv

# A truck at (10, 5) heading north (+y) with the trailer 0.2 rad to the left, goal at (0, 25)
# heading west (pi). In the tractor frame (x forward = world +y, y left = world -x) the goal is
# 20 m ahead and 10 m to the left.
POSE = (10.0, 5.0, math.pi / 2, 0.2)
GOAL = (0.0, 25.0, math.pi)
PARAMS = {  # each at a known point of its default range [min, max]
    "wheelbase": 3.8,  # [3.4, 4.2] mid -> 0
    "kingpin_offset": -0.5,  # [-0.5, 0.3] min -> -1
    "trailer_wheelbase": 11.0,  # [6, 11] max -> +1
    "front_overhang": 1.5,  # [1.2, 1.6] -> +0.5
    "rear_overhang": 0.75,  # [0.6, 1.2] -> -0.5
    "tractor_width": 2.3,  # [2.3, 2.55] -> -1
    "trailer_rear_overhang": 2.25,  # [1, 3.5] -> 0
    "trailer_width": 2.6,  # [2.4, 2.6] -> +1
    "max_steer": 0.625,  # [0.55, 0.7] -> 0
    "max_speed": 9.0,  # [6, 10] -> +0.5
    "max_accel": 2.625,  # [1.5, 3] -> +0.5
    "max_jerk": 4.0,  # [2, 5]
    "max_steer_rate": 0.5,  # [0.4, 0.8] -> -0.5
    "max_steer_accel": 2.0,  # [1, 3]
}
CONTROL = {"speed": 3.0, "accel": 1.0, "jerk": -2.0, "steer": 0.25, "steer_rate": -0.1}
CONTROL["steer_accel"] = 0.5
WALL_AHEAD = 12.0  # [m] from the LiDAR origin, across the heading


@pytest.fixture(scope="module")
def obs():
    env = TruckEnv(num_envs=1, seed=0)
    env.reset()
    s = env.get_state()
    s["pose"] = torch.tensor([POSE])
    s["goal"] = torch.tensor([GOAL])
    for k, v in PARAMS.items():
        s["params", k] = torch.tensor([v])
    for k, v in CONTROL.items():
        s[k] = torch.tensor([v])
    # LiDAR origin: tractor body centre, 0.5 * (3.8 + 1.5 - 0.75) = 2.275 m ahead of the rear axle
    origin_y = POSE[1] + 2.275
    wall_y = origin_y + WALL_AHEAD
    s["segments"] = torch.zeros_like(s["segments"])
    s["mask"] = torch.zeros_like(s["mask"])
    s["segments"][0, 0] = torch.tensor([-30.0, wall_y, 50.0, wall_y])
    s["mask"][0, 0] = True
    s.update(env.task.errors(s))
    td = env.set_state(s)
    return td["observation"][0].double(), td["lidar"][0].double()


def test_goal_position_in_the_tractor_frame(obs):
    o, _ = obs
    assert o[0] == pytest.approx(20.0 / 50.0, abs=1e-6)  # ahead, / 50 m (paper)
    assert o[1] == pytest.approx(10.0 / 50.0, abs=1e-6)  # left is positive


def test_heading_features(obs):
    o, _ = obs
    d_tractor = GOAL[2] - POSE[2]  # pi/2: goal heading is 90 deg to the left of the tractor
    d_trailer = d_tractor - POSE[3]
    expected = [
        math.sin(d_tractor),
        math.cos(d_tractor),
        math.sin(d_trailer),
        math.cos(d_trailer),
        math.sin(POSE[3]),
        math.cos(POSE[3]),
    ]
    assert o[2:8].tolist() == pytest.approx(expected, abs=1e-6)


def test_motion_over_limits(obs):
    o, _ = obs
    p, c = PARAMS, CONTROL
    expected = [
        c["speed"] / p["max_speed"],
        c["accel"] / p["max_accel"],
        c["jerk"] / p["max_jerk"],
        c["steer"] / p["max_steer"],
        c["steer_rate"] / p["max_steer_rate"],
        c["steer_accel"] / p["max_steer_accel"],
    ]
    assert o[8:14].tolist() == pytest.approx(expected, abs=1e-6)


def test_geometry_and_mode_limits_mapped_to_minus_one_one(obs):
    o, _ = obs
    # indices 14..23 in the documented order, then the accel (max_accel) and rate
    # (max_steer_rate) limits of the default control mode
    expected = [0.0, -1.0, 1.0, 0.5, -0.5, -1.0, 0.0, 1.0, 0.0, 0.5, 0.5, -0.5]
    assert o[14:26].tolist() == pytest.approx(expected, abs=1e-5)
    assert o.shape == (26,)


def test_lidar_origin_and_beam_order(obs):
    _, lidar = obs
    # 16 beams over 2 pi from -pi: beam 8 points straight ahead, beam 12 to the left, beam 4 right
    assert lidar[8] * 50.0 == pytest.approx(WALL_AHEAD, abs=1e-4)
    for k in (9, 10, 11):  # 22.5, 45, 67.5 deg left of ahead
        a = (k - 8) * math.pi / 8
        assert lidar[k] * 50.0 == pytest.approx(WALL_AHEAD / math.cos(a), abs=1e-3)
    assert lidar[12] == 1.0 and lidar[4] == 1.0 and lidar[0] == 1.0  # nothing there: max range
