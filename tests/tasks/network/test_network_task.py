"""The network task (truckrl/tasks/network/): TorchRL's spec check, start and goal feasibility
against a numpy oracle, route progress by hand, traffic that never overlaps itself or the truck,
touching a vehicle as a collision, the curriculum and the evaluation bins, one-line config
errors. The golden rollout is tests/tasks/network/test_network_golden.py."""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from tests.sim.network.test_traffic import corners, overlapping_pairs, poses
from truckrl.config.fields import ConfigError
from truckrl.env import TruckEnv
from truckrl.tasks import EnvConfig, make_task
from truckrl.tasks.network.bins import network_bins
from truckrl.tasks.network.task import project, route_errors, route_info, route_state

#: Small pools: every env here draws few episodes.
POOL = 16


def network_env(n=4, seed=0, **task) -> TruckEnv:
    config = {"task": {"name": "network", **task}, "episode_pool": POOL, "max_steps": 60}
    return TruckEnv(num_envs=n, config=config, seed=seed)


@pytest.fixture(scope="module")
def sampled():
    """64 episodes of the whole chain, as the task core draws them (no env)."""
    task = make_task(EnvConfig(task={"name": "network"}))
    return task, task.sample(64, torch.Generator().manual_seed(7), torch.device("cpu"))


# ------------------------------------------------------------------------------ numpy oracle
def extents(p: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Front and rear reach from the tractor rear axle and half width of a straight truck [m]
    (the vehicle layout of docs/environment.md: the trailer's axle ``kingpin_offset +
    trailer_wheelbase`` behind the tractor's, its rear overhang behind that)."""
    front = np.maximum(
        p["wheelbase"] + p["front_overhang"], p["trailer_front_overhang"] - p["kingpin_offset"]
    )
    rear = np.maximum(
        p["rear_overhang"],
        p["kingpin_offset"] + p["trailer_wheelbase"] + p["trailer_rear_overhang"],
    )
    return front, rear, 0.5 * np.maximum(p["tractor_width"], p["trailer_width"])


def body_spans(s: dict) -> list[tuple[tuple[float, float, float], ...]]:
    """Each straight truck's tractor and trailer as ``(behind, ahead, half width)`` [m] along
    its heading from the tractor rear axle (docs/environment.md's layout; the bounding box of
    :func:`extents` also covers the corners beside the narrower body)."""
    p = {k[len("params/") :]: v for k, v in s.items() if k.startswith("params/")}
    hitch = -p["kingpin_offset"]
    tractor = zip(
        -p["rear_overhang"],
        p["wheelbase"] + p["front_overhang"],
        p["tractor_width"] / 2,
        strict=True,
    )
    trailer = zip(
        hitch - p["trailer_wheelbase"] - p["trailer_rear_overhang"],
        hitch + p["trailer_front_overhang"],
        p["trailer_width"] / 2,
        strict=True,
    )
    return [(a, b) for a, b in zip(tractor, trailer, strict=True)]


def footprint(pose: np.ndarray, front, rear, half) -> np.ndarray:
    """``[4, 2]`` corners of the straight truck at ``pose (x, y, heading)``."""
    mid = pose[:2] + 0.5 * (front - rear) * np.array([math.cos(pose[2]), math.sin(pose[2])])
    return corners(mid, np.array(pose[2]), np.array(front + rear), np.array(2 * half))


def seg_hits_box(seg: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``[E]`` bool: segments ``[E, 4]`` touch the convex box with corners ``c [4, 2]`` (an
    end inside, or a proper crossing of an edge)."""

    def inside(p):
        e = np.roll(c, -1, 0) - c
        rel = p[:, None, :] - c[None]
        crs = e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0]
        return (crs >= 0).all(-1) | (crs <= 0).all(-1)

    a, b = seg[:, :2], seg[:, 2:]
    hit = inside(a) | inside(b)
    for k in range(4):
        p, q = c[k], c[(k + 1) % 4]

        def orient(u, v, w):
            return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (
                w[..., 0] - u[..., 0]
            )

        d1, d2 = orient(a, b, p[None]), orient(a, b, q[None])
        d3, d4 = orient(p[None], q[None], a), orient(p[None], q[None], b)
        hit |= (d1 * d2 < 0) & (d3 * d4 < 0)
    return hit


def polyline_distance(p: np.ndarray, pts: np.ndarray) -> tuple[float, float]:
    """Distance from ``p`` to the polyline ``pts [Q, 2]`` and the heading of the nearest piece."""
    a, b = pts[:-1], pts[1:]
    ab = b - a
    L2 = np.maximum((ab**2).sum(-1), 1e-12)
    t = np.clip(((p - a) * ab).sum(-1) / L2, 0, 1)
    d = np.linalg.norm(p - (a + t[:, None] * ab), axis=-1)
    d = np.where((ab**2).sum(-1) > 1e-12, d, np.inf)
    k = int(np.argmin(d))
    return float(d[k]), math.atan2(ab[k, 1], ab[k, 0])


def numpy_of(state) -> dict:
    """The state's leaves as numpy (floats as float64), nested keys joined by ``/``."""
    out = {}
    for k, v in state.items(include_nested=True, leaves_only=True):
        name = "/".join(k) if isinstance(k, tuple) else k
        out[name] = v.numpy().astype(np.float64) if v.is_floating_point() else v.numpy()
    return out


def truck_of(s: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`extents` of the trucks of a numpy state."""
    return extents({k[len("params/") :]: v for k, v in s.items() if k.startswith("params/")})


def vehicle_corners(state) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle corners ``[n, M, 4, 2]`` walked along the lanes in numpy, and which are on the
    road."""
    net = SimpleNamespace(lanes=state["tr_lanes"])
    tr = SimpleNamespace(lane=state["tr_lane"], s=state["tr_s"])
    xy, heading = poses(net, tr)
    c = corners(
        xy, heading, state["tr_length"].double().numpy(), state["tr_width"].double().numpy()
    )
    return c, (state["tr_active"] & ~state["tr_waiting"]).numpy()


# ------------------------------------------------------------------------------------ tests
def test_env_specs_observation_and_bins():
    env = network_env()
    check_env_specs(env, seed=0)
    td = env.reset()
    # 4 route points ahead (x, y each), 4 tracks (6 each)
    assert td["observation"].shape == (4, 26 + 8 + 24)
    info = {k: v for k, v in env.get_state()["route"].items()}
    bins = env.task.category_bins(info)
    assert set(bins) == {
        "block types on the route",
        "junctions",
        "traffic [vehicles / 100 m of lane]",
        "turns at junctions",
    }
    env.close()


def route_arc(p: np.ndarray, pts: np.ndarray) -> float:
    """Arc length [m] along the polyline ``pts [R, 2]`` of its point nearest to ``p``."""
    a, b = pts[:-1], pts[1:]
    ab = b - a
    L2 = np.maximum((ab**2).sum(-1), 1e-12)
    t = np.clip(((p - a) * ab).sum(-1) / L2, 0, 1)
    k = int(np.argmin(np.linalg.norm(p - (a + t[:, None] * ab), axis=-1)))
    return float(np.linalg.norm(ab, axis=-1)[:k].sum() + t[k] * math.sqrt(L2[k]))


def test_start_and_goal_are_feasible_by_a_numpy_oracle(sampled):
    """Every start option in use, each curriculum level's start and the goal: on a lane
    centre-line facing along it, no curb touching the straight truck, outside every junction
    disc, and no vehicle spawned on it; a level's start on a lane of the block it names (or of
    the junction after it: a junction's arm reaches out of its disc), its
    distance to the goal along the route within the candidates' reach of the level's distance
    (or the level's link start option), at least min_goal_gap."""
    task, state = sampled
    check_starts_by_oracle(task, state)


@pytest.mark.parametrize("level", [0, 2, 5])
def test_a_pool_refill_places_its_levels_start_by_the_same_oracle(level):
    """A refill for one level (NetworkTask.sample_pool): only that level's start is searched,
    and it passes the oracle above; vehicles only where the level keeps some."""
    task = make_task(EnvConfig(task={"name": "network"}))
    state, _ = task.sample_pool(
        48, torch.Generator().manual_seed(3), torch.device("cpu"), level, None
    )
    check_starts_by_oracle(task, state, levels=[level])
    share = task.cfg.task.curriculum.traffic[level]
    assert bool(state["tr_active"].any()) == (share > 0.0)


def test_a_pool_refill_keeps_the_passing_episodes_and_hands_the_other_trucks_on():
    """The refill's trucks are those carried over first, then new ones from the generator; the
    episodes that fail the rule are left out and their trucks carried to the next refill, so no
    truck is dropped (the trucks' distribution stays that of sample_params)."""
    task = make_task(EnvConfig(task={"name": "network"}))
    dev, g = torch.device("cpu"), torch.Generator().manual_seed(11)
    trucks = task.sample_params(128, torch.Generator().manual_seed(11), dev)
    first, carry = task.sample_pool(128, g, dev, 0, None)
    assert bool(first["route", "feasible"].all()) and carry is not None
    kept = {k: first["params", k] for k in trucks}
    # the kept and the carried trucks are the 64 drawn, in order, each once
    n_kept, n_carry = first.shape[0], carry["wheelbase"].shape[0]
    assert n_kept + n_carry == 128 and n_kept >= 64
    for k, v in trucks.items():
        both = torch.cat((kept[k], carry[k]))
        assert torch.equal(both.sort().values, v.sort().values), k
    second, carry2 = task.sample_pool(128, g, dev, 0, carry)
    # the carried trucks are the first rows of the next refill: kept there or carried again
    later = torch.cat(
        (second["params", "wheelbase"], carry2["wheelbase"] if carry2 else torch.zeros(0))
    )
    assert all(bool((later == t).any()) for t in carry["wheelbase"])
    # a refill asked for fewer trucks than are carried into it draws for every carried one
    assert n_carry > 1
    small, left = task.sample_pool(1, g, dev, 0, carry)
    n_left = 0 if left is None else left["wheelbase"].shape[0]
    assert small.shape[0] + n_left == n_carry and small.shape[0] >= 1


def check_starts_by_oracle(task, state, levels=None) -> None:
    """The oracle of test_start_and_goal_are_feasible_by_a_numpy_oracle, on the curriculum
    levels ``levels`` (every level: ``None``)."""
    assert bool(state["route", "feasible"].all())
    s = numpy_of(state)
    front, rear, half = truck_of(s)
    bodies = body_spans(s)
    veh, on_road = vehicle_corners(state)
    cur, scene = task.cfg.task.curriculum, task.cfg.task.scene
    reach = scene.start_tries * scene.start_step
    n, J = state.shape[0], task.max_junctions
    lanes_per_block = s["tr_lanes"].shape[1] // (2 * J + 1)
    near_target = tried = passed = 0
    for i in range(n):
        lanes = s["tr_lanes"][i][s["tr_lane_len"][i] > 0]
        block_of = np.flatnonzero(s["tr_lane_len"][i] > 0) // lanes_per_block
        curbs = s["segments"][i][s["mask"][i]]
        zc, zr = (
            s["tr_zone_centre"][i][s["tr_zone_mask"][i]],
            s["tr_zone_radius"][i][s["tr_zone_mask"][i]],
        )
        goal_s = route_arc(s["goal"][i][:2], s["route_points"][i])
        for v, (j, distance) in enumerate(zip(cur.junctions, cur.distance, strict=True)):
            if levels is not None and v not in levels:
                continue
            start, option = s["level_starts"][i, v], s["start_options"][i, J - j]
            gap = goal_s - route_arc(start[:2], s["route_points"][i])
            on = [polyline_distance(start[:2], lane)[0] < 1e-3 for lane in lanes]
            # on its link, or on the arm of the junction after it (outside the junction's disc)
            assert set(block_of[on]) & {s["level_blocks"][i, v], s["level_blocks"][i, v] + 1}
            assert s["level_blocks"][i, v] >= 2 * (J - j) and s["level_blocks"][i, v] % 2 == 0
            # past the junction after its link: on that junction's lane, farther along the
            # route than the junction's centre (the point of the route nearest to it)
            jb = s["level_blocks"][i, v] + 1
            arc = route_arc(start[:2], s["route_points"][i])
            past = jb < 2 * J + 1 and jb in set(block_of[on])
            past = past and arc > route_arc(s["tr_zone_centre"][i, jb], s["route_points"][i])
            assert bool(s["level_past"][i, v]) == past, (i, v)
            passed += past
            assert gap >= scene.min_goal_gap - 0.5, (i, v, gap)
            if distance == 0.0 or np.allclose(start, option, atol=1e-4):  # the option
                assert np.allclose(start, option, atol=1e-4), (i, v)
                continue
            option_gap = goal_s - route_arc(option[:2], s["route_points"][i])
            expected = min(distance, option_gap)
            assert abs(gap - expected) <= reach + 1.0, (i, v, gap, expected)
            near_target += abs(gap - expected) <= 1.0
            tried += 1
        poses = (s["start_options"][i, 0], s["start_options"][i, 1], s["goal"][i])
        checked = range(len(cur.junctions)) if levels is None else levels
        for pose in (*poses, *s["level_starts"][i][list(checked)]):
            best = min(polyline_distance(pose[:2], lane) for lane in lanes)
            assert best[0] < 1e-3, (i, pose, best)
            assert abs(math.remainder(best[1] - pose[2], 2 * math.pi)) < 1e-3, (i, pose, best)
            box = footprint(pose, front[i], rear[i], half[i])
            assert not seg_hits_box(curbs, box).any(), (i, pose)
            # each body's box to each disc: the disc's centre clamped into the box
            for (lo, hi, w), (c, r) in itertools.product(bodies[i], zip(zc, zr, strict=True)):
                u = np.array([math.cos(pose[2]), math.sin(pose[2])])
                rel = c - pose[:2]
                along = np.clip(rel @ u, lo, hi)
                across = np.clip(rel @ np.array([-u[1], u[0]]), -w, w)
                nearest = pose[:2] + along * u + across * np.array([-u[1], u[0]])
                assert np.linalg.norm(c - nearest) >= r, (i, pose, c, r)
            both = np.concatenate((box[None], veh[i][on_road[i]]))[None]
            hit = overlapping_pairs(both, np.ones(both.shape[:2], dtype=bool))
            assert not hit[0, 0].any(), (i, pose)
    if levels is None:
        assert tried > n and near_target > 0.5 * tried  # most levels' starts at their distance
        assert 0 < passed < tried  # starts past a junction and starts before one, both checked
    elif cur.distance[levels[0]] > 0.0:
        assert tried > 0.5 * n and near_target > 0.5 * tried


def test_the_reset_pool_refills_by_the_tasks_own_size_unless_one_is_set():
    from truckrl.tasks.base import Task
    from truckrl.tasks.network.task import NetworkTask

    assert NetworkTask.episode_pool > Task.episode_pool
    assert EnvConfig(task={"name": "network"}).episode_pool == NetworkTask.episode_pool
    assert EnvConfig(task={"name": "intersection"}).episode_pool == Task.episode_pool
    assert EnvConfig(task={"name": "network"}, episode_pool=8).episode_pool == 8
    env = TruckEnv(num_envs=2, config={"task": {"name": "network"}, "max_steps": 60}, seed=0)
    draw, asked = env._pool._draw, []
    env._pool._draw = lambda k, key: asked.append(k) or draw(k, key)
    env.reset()
    assert asked == [NetworkTask.episode_pool]


def test_a_level_change_drops_the_episodes_drawn_for_the_old_level():
    """Refills are drawn for one curriculum level (level 0: no vehicle placed): after
    set_difficulty moves to level 5 (every vehicle), the restarted trucks start at that level,
    with traffic, and not on the held episodes drawn for level 0."""
    config = {"task": {"name": "network"}, "max_steps": 1, "episode_pool": 16}
    env = TruckEnv(num_envs=8, config=config, seed=6)
    env.set_difficulty(0.0)
    td = env.reset()
    assert not env.get_state()["tr_active"].any()
    env.set_difficulty(3.0)
    env.step_and_maybe_reset(td.set("action", torch.zeros(8, 2)))  # every truck restarts
    st = env.get_state()
    assert (st["step_count"] == 0).all() and (st["route", "level"] == 5).all()
    assert st["tr_active"].any(-1).float().mean() > 0.5
    env.close()


def test_a_reset_state_holds_storage_of_its_own_not_the_pools():
    """The compiled step guards on its inputs' storage offsets: a state made of slices of the
    episode pool would compile again whenever a full reset took rows at another offset."""
    env = network_env(n=4)
    env.reset()
    held = {v.untyped_storage().data_ptr() for v in env._pool._episodes.values()}
    state = env._state.items(include_nested=True, leaves_only=True)
    shared = [k for k, v in state if v.untyped_storage().data_ptr() in held]
    assert not shared, f"state leaves on the pool's storage: {shared}"


def test_leaving_idle_traffic_out_of_the_step_changes_nothing():
    """Below the first curriculum level with vehicles the env steps without the traffic's keys
    (NetworkTask.idle_keys): the outputs and the state are bit for bit those of an env that
    steps the traffic all along, also after the difficulty rises to a level with vehicles,
    from which on the traffic is stepped again."""
    from truckrl.tasks.network.task import TRAFFIC_KEYS

    def rollout(busy: bool):
        config = {"task": {"name": "network"}, "episode_pool": 64, "max_steps": 8}
        env = TruckEnv(num_envs=16, config=config, seed=0)  # every truck restarts after the rise
        if busy:
            env.task.idle_keys = lambda difficulty: ()
        env.set_difficulty(0.0)
        td = env.reset()
        gen, outs, idle = torch.Generator().manual_seed(1), [], []
        for t in range(30):
            if t == 10:
                env.set_difficulty(3.0)
            action = torch.rand(16, 2, generator=gen) * 2.0 - 1.0
            step, td = env.step_and_maybe_reset(td.set("action", action))
            outs.append(step["next"].clone())
            idle.append(set(env._idle))
        return outs, idle, env.get_state()

    idle_outs, idle, idle_state = rollout(busy=False)
    busy_outs, _, busy_state = rollout(busy=True)
    for a, b in zip(idle_outs, busy_outs, strict=True):
        assert (a == b).all()
    assert (idle_state == busy_state).all()
    assert busy_state["tr_active"].any()  # vehicles took part after the rise
    assert idle[0] == set(TRAFFIC_KEYS) and not idle[-1]


def test_tracks_are_the_nearest_vehicles_in_the_tractor_frame_by_a_numpy_oracle():
    """The observation's tracks against the vehicles walked along their lanes in numpy, turned
    into the tractor's frame and sorted by distance by hand."""
    env = network_env(n=16, seed=3, tracks=3)
    env.set_difficulty(3.0)  # every spawned vehicle drives
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        action = torch.rand(16, 2, generator=gen) * 2.0 - 1.0
        _, td = env.step_and_maybe_reset(td.set("action", action))
    state = env.get_state()
    obs = td["observation"][:, 26 + 8 :].double().numpy().reshape(16, 3, 6)
    net = SimpleNamespace(lanes=state["tr_lanes"])
    xy, heading = poses(net, SimpleNamespace(lane=state["tr_lane"], s=state["tr_s"]))
    pose = state["pose"].double().numpy()
    on = (state["tr_active"] & ~state["tr_waiting"]).numpy()
    speed = state["tr_v"].double().numpy()
    reach = env.config.lidar.max_range
    seen_any = 0
    for i in range(16):
        c, s_ = math.cos(pose[i, 2]), math.sin(pose[i, 2])
        rows = []
        for j in np.flatnonzero(on[i]):
            dx, dy = xy[i, j] - pose[i, :2]
            x, y = c * dx + s_ * dy, -s_ * dx + c * dy
            if math.hypot(x, y) < reach:
                rel = heading[i, j] - pose[i, 2]
                rows.append((math.hypot(x, y), [1, x / 50, y / 50, math.cos(rel), math.sin(rel),
                                                speed[i, j] / 10]))  # fmt: skip
        rows.sort(key=lambda r: r[0])
        want = np.zeros((3, 6))
        for r, (_, f) in enumerate(rows[:3]):
            want[r] = f
        seen_any += len(rows) > 0
        np.testing.assert_allclose(obs[i], want, atol=2e-4)
    assert seen_any >= 4  # vehicles were in reach in several scenes
    env.close()


def test_route_progress_by_hand():
    """An L-shaped route (0, 0) -> (10, 0) -> (10, 10), goal at its end: at (4, 1) the truck is
    4 m along it and 1 m off, 16 + 1 m to go; at (11, 6), 16 m along, 1 m off, 4 + 1 to go; the
    step between earns 0.05 x 12 m of progress and, turning from 0 to 90 deg with the route,
    0.5 x (0 - pi/2) for the tractor (heading to the route's heading 0 -> ... -> 0)."""
    points = torch.tensor([[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]])
    cum = torch.tensor([[0.0, 10.0, 20.0]])
    window = torch.zeros(1, 1, 1, dtype=torch.long)
    base = {
        "route_points": points,
        "route_cum": cum,
        "goal_s": torch.tensor([20.0]),
        "window": window,
    }
    a = {**base, "pose": torch.tensor([[4.0, 1.0, 0.0, 0.0]])}
    b = {**base, "pose": torch.tensor([[11.0, 6.0, math.pi / 2, 0.0]])}
    ra, rb = route_state(a), route_state(b)
    assert ra["route_s"].item() == pytest.approx(4.0) and ra["route_to_go"].item() == pytest.approx(
        17.0
    )
    assert rb["route_s"].item() == pytest.approx(16.0) and rb[
        "route_to_go"
    ].item() == pytest.approx(5.0)
    assert rb["route_heading"].item() == pytest.approx(math.pi / 2)
    s, off, _, piece = project(points, cum, torch.tensor([[10.5, 9.0, 0.0]]))
    assert (s.item(), off.item(), piece.item()) == (pytest.approx(19.0), pytest.approx(0.5), 1)
    task = make_task(EnvConfig(task={"name": "network"}))
    flags = {k: torch.tensor([False]) for k in ("success", "collision", "jackknife", "truncated")}
    terms = task.reward_terms({**a, **ra}, {**b, **rb}, flags)
    assert terms["r_progress"].item() == pytest.approx(0.05 * 12.0)
    assert terms["r_tractor_heading"].item() == pytest.approx(0.0, abs=1e-6)
    assert route_errors({**b, **rb})["tractor_heading_error"].item() == pytest.approx(0.0, abs=1e-6)


def test_traffic_never_overlaps_itself_or_a_standing_truck():
    """Dense traffic; in each scene the truck is moved onto the lane of a vehicle, its rear end
    6 m ahead of it, and brakes there: over 80 steps no two vehicles overlap and none overlaps
    the truck (numpy separating-axis test on the boxes' corners); the vehicles behind it stop."""
    n = 8
    env = network_env(
        n=n,
        seed=3,
        traffic={"density": [4.0, 6.0]},
        curriculum={"difficulty": [0.0], "junctions": [2], "traffic": [1.0], "distance": [0.0]},
    )
    env.reset()
    st = env.get_state()
    s = numpy_of(st)
    front, rear, half = truck_of(s)
    on = (st["tr_active"] & ~st["tr_waiting"]).numpy()
    k = on.argmax(1)  # the first vehicle on the road in each scene
    rows = torch.arange(n)
    ahead = st["tr_s"][rows, k] + 0.5 * st["tr_length"][rows, k] + torch.tensor(rear) + 6.0
    lane = SimpleNamespace(lane=st["tr_lane"][rows, k][:, None], s=ahead.float()[:, None])
    xy, heading = poses(SimpleNamespace(lanes=st["tr_lanes"]), lane)
    st["pose"] = torch.tensor(np.concatenate((xy[:, 0], heading, 0 * heading), -1)).float()
    env.set_state(st)
    c, on = vehicle_corners(env.get_state())
    clear = []  # scenes where the truck landed on no vehicle
    for i in range(n):
        box = footprint(env.get_state()["pose"][i, :3].double().numpy(), front[i], rear[i], half[i])
        both = np.concatenate((box[None], c[i][on[i]]))[None]
        clear.append(not overlapping_pairs(both, np.ones(both.shape[:2], dtype=bool))[0, 0].any())
    assert sum(clear) >= 4
    brake = TensorDict({"action": torch.tensor([[-1.0, 0.0]] * n)}, batch_size=[n])
    moved = 0.0
    for _ in range(80):
        before = env.get_state()["tr_s"].clone()
        env.step(brake)
        st = env.get_state()
        moved += float((st["tr_s"] - before).abs().sum())
        c, on = vehicle_corners(st)
        assert not overlapping_pairs(c, on).any()
        s = numpy_of(st)
        for i in np.flatnonzero(clear):
            box = footprint(s["pose"][i, :3], front[i], rear[i], half[i])
            both = np.concatenate((box[None], c[i][on[i]]))[None]
            assert not overlapping_pairs(both, np.ones(both.shape[:2], dtype=bool))[0, 0].any()
    assert moved > 100.0  # the traffic did drive
    env.close()


def test_touching_a_vehicle_ends_the_episode_as_a_collision():
    """A car parked (desired speed ~0) on the truck's lane 3 m ahead of its front bumper: full
    throttle drives into it, and the episode ends as a collision (terminated) after the truck
    has covered the gap; the same drive without the car has no collision."""

    def drive(with_car: bool):
        env = network_env(n=1, seed=5, traffic={"max_vehicles": 2})
        env.reset()
        st = env.get_state()
        s = numpy_of(st)
        front, _, _ = truck_of(s)
        # the truck's lane: the lane its rear axle lies on, facing its way (numpy)
        lanes = s["tr_lanes"][0]
        best = min(
            (
                polyline_distance(s["pose"][0, :2], lane) + (k,)
                for k, lane in enumerate(lanes)
                if s["tr_lane_len"][0, k] > 0
                and abs(
                    math.remainder(
                        polyline_distance(s["pose"][0, :2], lane)[1] - s["pose"][0, 2], 2 * math.pi
                    )
                )
                < 1e-3
            ),
        )
        k = best[2]
        along = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(lanes[k], axis=0), axis=-1)])
        seg = int(np.searchsorted(along, 0.0, side="right"))
        # arc length of the rear axle on lane k: project onto its pieces
        a, b = lanes[k][:-1], lanes[k][1:]
        ab = b - a
        tt = np.clip(
            ((s["pose"][0, :2] - a) * ab).sum(-1) / np.maximum((ab**2).sum(-1), 1e-12), 0, 1
        )
        d = np.linalg.norm(s["pose"][0, :2] - (a + tt[:, None] * ab), axis=-1)
        j = int(np.argmin(d))
        s_axle = along[j] + tt[j] * np.linalg.norm(ab[j])
        del seg
        length = 4.5
        st["tr_active"][0] = torch.tensor([with_car, False])
        st["tr_waiting"][0] = False
        st["tr_lane"][0, 0] = k
        st["tr_home"][0, 0] = k
        st["tr_s"][0, 0] = float(s_axle + front[0] + 3.0 + length / 2)
        st["tr_v"][0, 0] = 0.0
        st["tr_v0"][0, 0] = 1e-3
        st["tr_length"][0, 0] = length
        st["tr_width"][0, 0] = 1.8
        env.set_state(st)
        go = TensorDict({"action": torch.tensor([[1.0, 0.0]])}, batch_size=[1])
        steps = 0
        while steps < 40:
            out = env.step(go)["next"]
            steps += 1
            if out["done"].item():
                break
        result = (bool(out["collision"].item()), bool(out["terminated"].item()), steps)
        env.close()
        return result

    hit, ended, step = drive(True)
    assert hit and ended and step >= 3  # 3 m to cover first
    hit, ended, _ = drive(False)
    assert not hit


def test_curriculum_keeps_the_draws_feasibility_verdict(sampled):
    """on_reset recomputes the route metadata for the level's start but keeps ``feasible``, the
    draw's verdict on the chain: an episode marked infeasible stays marked at every level."""
    task, state = sampled
    state = state[:4].clone()
    state["route", "feasible"] = torch.tensor([0.0, 1.0, 0.0, 1.0])
    for d in (0.0, 3.0):
        out = task.on_reset(state.clone(), torch.full((4,), d))
        assert out["route", "feasible"].tolist() == [0.0, 1.0, 0.0, 1.0]


def test_curriculum_starts_near_the_goal_then_routes_through_more_junctions():
    """At difficulty 0 (level 0: 40 m, no traffic) about half the routes are 40 m from start to
    goal (55 % of 1,024 at seed 1; the candidates reach 32 m either side; a route through no or one
    junction), no vehicle drives, and the blocks behind the start are out of the scene (and of
    every curb window the step reads); at 1.5
    (the whole route through 1 junction) every route has 3 blocks; at 3 (2 junctions, every
    vehicle) 5 blocks and some traffic."""
    env = network_env(n=64, seed=1)
    env.set_difficulty(0.0)
    env.reset()
    st = env.get_state()
    length = st["route", "route_length"]
    assert (length > 4.0).all() and (length < 40.0 + 32.0 + 1.0).all()
    assert ((length - 40.0).abs() < 1.0).float().mean() > 0.4
    assert (st["route", "junctions"] <= 1).all()
    assert not st["tr_active"].any() and (st["route", "traffic_density"] == 0).all()
    first = st["level_blocks"][torch.arange(64), 0].unsqueeze(-1)
    assert not (st["mask"] & (st["segment_block"] < first)).any()
    assert (st["mask"] & (st["segment_block"] == first)).any(-1).all()
    # nor in any stretch's curb window, which the step's LiDAR and collision test read
    block = st["segment_block"].gather(1, st["window"].flatten(1).long()).view_as(st["window"])
    assert not (st["window_valid"] & (block < first.unsqueeze(-1))).any()
    assert (st["window_valid"] & (block == first.unsqueeze(-1))).any()
    env.set_difficulty(1.5)
    env.reset()
    st = env.get_state()
    assert (st["route", "junctions"] == 1).all() and (st["route", "blocks"] == 3).all()
    env.set_difficulty(3.0)
    env.reset()
    st = env.get_state()
    assert (st["route", "junctions"] == 2).all() and (st["route", "blocks"] == 5).all()
    assert st["tr_active"].any()
    assert (st["route", "route_length"] > 100.0).all()
    env.close()


def test_route_info_skips_the_junction_a_start_is_past():
    """A chain straight, crossing (a left turn), straight, roundabout (a right turn), straight,
    by hand: from block 0 both junctions count; a start past the crossing (on its exit arm)
    counts only the roundabout, its type and its turn."""
    state = {
        "block_type": torch.tensor([[0, 2, 0, 4, 0]] * 2),
        "junction_turn": torch.tensor([[0.0, 1.2, 0.0, -1.2, 0.0]] * 2),
        "tr_active": torch.zeros(2, 1, dtype=torch.bool),
        "tr_lanes": torch.zeros(2, 10, 3, 2),
        "tr_lane_len": torch.ones(2, 10),
        "goal_s": torch.tensor([100.0, 100.0]),
        "route_s": torch.tensor([0.0, 0.0]),
    }
    info = route_info(state, torch.tensor([0, 0]), torch.tensor([False, True]))
    assert info["junctions"].tolist() == [2.0, 1.0] and info["blocks"].tolist() == [5.0, 4.0]
    assert info["has_crossing"].tolist() == [1.0, 0.0]
    assert info["has_roundabout"].tolist() == [1.0, 1.0]
    assert info["turns_left"].tolist() == [1.0, 0.0] and info["turns_right"].tolist() == [1.0, 1.0]
    before = route_info(state, torch.tensor([2, 2]))  # from the middle link: the roundabout only
    assert before["junctions"].tolist() == [1.0, 1.0] and before["turns_left"].tolist() == [0, 0]


def test_bins_by_hand():
    info = {
        f"has_{k}": torch.tensor(v)
        for k, v in {
            "straight": [1.0, 0.0, 1.0],
            "curve": [0.0, 1.0, 0.0],
            "crossing": [1.0, 0.0, 0.0],
            "t_junction": [0.0, 0.0, 1.0],
            "roundabout": [0.0, 1.0, 1.0],
            "median": [0.0, 0.0, 0.0],
        }.items()
    }
    info |= {
        "junctions": torch.tensor([1.0, 1.0, 2.0]),
        "traffic_density": torch.tensor([0.0, 0.5, 1.5]),
        "turns_straight": torch.tensor([1.0, 0.0, 0.0]),
        "turns_left": torch.tensor([0.0, 1.0, 1.0]),
        "turns_right": torch.tensor([0.0, 0.0, 1.0]),
    }
    b = network_bins(info)
    assert b["block types on the route"]["roundabout"].tolist() == [False, True, True]
    assert b["block types on the route"]["median"].tolist() == [False, False, False]
    assert {k: v.tolist() for k, v in b["junctions"].items()} == {
        "0": [False, False, False],
        "1": [True, True, False],
        "2": [False, False, True],
    }
    traffic = {k: v.tolist() for k, v in b["traffic [vehicles / 100 m of lane]"].items()}
    assert traffic == {
        "0": [True, False, False],
        "0-1": [False, True, False],
        "1-2": [False, False, True],
        "2-20": [False, False, False],
    }
    assert b["turns at junctions"]["right"].tolist() == [False, False, True]


@pytest.mark.parametrize(
    ("task", "needle"),
    [
        (
            {"curriculum": {"junctions": [1, 2]}},
            "env.task.curriculum: difficulty, junctions, traffic and distance must have one value "
            "per level",
        ),
        (
            {"curriculum": {"distance": [40.0, 80.0]}},
            "env.task.curriculum: difficulty, junctions, traffic and distance must have one value "
            "per level, got 6, 6, 6 and 2",
        ),
        (
            {"curriculum": {"distance": [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0]}},
            "env.task.curriculum.distance",
        ),
        ({"scene": {"start_step": 0.0}}, "start_step = 0.0 is outside the allowed range"),
        (
            {"curriculum": {"difficulty": [0.0, 2.0, 1.0, 3.0, 4.0, 5.0]}},
            "env.task.curriculum.difficulty = [0.0, 2.0, 1.0, 3.0, 4.0, 5.0]: must start at 0 and "
            "increase",
        ),
        (
            {"network": {"num_blocks": [2, 4]}},
            "env.task.network.num_blocks = [2, 4]: not read by the network task",
        ),
        (
            {"network": {"block_types": ["straight", "curve"]}},
            "env.task.network.block_types = ['straight', 'curve']: needs a junction",
        ),
        ({"route": {"ahead": 0}}, "env.task.route.ahead = 0 is outside the allowed range"),
        ({"tracks": 65}, "env.task.tracks = 65 is outside the allowed range"),
        (
            {"traffic": {"density": [3.0, 1.0]}},
            "env.task.traffic.density = [3.0, 1.0]: min must not exceed max",
        ),
    ],
)
def test_bad_config_is_a_one_line_error(task, needle):
    with pytest.raises(ConfigError) as e:
        make_task(EnvConfig(task={"name": "network", **task})).sample(
            2, torch.Generator().manual_seed(0), torch.device("cpu")
        )
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_the_task_keeps_its_network_defaults_under_a_partial_override():
    """The task draws 12-18 m roads with 20 cm chords; setting one of them keeps the other (the
    sim's NetworkConfig defaults are 8-10 m and 5 cm)."""
    net = EnvConfig(task={"name": "network"}).task.network
    assert (tuple(net.road_width), net.chord_error) == ((12.0, 18.0), 0.2)
    net = EnvConfig(task={"name": "network", "network": {"chord_error": 0.1}}).task.network
    assert tuple(net.road_width) == (12.0, 18.0)
    net = EnvConfig(task={"name": "network", "network": {"road_width": [9, 10]}}).task.network
    assert net.chord_error == 0.2


def test_the_goal_link_is_never_a_curve_where_another_link_is_allowed(sampled):
    """The goal's link (the chain's last block) is a straight road or a median; with curves the
    only link type allowed, a curve."""
    from truckrl.sim.network.config import BLOCK_NAMES

    _, st = sampled
    curve = BLOCK_NAMES.index("curve")
    types = st["block_type"]
    assert (types[:, -1] >= 0).all() and (types[:, -1] != curve).all()
    assert (types[:, 0:-1:2] == curve).any()  # the other links still draw curves
    task = make_task(
        EnvConfig(task={"name": "network", "network": {"block_types": ["curve", "crossing"]}})
    )
    only = task.sample(8, torch.Generator().manual_seed(7), torch.device("cpu"))
    assert (only["block_type"][:, -1] == curve).all()
