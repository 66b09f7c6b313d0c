"""The network task's sub-goal view (truckrl/tasks/network/cells/): the sub-goals of a
hand-built chain, the intersection task's observation, the switching rule at its boundary,
success at the final goal only, the sub-goals of drawn chains against their lane centre-lines
(numpy), one-line config errors, and what the chain tool reports of a path."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.env import TruckEnv
from truckrl.sim.vehicle import truck_extents
from truckrl.tasks import EnvConfig, make_task
from truckrl.tasks.network.cells.task import CELLS_TASK
from truckrl.tasks.network.tools import collision_sites, pooled_tables, route_pose, subgoals_passed

HALF_PI = math.pi / 2
#: The hand-built chain: an L-shaped route (0, 0) -> (100, 0) -> (100, 100), arc length 200 m;
#: junction exits at 50 m (the point (50, 0)) and 130 m ((100, 30)), the goal at 190 m.
EXITS = (50.0, 130.0)
GOAL = (100.0, 90.0, HALF_PI)


def config(**subgoal) -> EnvConfig:
    return EnvConfig(
        lidar={"num_beams": 16},
        max_steps=50,
        task={"name": CELLS_TASK, "subgoal": subgoal},
    )


def route_xy(s: float) -> tuple[float, float, float]:
    """The pose at arc length ``s`` of the L-shaped route, by hand."""
    return (s, 0.0, 0.0) if s <= 100.0 else (100.0, s - 100.0, HALF_PI)


def hand_state(task, poses, speed=0.0):
    """One row per truck pose ``(x, y, heading, articulation)`` on the hand-built chain: the
    same truck, curbs 30 m off the route, the start options ``back`` past each exit."""
    n = len(poses)
    gen = torch.Generator().manual_seed(3)
    one = task.sample_params(1, gen, torch.device("cpu"))
    params = {k: v.expand(n).clone() for k, v in one.items()}
    _, rear, _ = truck_extents(one)
    back = float(rear[0]) + task.cfg.task.scene.start_margin
    segments = torch.tensor(
        [[-50.0, -30.0, 150.0, -30.0], [130.0, -30.0, 130.0, 150.0], [-50.0, 12.0, 70.0, 12.0]]
    )
    scene = {
        "start": torch.tensor([p[:3] for p in poses]),
        "goal": torch.tensor([GOAL] * n),
        "segments": segments.expand(n, 3, 4).clone(),
        "mask": torch.ones(n, 3, dtype=torch.bool),
        "kind": torch.zeros(n, 3, dtype=torch.int8),
    }
    state = task.initial_state(params, scene, torch.device("cpu"))
    state["pose"] = torch.tensor(poses)
    state["speed"] = torch.full((n,), speed)
    state["route_points"] = (
        torch.tensor([[[0.0, 0.0], [100.0, 0.0], [100.0, 100.0]]]).expand(n, 3, 2).clone()
    )
    state["route_cum"] = torch.tensor([[0.0, 100.0, 200.0]]).expand(n, 3).clone()
    options = [(0.0 + back, 0.0, 0.0)] + [route_xy(e + back) for e in EXITS]
    state["start_options"] = torch.tensor([options] * n)
    state.update(task.errors(state))
    return task.complete_state(state)


def test_subgoals_of_a_hand_built_chain():
    """20 m past the exits at 50 and 130 m: (70, 0) heading 0 and (100, 50) heading 90 deg,
    then the goal; with 70 m past, (100, 20) and then the goal twice (clamped at 190 m)."""
    task = make_task(config())
    st = hand_state(task, [(10.0, 0.0, 0.0, 0.0)])
    want = torch.tensor([[70.0, 0.0, 0.0], [100.0, 50.0, HALF_PI], list(GOAL)])
    torch.testing.assert_close(st["subgoals"][0], want, atol=1e-3, rtol=0)
    torch.testing.assert_close(st["subgoal_s"][0], torch.tensor([70.0, 150.0, 190.0]))
    assert st["subgoal_index"].tolist() == [0]
    far = make_task(config(past_exit=70.0))
    st = hand_state(far, [(10.0, 0.0, 0.0, 0.0)])
    want = torch.tensor([[100.0, 20.0, HALF_PI], list(GOAL), list(GOAL)])
    torch.testing.assert_close(st["subgoals"][0], want, atol=1e-3, rtol=0)
    torch.testing.assert_close(st["subgoal_s"][0], torch.tensor([120.0, 190.0, 190.0]))


def test_subgoal_switches_exactly_at_the_switch_distance_and_never_back():
    """switch = 5 m: the first sub-goal (70 m) hands over at 65 m, the second (150 m) at 145 m
    (the point (100, 45)); the goal (190 m) stays the last. Through the env's step (trucks at
    rest, every one coming with the first sub-goal current); the observed goal is the new
    sub-goal in the tractor frame, by hand."""
    poses = [
        (64.99, 0.0, 0.0, 0.0),
        (65.01, 0.0, 0.0, 0.0),
        (100.0, 44.99, HALF_PI, 0.0),
        (100.0, 45.01, HALF_PI, 0.0),
        (100.0, 99.0, HALF_PI, 0.0),
    ]
    env = TruckEnv(num_envs=len(poses), config=config(), seed=0)
    st = hand_state(env.task, poses)
    st["subgoal_index"] = torch.zeros(len(poses), dtype=torch.long)  # all arrive from the start
    td = env.set_state(st)
    td = env.step(td.set("action", torch.zeros(len(poses), 2)))["next"]
    st = env.get_state()
    assert st["subgoal_index"].tolist() == [0, 1, 1, 2, 2]
    # truck 1 at (65.01, 0) heading 0 sees (100, 50): 34.99 m ahead, 50 m left, over 50 m
    obs = td["observation"]
    torch.testing.assert_close(obs[1, :2], torch.tensor([34.99 / 50, 1.0]), atol=1e-4, rtol=0)
    # truck 0 still sees (70, 0): 5.01 m ahead; goal heading terms: sin 0, cos 0
    torch.testing.assert_close(
        obs[0, :4], torch.tensor([5.01 / 50, 0.0, 0.0, 1.0]), atol=1e-4, rtol=0
    )
    # back to the start: the sub-goal stays
    st["pose"][1] = torch.tensor([10.0, 0.0, 0.0, 0.0])
    td = env.set_state(st)
    env.step(td.set("action", torch.zeros(len(poses), 2)))
    assert env.get_state()["subgoal_index"].tolist() == [0, 1, 1, 2, 2]


def test_observation_is_the_intersection_tasks_against_the_subgoal():
    """A moving, articulated truck with its sub-goal at (70, 0): the cells task observes what
    the intersection task observes (its own state and code path) for that goal."""
    cells = make_task(config())
    pose = (30.0, 3.0, 0.2, -0.15)
    st = hand_state(cells, [pose], speed=4.0)
    st["steer"] = torch.tensor([0.1])
    inter = make_task(EnvConfig(lidar={"num_beams": 16}, max_steps=50))
    scene = {
        "start": torch.tensor([pose[:3]]),
        "goal": torch.tensor([[70.0, 0.0, 0.0]]),
        **{k: st[k] for k in ("segments", "mask", "kind")},
    }
    ist = inter.initial_state(dict(st["params"].items()), scene, torch.device("cpu"))
    ist["pose"], ist["speed"], ist["steer"] = st["pose"], st["speed"], st["steer"]
    ist = inter.complete_state(ist)
    d = torch.tensor([4.0])
    a = cells.observe(dict(st.items()) | {"params": dict(st["params"].items())}, d)
    b = inter.observe(dict(ist.items()) | {"params": dict(ist["params"].items())}, d)
    assert a["observation"].shape == b["observation"].shape == (1, 26)
    assert cells.num_features == inter.num_features == 26  # the env's observation spec
    torch.testing.assert_close(a["observation"], b["observation"])
    torch.testing.assert_close(a["lidar"], b["lidar"])
    assert float(b["lidar"].min()) < 0.5  # the curbs are in view: the LiDAR is compared


def test_success_only_at_the_final_goal():
    """A truck at rest exactly on a sub-goal's pose has not succeeded; one on the goal has."""
    poses = [(70.0, 0.0, 0.0, 0.0), (100.0, 50.0, HALF_PI, 0.0), (*GOAL, 0.0)]
    env = TruckEnv(num_envs=3, config=config(), seed=0)
    env.set_difficulty(4.0)
    td = env.set_state(hand_state(env.task, poses))
    out = env.step(td.set("action", torch.zeros(3, 2)))["next"]
    assert out["success"].squeeze(-1).tolist() == [False, False, True]
    assert not out["collision"].any()


def test_drawn_chains_subgoals_lie_past_the_exits_on_the_lanes():
    """Drawn episodes: each junction's sub-goal lies on the lane of the link behind it, 20 m
    (along the lane, numpy) from the lane's start (the junction's exit) and facing along it, or
    at the final goal; the sub-goals of junctions behind the start count as passed."""
    env = TruckEnv(num_envs=12, config=config(), seed=5)
    env.set_difficulty(1.5)  # level 3: one junction, the whole route, the start on L_1
    env.reset()
    st = env.get_state()
    assert st["subgoal_index"].tolist() == [1] * 12
    env.set_difficulty(4.0)
    env.set_seed(5)
    env.reset()
    st = env.get_state()
    assert st["subgoal_index"].tolist() == [0] * 12
    lanes = st["tr_lanes"].numpy()
    L = lanes.shape[1] // st["block_type"].shape[1]
    checked = 0
    for i in range(12):
        for j in (1, 2):
            sub = st["subgoals"][i, j - 1].numpy()
            if st["subgoal_s"][i, j - 1] >= st["goal_s"][i] - 1e-3:
                assert np.allclose(sub, st["goal"][i].numpy(), atol=1e-4)
                continue
            lane = lanes[i, 2 * j * L]
            piece = np.diff(lane, axis=0)
            length = np.linalg.norm(piece, axis=1)
            if length.sum() < 25.0:
                continue  # the sub-goal lies beyond this link
            t = np.clip(((sub[:2] - lane[:-1]) * piece).sum(1) / np.maximum(length**2, 1e-12), 0, 1)
            near = lane[:-1] + t[:, None] * piece
            k = np.argmin(np.linalg.norm(near - sub[:2], axis=1))
            assert np.linalg.norm(near[k] - sub[:2]) < 0.3
            along = length[:k].sum() + t[k] * length[k]
            assert along == pytest.approx(20.0, abs=0.3)
            heading = math.atan2(piece[k, 1], piece[k, 0])
            # the sub-goal faces along its resampled route piece, whose chord turns from the
            # lane's tangent by at most half its length over the tightest lane radius (curve
            # radius min less a quarter of the widest road), plus the lane polyline's own piece
            spacing = float(st["route_cum"][i, -1]) / (st["route_cum"].shape[1] - 1)
            net = env.task.cfg.task.network
            radius = net.curve_radius[0] - 0.25 * net.road_width[1]
            tol = spacing / (2.0 * radius) + 0.01
            assert abs(math.remainder(sub[2] - heading, 2 * math.pi)) < tol
            checked += 1
    assert checked >= 12


def test_subgoals_passed_reports_the_furthest_projection():
    """A path that reaches 66 m along the route and drives back has passed one sub-goal."""
    task = make_task(config())
    st = hand_state(task, [(10.0, 0.0, 0.0, 0.0), (10.0, 0.0, 0.0, 0.0)])
    x = torch.tensor([[10.0, 40.0, 66.0, 30.0], [10.0, 40.0, 64.0, 30.0]])
    path = torch.stack((x, torch.zeros_like(x), torch.zeros_like(x), torch.zeros_like(x)), -1)
    passed, furthest = subgoals_passed(st, path, 5.0)
    assert passed.tolist() == [1, 0]
    torch.testing.assert_close(furthest, torch.tensor([66.0, 64.0]))


@pytest.mark.parametrize(
    ("subgoal", "needle"),
    [
        ({"switch": -1.0}, "env.task.subgoal.switch = -1.0 is outside the allowed range"),
        ({"past_exit": 2000.0}, "env.task.subgoal.past_exit = 2000.0 is outside the allowed range"),
    ],
)
def test_bad_subgoal_config_is_a_one_line_error(subgoal, needle):
    with pytest.raises(ConfigError) as e:
        config(**subgoal)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_horizon_shows_the_route_pose_ahead_until_the_subgoal_is_near():
    """horizon = 30 m on the hand-built chain: at 10 m the sub-goal (70 m) is shown as the
    route pose at 40 m, (40, 0) heading 0; at 50 m as itself, (70, 0); at 90 m (the next
    sub-goal, 150 m, current) as the pose at 120 m, (100, 20) heading 90 deg."""
    task = make_task(config(horizon=30.0))
    st = hand_state(task, [(10.0, 0.0, 0.0, 0.0), (50.0, 0.0, 0.0, 0.0), (90.0, 0.0, 0.0, 0.0)])
    assert st["subgoal_index"].tolist() == [0, 0, 1]
    obs = task.observe(dict(st.items()) | {"params": dict(st["params"].items())}, torch.zeros(3))
    want = torch.tensor(
        [[30.0 / 50, 0.0, 0.0, 1.0], [20.0 / 50, 0.0, 0.0, 1.0], [10.0 / 50, 20.0 / 50, 1.0, 0.0]]
    )
    torch.testing.assert_close(obs["observation"][:, :4], want, atol=1e-5, rtol=0)


def test_collision_sites_name_the_curb_block_and_body():
    """The curb y = 12 (slot 2, block 1 here): a truck straddling it touches it with both
    bodies; at y = 9 with the trailer swung 0.3 rad to the left (its rear ~12 m behind the
    axle reaches y ~ 12.5) with the trailer; at y = 10 nosing 0.25 rad to the left (the bumper
    ~5 m ahead reaches y ~ 11.2 + 1.2) with the tractor; one on the route touches none."""
    task = make_task(config())
    poses = [(30.0, 11.5, 0.0, 0.0), (30.0, 9.0, 0.0, -0.3), (30.0, 10.0, 0.25, 0.0)]
    st = hand_state(task, [*poses, (30.0, 0.0, 0.0, 0.0)])
    st["segment_block"] = torch.tensor([[0, 2, 1]] * 4)
    what, body, block = collision_sites(st, st["pose"])
    assert what.tolist() == [1, 1, 1, 0]
    assert body[:3].tolist() == [2, 1, 0]
    assert block.tolist() == [1, 1, 1, -1]


def test_pooled_record_keeps_runs_apart_and_summarises_the_headline_runs():
    """Two runs of 4 episodes: one bin each; the summary is the headline run's alone (3 of 4
    successes, not 3 of 8); pooled bins count the headline run's episodes only."""
    from truckrl.sim.network.config import BLOCK_NAMES
    from truckrl.tasks.goals import POSE_ERRORS

    def results(success):
        n = len(success)
        out = {"success": torch.tensor(success)}
        for k in ("collision", "jackknife"):
            out[k] = torch.zeros(n, dtype=torch.bool)
        out["truncated"] = ~out["success"]
        out |= {f"has_{b}": torch.ones(n) for b in BLOCK_NAMES}
        out |= {k: torch.zeros(n) for k in ("turns_straight", "turns_left", "turns_right")}
        out |= {q.key: torch.ones(n) for q in POSE_ERRORS}
        out |= {"junctions": torch.ones(n), "traffic_density": torch.zeros(n)}
        return out | {"length": torch.ones(n), "route_length": torch.full((n,), 120.0)}

    runs = [
        ("a", True, results([True, True, True, False])),
        ("b", False, results([False] * 4)),
    ]
    summary, rows = pooled_tables(runs, POSE_ERRORS)
    assert summary["episodes"] == 4 and summary["success_rate"] == pytest.approx(0.75)
    by = {(r["dimension"], r["bin"]): r for r in rows}
    assert by[("run", "a")]["count"] == 4 and by[("run", "b")]["success_rate"] == 0.0
    assert by[("block types on the route, pooled", "straight")]["count"] == 4
    assert by[("route length [m], pooled", "0-150")]["success_rate"] == pytest.approx(0.75)


def test_route_pose_by_hand():
    """On the L-shaped route from a start 10 m along it: (40, 2) heading 0.1 rad is 30 m on,
    2 m left, 5.73 deg off; (103, 60) heading 90 deg is 150 m on, 3 m right, 0 deg off."""
    task = make_task(config())
    st = hand_state(task, [(10.0, 0.0, 0.0, 0.0)] * 2)
    pose = torch.tensor([[40.0, 2.0, 0.1, 0.0], [103.0, 60.0, HALF_PI, 0.0]])
    along, left, error = route_pose(st, pose)
    torch.testing.assert_close(along, torch.tensor([30.0, 150.0]))
    torch.testing.assert_close(left, torch.tensor([2.0, -3.0]))
    torch.testing.assert_close(error, torch.tensor([math.degrees(0.1), 0.0]))
