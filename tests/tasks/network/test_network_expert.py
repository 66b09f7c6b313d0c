"""The network task's scripted route driver (truckrl/tasks/network/expert.py): its speed rule
for a vehicle on the route against hand-computed gaps, the route samples a vehicle covers
against a numpy point-in-polygon oracle, its success on the first curriculum level, and the
demonstrations ``demos.source=driver`` clones, and the labels it gives a policy's own states
(DAgger, ``demos.dagger_rounds``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tests.sim.network.test_traffic import corners
from truckrl.env import LIDAR_KEY, OBS_KEY, TruckEnv
from truckrl.planning import held_out_states
from truckrl.planning.controller import setpoint_action
from truckrl.tasks import EnvConfig
from truckrl.tasks.network.expert import RouteDriver, _covered, demonstrations, drive, labelled
from truckrl.tasks.network.task import empty_traffic

WHEELBASE, FRONT = 4.0, 1.4  # m: the truck's rear axle to its front bumper is 5.4 m


def straight_state(car_x: float | None, car_y: float = 0.0) -> dict:
    """A truck at rest at the origin heading +x on a straight 200 m route along the x axis; a
    4 m car parked with its centre at ``(car_x, car_y)`` facing +x (None: no car)."""
    n = 1
    pts = torch.stack((torch.linspace(0.0, 200.0, 201), torch.zeros(201)), -1).unsqueeze(0)
    params = {
        "wheelbase": torch.tensor([WHEELBASE]),
        "front_overhang": torch.tensor([FRONT]),
        "max_speed": torch.tensor([8.0]),
        "max_steer": torch.tensor([0.6]),
        "tractor_width": torch.tensor([2.5]),
        "trailer_width": torch.tensor([2.5]),
    }
    s = {
        "pose": torch.zeros(n, 4),
        "speed": torch.zeros(n),
        "params": params,
        "route_points": pts,
        "route_cum": pts[..., 0].clone(),
        "route_s": torch.zeros(n),
        "goal_s": torch.tensor([150.0]),
    }
    tr = empty_traffic(n, 1, "cpu")
    if car_x is not None:
        tr["tr_lanes"] = torch.tensor([[[[-50.0, car_y], [250.0, car_y]]]])
        tr["tr_cum"] = torch.tensor([[[0.0, 300.0]]])
        tr["tr_lane_len"] = torch.tensor([[300.0]])
        tr["tr_s"] = torch.tensor([[car_x + 50.0]])
        tr["tr_length"] = torch.tensor([[4.0]])
        tr["tr_width"] = torch.tensor([[1.8]])
        tr["tr_active"] = torch.tensor([[True]])
    return {**s, **tr}


def test_the_driver_stops_before_a_car_on_its_route():
    driver = RouteDriver()
    free, _ = driver.setpoints(straight_state(None))
    assert float(free) == pytest.approx(driver.cruise)  # 6 m/s: below the truck's 8
    # car centre at 20 m: its box grown by 1.25 + 0.6 m reaches back to 20 - 2 - 1.85 = 16.15 m,
    # so the first covered route sample (1 m apart) is at 17 m; the bumper gap kept is 3 m
    speed, steer = driver.setpoints(straight_state(20.0))
    gap = 17.0 - (WHEELBASE + FRONT) - driver.stop_gap
    assert float(speed) == pytest.approx(math.sqrt(2.0 * driver.brake * gap), rel=1e-5)
    assert float(steer) == pytest.approx(0.0, abs=1e-6)
    # the same car 4 m to the side (the other lane): 4 - 0.9 > 1.85, the route is free
    aside, _ = driver.setpoints(straight_state(20.0, 4.0))
    assert float(aside) == pytest.approx(driver.cruise)
    # within the stopping gap: stop
    close, _ = driver.setpoints(straight_state(9.0))
    assert float(close) == 0.0


def test_the_driver_stops_for_a_car_that_will_cross_its_route():
    """A car 12 m to the right of the route, driving towards it at 6 m/s on a lane that crosses
    the route at x = 20 m: where it is now covers no route sample, where it will be in 2 s (its
    centre on the route) does, so the driver that reads 2 s ahead plans to stop before it."""
    s = straight_state(None)
    s["tr_lanes"] = torch.tensor([[[[20.0, -50.0], [20.0, 50.0]]]])  # heading +y
    s["tr_cum"] = torch.tensor([[[0.0, 100.0]]])
    s["tr_lane_len"] = torch.tensor([[100.0]])
    s["tr_s"] = torch.tensor([[50.0 - 12.0]])
    s["tr_v"] = torch.tensor([[6.0]])
    s["tr_length"] = torch.tensor([[4.0]])
    s["tr_width"] = torch.tensor([[1.8]])
    s["tr_active"] = torch.tensor([[True]])
    now, _ = RouteDriver(predict=(0.0,)).setpoints(s)
    assert float(now) == pytest.approx(RouteDriver().cruise)  # 12 - 2 - 1.85 m clear of it
    # in 1 s its box (half length 2 + 1.85 grown) spans y = -9.85 ... -2.15: still clear
    assert float(RouteDriver(predict=(0.0, 1.0)).setpoints(s)[0]) == pytest.approx(now)
    # in 2 s its centre is at (20, 0): half width 0.9 + 1.85 covers x = 17.25 ... 22.75, so the
    # first covered sample (1 m apart) is at 18 m
    driver = RouteDriver(predict=(0.0, 1.0, 2.0))
    speed, _ = driver.setpoints(s)
    gap = 18.0 - (WHEELBASE + FRONT) - driver.stop_gap
    assert float(speed) == pytest.approx(math.sqrt(2.0 * driver.brake * gap), rel=1e-5)


def test_covered_route_samples_match_a_point_in_polygon_oracle():
    g = torch.Generator().manual_seed(3)
    n, m, k = 8, 5, 40
    s = straight_state(None)
    xy = torch.rand(n, k, 2, generator=g) * 30.0
    box = torch.cat(
        (
            torch.rand(n, m, 2, generator=g) * 30.0,
            torch.zeros(n, m, 4),
        ),
        -1,
    )
    heading = torch.rand(n, m, generator=g) * 2 * math.pi
    box[..., 2], box[..., 3] = heading.cos(), heading.sin()
    box[..., 4] = 2.0 + 4.0 * torch.rand(n, m, generator=g)  # half lengths
    box[..., 5] = 0.8 + 0.5 * torch.rand(n, m, generator=g)  # half widths
    active = torch.rand(n, m, generator=g) < 0.8
    waiting = torch.rand(n, m, generator=g) < 0.2
    st = {"tr_active": active, "tr_waiting": waiting}
    params = {k: v.expand(n) for k, v in s["params"].items()}
    got = _covered(xy, box, st, params, clearance=0.6).numpy()
    # oracle: corners of the grown box, a point inside all four edges' half-planes
    grow = 1.25 + 0.6
    b = box.double().numpy()
    c = corners(b[..., :2], np.arctan2(b[..., 3], b[..., 2]), 2 * (b[..., 4] + grow),
                2 * (b[..., 5] + grow))  # fmt: skip
    p = xy.double().numpy()[:, None, :, None, :]  # [n, 1, k, 1, 2]
    e0, e1 = c[:, :, None], np.roll(c, -1, axis=2)[:, :, None]  # [n, m, 1, 4, 2]
    cross = (e1[..., 0] - e0[..., 0]) * (p[..., 1] - e0[..., 1]) - (e1[..., 1] - e0[..., 1]) * (
        p[..., 0] - e0[..., 0]
    )
    inside = (cross >= 0).all(-1) | (cross <= 0).all(-1)  # [n, m, k]
    want = inside & (active & ~waiting).numpy()[..., None]
    assert want.any() and (~want).any()
    np.testing.assert_array_equal(got, want)


def test_the_driver_solves_most_scenes_of_the_first_level():
    """Difficulty 0: the goal 40 m of route ahead, no traffic, 30 m tolerance: a straight run or
    one turn, which the driver takes."""
    cfg = EnvConfig(task={"name": "network"}, max_steps=1000, episode_pool=64)
    states = held_out_states(cfg, 64, 12345, "cpu", difficulty=0.0)
    result, samples = drive(cfg, states, 0.0)
    assert result["success"].float().mean() >= 0.85
    assert not (result["success"] & result["collision"]).any()
    # every recorded sample is of a successful episode: as many as their steps
    assert samples.batch_size[0] == int(result["steps"][result["success"]].sum())


def test_demonstrations_are_what_the_policy_sees():
    cfg = EnvConfig(task={"name": "network"}, max_steps=1000, episode_pool=16)
    solved, samples = demonstrations(cfg, 8, 99991, 0.0)
    assert solved.shape == (8,) and solved.any()
    # the shared features, the route extras and the tracks
    assert samples[OBS_KEY].shape[-1] == 26 + 8 + 24
    assert samples[LIDAR_KEY].shape[-1] == cfg.lidar.num_beams
    a = samples["action"]
    assert a.abs().max() <= 1.0 and a.shape[-1] == 2


def test_labelled_states_are_the_policys_own_with_the_drivers_actions():
    """``labelled``: a policy (here one fixed action: creep and steer left) drives; every state
    it visits is kept, of failed episodes too, in step order, with the action the driver would
    take there, not the policy's. Checked against a replay of the same scenes by hand."""
    cfg = EnvConfig(task={"name": "network"}, max_steps=30, episode_pool=16)
    fixed = torch.tensor([0.3, 0.6])
    solved, samples = labelled(cfg, 6, 99991, 1.0, lambda td: fixed.expand(td.shape[0], 2))
    assert solved.shape == (6,) and not solved.any()  # 30 steps reach no goal
    states = held_out_states(cfg, 6, 99991, "cpu", difficulty=1.0)
    env = TruckEnv(num_envs=6, config=cfg, seed=0)
    env.set_difficulty(1.0)
    td = env.set_state(states.clone())
    alive = torch.ones(6, dtype=torch.bool)
    obs, lidar, want = [], [], []
    for _ in range(cfg.max_steps):
        s = env.get_state()
        label = setpoint_action(*RouteDriver().setpoints(s), s, cfg.control, cfg.dt)
        obs.append(td[OBS_KEY][alive])
        lidar.append(td[LIDAR_KEY][alive])
        want.append(label[alive])
        td = env.step(td.set("action", fixed.expand(6, 2).clone()))["next"]
        alive &= ~td["done"].squeeze(-1)
    env.close()
    assert samples.batch_size[0] == sum(len(o) for o in obs)
    assert torch.equal(samples[OBS_KEY], torch.cat(obs))
    assert torch.equal(samples[LIDAR_KEY], torch.cat(lidar))
    assert torch.equal(samples["action"], torch.cat(want))
    assert not torch.isclose(samples["action"], fixed).all(-1).any()  # never the policy's
