"""``env.task.reward.shaping=route``: the lane route, distance to go and heading, hand-computed."""

from __future__ import annotations

import math

import pytest
import torch

from truckrl.env import TruckEnv
from truckrl.tasks import EnvConfig
from truckrl.tasks.intersection.task import route_errors, route_path, route_reference

HALF_PI = math.pi / 2


def poses(*rows):
    return torch.tensor(rows, dtype=torch.float32)


def test_corner_of_a_right_turn_and_straight_fallbacks():
    start = poses((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (5.0, 1.0, HALF_PI))
    goal = poses((20.0, -20.0, -HALF_PI), (50.0, 3.0, 0.0), (-10.0, -20.0, -HALF_PI), (0, 9, 0))
    path = route_path(start, goal)
    # right turn: the start lane y = 0 meets the goal lane x = 20 at (20, 0)
    assert path[0].tolist() == [[0.0, 0.0], [20.0, 0.0], [20.0, -20.0]]
    # parallel lanes (straight road): the midpoint
    assert path[1, 1].tolist() == pytest.approx([25.0, 1.5])
    # the lanes meet behind the start (x = -10): straight line
    assert path[2, 1].tolist() == pytest.approx([-5.0, -10.0])
    # the corner (5, 9) would lie ahead of the start but past the goal along its heading
    assert path[3, 1].tolist() == pytest.approx([2.5, 5.0])


def test_distance_to_go_and_heading_along_the_route():
    path = route_path(poses((0.0, 0.0, 0.0)), poses((20.0, -20.0, -HALF_PI))).expand(4, 3, 2)
    xy = torch.tensor([[10.0, 0.0], [20.0, -10.0], [10.0, -3.0], [25.0, -30.0]])
    to_go, heading = route_reference(xy, path, torch.full((4,), -HALF_PI))
    # on leg 1: 10 m to the corner + 20 m; on leg 2: 10 m; 3 m off leg 1: 3 + 10 + 20;
    # past the goal: the projection stops at the goal, so the straight distance to it
    assert to_go.tolist() == pytest.approx([30.0, 10.0, 33.0, math.hypot(5.0, 10.0)])
    assert heading.tolist() == pytest.approx([0.0, -HALF_PI, 0.0, -HALF_PI])


def test_route_errors_measure_heading_to_the_leg():
    s = {
        "pose": poses((10.0, 0.0, 0.1, -0.2)),
        "goal": poses((20.0, -20.0, -HALF_PI)),
        "route_path": route_path(poses((0.0, 0.0, 0.0)), poses((20.0, -20.0, -HALF_PI))),
    }
    e = route_errors(s)
    assert e["pos_error"].item() == pytest.approx(30.0)
    assert e["tractor_heading_error"].item() == pytest.approx(0.1)
    assert e["trailer_heading_error"].item() == pytest.approx(0.1)  # 0.1 - 0.2 = -0.1


def test_route_shaping_rewards_driving_along_the_lane():
    cfg = EnvConfig(max_steps=50, task={"reward": {"shaping": "route"}})
    env = TruckEnv(num_envs=8, config=cfg, seed=3)
    td = env.reset()
    state = env.get_state()
    path = state["route_path"]
    assert torch.equal(path[:, 0], state["pose"][:, :2])  # the route starts at the truck
    assert torch.equal(path[:, 2], state["goal"][:, :2])
    before = route_errors({k: state[k] for k in ("pose", "goal", "route_path")})
    td = env.step(td.set("action", torch.tensor([[1.0, 0.0]]).expand(8, 2)))["next"]
    after_state = env.get_state()
    after = route_errors({k: after_state[k] for k in ("pose", "goal", "route_path")})
    progress = 0.05 * (before["pos_error"] - after["pos_error"])
    alive = ~td["done"].squeeze(-1)
    assert torch.allclose(td["r_progress"].squeeze(-1)[alive], progress[alive], atol=1e-6)
    # the paper's shaping on the same scenes gives a different progress term in turns
    paper = TruckEnv(num_envs=8, config=EnvConfig(max_steps=50), seed=3)
    td_p = paper.reset()
    td_p = paper.step(td_p.set("action", torch.tensor([[1.0, 0.0]]).expand(8, 2)))["next"]
    turns = state["route", "route"] >= 2
    assert turns.any()
    assert not torch.allclose(td_p["r_progress"][turns], td["r_progress"][turns])


def test_a_hand_built_state_gets_its_route():
    env = TruckEnv(num_envs=2, config=EnvConfig(task={"reward": {"shaping": "route"}}), seed=0)
    env.reset()
    state = env.get_state()
    del state["route_path"]
    env.set_state(state)
    assert torch.equal(env.get_state()["route_path"][:, 2], state["goal"][:, :2])
