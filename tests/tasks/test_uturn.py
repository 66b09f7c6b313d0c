"""Task uturn (truckrl/tasks/uturn/task.py): specs, hand-computed errors and rewards, reversing."""

import math

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from tests.conftest import compose_config
from truckrl.cli import to_config
from truckrl.config.schemas import TrainConfig
from truckrl.env import TruckEnv
from truckrl.sim.vehicle import truck_extents
from truckrl.tasks.base import NUM_FEATURES
from truckrl.tasks.config import EnvConfig
from truckrl.tasks.uturn.start import reverse_path
from truckrl.tasks.uturn.task import UTurnTask, route_to_go, turning_point

UTURN = {"task": {"name": "uturn"}}
TOL = 1e-3  # [m] float32 round-off at coordinates of O(100 m)


def test_check_env_specs():
    env = TruckEnv(num_envs=3, config=UTURN, seed=0)
    check_env_specs(env, seed=1)
    td = env.reset()
    assert td["observation"].shape == (3, NUM_FEATURES + 3)
    state = env.get_state()
    assert "max_reverse_speed" in state["params"].keys()
    assert {"road_width", "branch_side", "branch_angle", "goal_distance"} <= set(
        state["route"].keys()
    )


def test_experiment_preset_composes():
    tc = to_config(TrainConfig, compose_config("train", "experiment=uturn"))
    assert tc.env.task.name == "uturn"
    assert tc.env.max_steps == 1000 and tc.ppo.gamma == 0.998
    assert tc.env.task.observe_route  # P, T and the branch axis observed
    assert tc.demos.episodes == 0  # no driven demonstrations (docs/reversing.md)
    assert tc.collector.num_envs == 1024  # the fast layout underneath


def hand_state(pose, goal=(0.0, 0.0, math.pi)):
    return {
        "pose": torch.tensor([pose]),
        "goal": torch.tensor([goal]),
        "turn_point": torch.tensor([[10.0, 0.0]]),
        "start_heading": torch.tensor([0.0]),
    }


def test_errors_by_hand():
    task = UTurnTask(EnvConfig(task=UTURN["task"]))
    err = task.errors(hand_state((3.0, 4.0, 0.3, 0.1)))
    assert err["pos_error"].item() == pytest.approx(5.0)
    assert err["tractor_heading_error"].item() == pytest.approx(math.pi - 0.3, abs=1e-6)
    assert err["trailer_heading_error"].item() == pytest.approx(math.pi - 0.4, abs=1e-6)
    # wrapping: heading -3.0 is pi - 3.0 short of -pi (= pi); the trailer's -3.2 is past it
    err = task.errors(hand_state((0.0, 0.0, -3.0, -0.2)))
    assert err["tractor_heading_error"].item() == pytest.approx(math.pi - 3.0, abs=1e-6)
    assert err["trailer_heading_error"].item() == pytest.approx(3.2 - math.pi, abs=1e-6)


def test_rewards_by_hand():
    """Route shaping: to_go = w (|p - T| + |T - g|) + (1 - w) |p - g|, w = (1 + cos(theta -
    theta_0)) / 2, with T = (10, 0), g = (0, 0), theta_0 = 0."""
    task = UTurnTask(EnvConfig(task=UTURN["task"]))
    assert task.cfg.task.reward.shaping == "route"  # the default
    before = hand_state((3.0, 4.0, 0.0, 0.0))
    after = hand_state((6.0, 4.0, math.pi / 2, -0.5))
    for s in (before, after):
        s.update(task.errors(s))
    # before: w = 1, |p - T| = sqrt(49 + 16), |T - g| = 10
    to_go_b = math.sqrt(65.0) + 10.0
    # after: w = 1/2, |p - T| = sqrt(16 + 16), |p - g| = sqrt(36 + 16)
    to_go_a = 0.5 * (math.sqrt(32.0) + 10.0) + 0.5 * math.sqrt(52.0)
    assert route_to_go(before).item() == pytest.approx(to_go_b, rel=1e-6)
    assert route_to_go(after).item() == pytest.approx(to_go_a, rel=1e-6)
    no = torch.tensor([False])
    flags = {"success": no, "collision": torch.tensor([True]), "jackknife": no, "truncated": no}
    r = task.reward_terms(before, after, flags)
    assert tuple(r) == task.reward_keys
    assert r["r_progress"].item() == pytest.approx(0.05 * (to_go_b - to_go_a), rel=1e-5)
    # headings to the goal's pi: tractor pi -> pi/2, trailer pi -> pi/2 + 0.5 (+0.5 rad wrong)
    assert r["r_tractor_heading"].item() == pytest.approx(0.5 * (math.pi / 2), rel=1e-5)
    assert r["r_trailer_heading"].item() == pytest.approx(0.5 * (math.pi / 2 - 0.5), rel=1e-5)
    assert r["r_collision"].item() == -7.0
    assert r["r_success"].item() == 0.0 and r["r_timeout"].item() == 0.0 and r["r_time"].item() == 0
    flags = {"success": torch.tensor([True]), "collision": no, "jackknife": no, "truncated": no}
    assert task.reward_terms(before, after, flags)["r_success"].item() == 5.0
    flags = {"success": no, "collision": no, "jackknife": no, "truncated": torch.tensor([True])}
    assert task.reward_terms(before, after, flags)["r_timeout"].item() == -8.0
    # the paper's shaping: straight distance to the goal, 5 -> sqrt(52)
    goal_task = UTurnTask(EnvConfig(task={"name": "uturn", "reward": {"shaping": "goal"}}))
    r = goal_task.reward_terms(before, after, flags)
    assert r["r_progress"].item() == pytest.approx(0.05 * (5.0 - math.sqrt(52.0)), rel=1e-5)


def test_turning_point_on_the_branch_axis():
    """T = mouth + R(heading) (depth cot a, side (W / 2 + depth)), depth = 0.5 branch depth."""
    info = {
        "road_width": torch.tensor([8.0, 8.0]),
        "branch_depth": torch.tensor([20.0, 20.0]),
        "branch_side": torch.tensor([1.0, -1.0]),
        "branch_angle": torch.tensor([math.pi / 2, math.pi / 4]),
        "mouth_x": torch.tensor([1.0, 0.0]),
        "mouth_y": torch.tensor([2.0, 0.0]),
        "road_heading": torch.tensor([math.pi / 2, 0.0]),
    }
    t = turning_point(info, 0.5)
    # scene 0: local (0, 4 + 10) turned by 90 deg -> (-14, 0), plus the mouth
    assert torch.allclose(t[0], torch.tensor([-13.0, 2.0]), atol=1e-5)
    # scene 1: right branch leaning forward at 45 deg: local (10, -(4 + 10))
    assert torch.allclose(t[1], torch.tensor([10.0, -14.0]), atol=1e-5)


def test_negative_speed_reachable():
    """The default control (acceleration + steering rate): full braking at rest reverses, down
    to -max_reverse_speed, the truck moves backwards, and the extras show it."""
    env = TruckEnv(num_envs=4, config=UTURN, seed=3)
    td = env.reset()
    start = env.get_state()
    for _ in range(40):
        td["action"] = torch.tensor([[-1.0, 0.0]]).expand(4, 2)
        td = env.step(td)["next"]
    s = env.get_state()
    v_rev = s["params", "max_reverse_speed"]
    assert torch.allclose(s["speed"], -v_rev)
    heading = start["pose"][:, 2]
    moved = s["pose"][:, :2] - start["pose"][:, :2]
    along = moved[:, 0] * heading.cos() + moved[:, 1] * heading.sin()
    assert (along < -5.0).all()
    obs = td["observation"]
    assert torch.allclose(obs[:, NUM_FEATURES], torch.full((4,), -1.0))
    lo, hi = env.config.vehicle.max_reverse_speed
    assert torch.allclose(obs[:, NUM_FEATURES + 1], (v_rev - (lo + hi) / 2) / ((hi - lo) / 2))


def test_hand_built_state_gets_a_turning_point():
    """A state without scene metadata (set_state from a hand-made state) still runs."""
    env = TruckEnv(num_envs=2, config=UTURN, seed=0)
    env.reset()
    state = env.get_state()
    want = state["turn_point"].clone()
    del state["turn_point"]
    env.set_state(state.clone())
    assert torch.allclose(env.get_state()["turn_point"], want)
    del state["route"]
    env.set_state(state)
    mid = 0.5 * (state["pose"][:, :2] + state["goal"][:, :2])
    assert torch.allclose(env.get_state()["turn_point"], mid)


# ----------------------------------------------------------------------------- start curriculum
def curriculum_starts(difficulty: float, n: int = 10_000, seed: int = 7, **start):
    """``n`` default scenes after ``on_reset`` at ``difficulty``: (task, state before, after)."""
    cfg = EnvConfig(task={"name": "uturn", "start": start})
    task = UTurnTask(cfg)
    before = task.sample(n, torch.Generator().manual_seed(seed), torch.device("cpu"))
    after = task.on_reset(before.clone(), torch.full((n,), difficulty))
    return task, before, after


@pytest.mark.parametrize("difficulty", [0.0, 1.0, 2.0, 3.0, 4.0, 9.0])
def test_start_kinds_follow_the_difficulty(difficulty):
    """With stage_difficulty (0, 4): p = d / 4, z = 3 p + r (r the stage draw); z >= 3 keeps
    the generator's road start; 2 <= z < 3 starts on the forward leg, z - 2 of the way from the
    pull point back to the road start; z < 2 on the reverse path at sigma >= 1 - z / 2 (further
    on only where the drawn point is not free; rarely). Moved starts are at rest, their errors
    recomputed, ``pulled`` set on the path."""
    _, before, after = curriculum_starts(difficulty)
    r = before["route", "stage_draw"]
    z = 3.0 * min(difficulty / 4.0, 1.0) + r
    kind = after["route", "start_kind"]
    road, leg = kind == 0.0, kind == 4.0
    path = ~(road | leg)
    assert torch.equal(road, z >= 3.0) and torch.equal(leg, (z >= 2.0) & (z < 3.0))
    assert torch.equal(after["pose"][road], before["pose"][road])
    sigma = after["route", "start_sigma"]
    assert (sigma[road] == -1.0).all()
    assert torch.allclose(sigma[leg], 2.0 - z[leg])
    drawn = 1.0 - 0.5 * z[path]
    assert (sigma[path] >= drawn - 1e-5).all() and (sigma[path] <= 1.0).all()
    if path.any():
        assert (sigma[path] > drawn + 1e-5).float().mean().item() < 0.3
    assert (after["pulled"][path] == 1.0).all() and (after["pulled"][road] == 0.0).all()
    assert (after["speed"] == 0).all()
    task = UTurnTask(EnvConfig(task={"name": "uturn"}))
    err = task.errors({k: after[k] for k in ("pose", "goal")})
    for k, v in err.items():
        assert torch.allclose(after[k], v)


def test_curriculum_off_and_hand_built_states_keep_the_start():
    _, before, after = curriculum_starts(0.0, n=100, enabled=False)
    assert torch.equal(after["pose"], before["pose"])
    task = UTurnTask(EnvConfig(task=UTURN["task"]))
    state = before.clone()
    del state["route"]
    assert torch.equal(task.on_reset(state, torch.zeros(100))["pose"], before["pose"])


def articulated_footprint(pose: np.ndarray, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Tractor and trailer rectangles ``[n, 4, 2]`` at any articulation, from the parameters
    alone: the tractor as in the scene tests; the trailer about its kingpin (``kingpin_offset``
    behind the tractor rear axle) along ``theta + phi``."""
    from tests.sim.test_uturn_scene import footprint

    tractor, _ = footprint(pose, p)
    x, y, th, phi = pose.T
    psi = th + phi
    k = np.stack((x - p["kingpin_offset"] * np.cos(th), y - p["kingpin_offset"] * np.sin(th)), -1)
    u = np.stack((np.cos(psi), np.sin(psi)), -1)
    v = np.stack((-np.sin(psi), np.cos(psi)), -1)
    ahead = p["trailer_front_overhang"]
    behind = p["trailer_wheelbase"] + p["trailer_rear_overhang"]
    half = 0.5 * p["trailer_width"]
    trailer = np.stack(
        [
            k + a[:, None] * u + sgn * half[:, None] * v
            for a, sgn in ((ahead, -1), (ahead, 1), (-behind, 1), (-behind, -1))
        ],
        1,
    )
    return tractor, trailer


@pytest.mark.parametrize("difficulty", [0.0, 1.0, 2.0, 3.0])
def test_path_starts_are_free_and_on_the_manoeuvre(difficulty):
    """On 10,000 scenes per difficulty, checked with geometry written here (separating axes on
    rectangles built from the parameters): every start keeps more than 15 cm to every segment
    (the clearance is 20 cm) and the simulator agrees; no start is jack-knifed. Past the branch:
    straight, facing the start heading, the trailer axle on the road centreline beyond the mouth.
    In the branch: straight on the branch axis, facing out. On the arc: the trailer between the
    two headings. On the forward leg: straight, facing the start heading, between the road
    start and the centreline."""
    from tests.sim.test_uturn_scene import local, sat_gap
    from truckrl.sim.collision import truck_collides

    task, before, after = curriculum_starts(difficulty)
    p = {k: after["params", k].double().numpy() for k in after["params"].keys()}
    info = {k: after["route", k].double().numpy() for k in after["route"].keys()}
    pose = after["pose"].double().numpy()
    seg, mask = after["segments"].double().numpy(), after["mask"].numpy()
    for rect in articulated_footprint(pose, p):
        gap = np.where(mask, sat_gap(rect, seg), np.inf)
        assert gap.min() > 0.15, f"a start comes within {gap.min():.3f} m of a segment"
    params = {k: after["params", k] for k in after["params"].keys()}
    assert not truck_collides(after["pose"], params, after["segments"], after["mask"]).any()
    assert (np.abs(pose[:, 3]) < p["max_articulation"]).all()

    kind = info["start_kind"]
    rel = (pose[:, 2] - info["road_heading"] + np.pi) % (2 * np.pi) - np.pi
    side, a = info["branch_side"], info["branch_angle"]
    out = np.arctan2(-side * np.sin(a), -np.cos(a))  # facing out of the branch (scene frame)
    axle = pose[:, :2] - (p["kingpin_offset"] + p["trailer_wheelbase"])[:, None] * np.stack(
        (np.cos(pose[:, 2]), np.sin(pose[:, 2])), -1
    )
    q = local(axle, info)  # the trailer axle in the scene frame (when straight)
    past, branch, arc, leg = kind == 1.0, kind == 3.0, kind == 2.0, kind == 4.0
    assert past.any() or branch.any() or arc.any() or leg.any()
    # the forward leg: straight, facing the start heading, the rear axle on the road between
    # the road start's lane and the centreline, in front of the mouth's far chamfer
    assert np.allclose(pose[leg, 3], 0.0) and np.allclose(np.cos(rel[leg]), 1.0, atol=1e-5)
    start_q = local(before["pose"].double().numpy()[:, :2], info)
    rear_axle = local(pose[:, :2], info)
    assert (rear_axle[leg, 0] >= start_q[leg, 0] - TOL).all()
    assert (rear_axle[leg, 1] <= TOL).all() and (rear_axle[leg, 1] >= start_q[leg, 1] - TOL).all()
    assert np.allclose(pose[past | branch, 3], 0.0)
    assert np.allclose(np.cos(rel[past]), 1.0, atol=1e-5)
    assert np.allclose(q[past, 1], 0.0, atol=TOL)
    assert (q[past, 0] > 0.0).all()
    assert np.allclose(np.cos(rel[branch] - out[branch]), 1.0, atol=1e-5)
    # on the branch axis: through (0, side W / 2) along (cos a, side sin a)
    w = q[branch] - np.stack((0 * side, side * 0.5 * info["road_width"]), -1)[branch]
    b = np.stack((np.cos(a), side * np.sin(a)), -1)[branch]
    assert np.allclose(w[:, 0] * b[:, 1] - w[:, 1] * b[:, 0], 0.0, atol=TOL)
    assert ((w * b).sum(-1) > 0).all(), "the trailer axle lies inside the branch"
    # on the arc the trailer heading turns from the start heading (0) to facing out
    psi = (rel + pose[:, 3] + np.pi) % (2 * np.pi) - np.pi
    lo, hi = np.minimum(0.0, out), np.maximum(0.0, out)
    assert ((psi[arc] >= lo[arc] - 1e-4) & (psi[arc] <= hi[arc] + 1e-4)).all()


def test_route_via_the_pull_point_by_hand():
    """Before the truck has pulled past P the route runs p -> P -> T -> g; after, p -> T -> g.
    T = (10, 0), P = (20, 0), g = (0, 0), theta_0 = 0; p = (3, 4) facing the start heading."""
    s = hand_state((3.0, 4.0, 0.0, 0.0))
    s["pull_point"] = torch.tensor([[20.0, 0.0]])
    s["pulled"] = torch.tensor([0.0])
    want = math.hypot(17.0, 4.0) + 10.0 + 10.0
    assert route_to_go(s).item() == pytest.approx(want, rel=1e-6)
    s["pulled"] = torch.tensor([1.0])
    assert route_to_go(s).item() == pytest.approx(math.sqrt(65.0) + 10.0, rel=1e-6)


def test_pulled_latches_once_level_with_the_pull_point():
    """Driving forward from the road start: ``pulled`` is 0 until the rear axle is level with
    P along the start heading, then stays 1 while the truck reverses back; the observation's
    last feature shows it."""
    env = TruckEnv(
        num_envs=2, config={"task": {"name": "uturn", "start": {"enabled": False}}}, seed=4
    )
    td = env.reset()
    s = env.get_state()
    assert (s["pulled"] == 0).all() and (td["observation"][:, -1] == 0).all()
    h = s["start_heading"]
    u = torch.stack((h.cos(), h.sin()), -1)
    seen = torch.zeros(2, dtype=torch.bool)
    for i in range(400):
        s = env.get_state()
        ahead = ((s["pose"][:, :2] - s["pull_point"]) * u).sum(-1)
        seen |= ahead >= 0
        assert torch.equal(s["pulled"] == 1.0, seen), i
        action = torch.where(seen[:, None], torch.tensor([-1.0, 0.0]), torch.tensor([0.3, 0.0]))
        td["action"] = action
        td = env.step(td)["next"]
        if td["done"].any():
            break
    assert seen.any(), "no truck pulled past P"
    assert (td["observation"][seen, -1] == 1.0).all()


def test_reverse_path_ends_short_of_the_end_wall():
    """The start curriculum's reverse path ends (sigma = 1) with the truck straight on the branch
    axis, facing out, its rear-centre ``branch_end_gap`` (0.5-2 m) plus the skew of its corners
    short of the branch end wall (branch axis and wall computed here from the scene metadata),
    over 2,000 scenes (branch angles across their range)."""
    n = 2000
    env = TruckEnv(num_envs=n, config=UTURN, seed=7)
    env.reset()
    s = env.get_state()
    info = s["route"]
    a, side, h = info["branch_angle"], info["branch_side"], info["road_heading"]
    # the branch axis in the world, from the local (cos a, side sin a)
    axis = torch.stack(
        (
            a.cos() * h.cos() - side * a.sin() * h.sin(),
            a.cos() * h.sin() + side * a.sin() * h.cos(),
        ),
        -1,
    )
    normal = torch.stack((-side * h.sin(), side * h.cos()), -1)  # across the road, branch side
    # the branch axis leaves the branch-side curb at the local x = 0 (mouth_x, mouth_y: the
    # road centreline there)
    mouth = torch.stack((info["mouth_x"], info["mouth_y"]), -1)
    mouth = mouth + 0.5 * info["road_width"][:, None] * normal
    path = reverse_path(info, s["params"], env.task.cfg.task.start)
    end = path.pose(torch.ones(n))[:, :2]  # tractor rear axle at the path's end
    rel = end - mouth
    assert (rel[:, 0] * axis[:, 1] - rel[:, 1] * axis[:, 0]).abs().max() < TOL
    _, rear, half_w = truck_extents({k: s["params"][k] for k in s["params"].keys()})
    rear_depth = ((end + rear[:, None] * axis - mouth) * normal).sum(-1)
    short = info["branch_depth"] - rear_depth - half_w * a.cos().abs()
    assert short.min() > 0.5 - TOL and short.max() < 2.0 + TOL


def test_observe_route_extras_by_hand():
    """``env.task.observe_route``: 6 more features after the 3, P and T in the tractor frame
    over the sensor scale, then the branch axis heading relative to the tractor (sin, cos).
    Tractor at (10, 5) heading 90 deg: P = (10, 25) is 20 m ahead, T = (0, 5) 10 m to its left;
    the branch axis points along -x, 90 deg left of the heading."""
    from truckrl.tasks.config import SENSOR_SCALE

    cfg = EnvConfig(task={"name": "uturn", "observe_route": True})
    task = UTurnTask(cfg)
    assert task.num_extras == 9 and task.num_features == NUM_FEATURES + 9
    assert UTurnTask(EnvConfig(task=UTURN["task"])).num_extras == 3  # the default is unchanged
    s = {
        "pose": torch.tensor([[10.0, 5.0, math.pi / 2, 0.0]]),
        "speed": torch.tensor([-1.0]),
        "params": {"max_reverse_speed": torch.tensor([2.0])},
        "pulled": torch.tensor([1.0]),
        "pull_point": torch.tensor([[10.0, 25.0]]),
        "turn_point": torch.tensor([[0.0, 5.0]]),
        "turn_axis": torch.tensor([[-1.0, 0.0]]),
    }
    x = task.observation_extras(s)[0]
    assert x.shape == (9,)
    assert x[0].item() == pytest.approx(-0.5) and x[2].item() == 1.0
    want = torch.tensor([20.0, 0.0, 0.0, 10.0]) / SENSOR_SCALE
    assert torch.allclose(x[3:7], want, atol=1e-5)
    assert torch.allclose(x[7:], torch.tensor([1.0, 0.0]), atol=1e-6)
    env = TruckEnv(num_envs=3, config=cfg, seed=0)
    check_env_specs(env, seed=1)
    assert env.reset()["observation"].shape == (3, NUM_FEATURES + 9)


def test_a_checkpoint_with_the_route_observed_loads(tmp_path):
    """The observation size of a saved policy follows its config (``observe_route``: 26 + 9),
    not the task class alone; the other setting is refused in one line."""
    from dataclasses import asdict

    import yaml

    from truckrl.rl.checkpoint import CheckpointError, save_training_state
    from truckrl.rl.curriculum import Curriculum
    from truckrl.rl.network import make_actor_critic
    from truckrl.rl.policy import load_policy
    from truckrl.rl.ppo import PPO

    for observe, path in ((True, tmp_path / "a.pt"), (False, tmp_path / "b.pt")):
        tc = to_config(
            TrainConfig, compose_config("train", "experiment=uturn", "env.compile=false")
        )
        ac = make_actor_critic(tc.model, NUM_FEATURES + 9, tc.env.lidar.num_beams)
        tc.env.task.observe_route = observe
        save_training_state(path, model=ac.model, ppo=PPO(ac, tc.ppo),
                            curriculum=Curriculum(tc.curriculum),
                            counters={"iteration": 1, "frames": 1, "wall_time_s": 1.0},
                            config_yaml=yaml.safe_dump(asdict(tc)),
                            num_obs=NUM_FEATURES + 9, num_beams=tc.env.lidar.num_beams)  # fmt: skip
    assert load_policy(tmp_path / "a.pt").env_config.task.observe_route
    with pytest.raises(
        CheckpointError, match="35 observation features but task 'uturn' observes 29"
    ):
        load_policy(tmp_path / "b.pt")
