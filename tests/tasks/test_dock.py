"""Task dock (truckrl/tasks/dock/task.py): specs, errors on the trailer against hand-computed values,
the rest test, one step's rewards by hand, reverse speed, tolerance floors and the start
curriculum of Task.on_reset."""

import math

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from truckrl.config.fields import ConfigError
from truckrl.env import TruckEnv
from truckrl.sim.collision import truck_collides
from truckrl.tasks import EnvConfig, make_task
from truckrl.tasks.base import NUM_FEATURES
from truckrl.tasks.dock.scene import START_APRON, START_PULLED

PRESET_TOL = {"position": 19.2, "heading_deg": 180.0}  # experiment=dock


def dock_env(n=8, seed=0, **cfg):
    config = {"task": {"name": "dock"}, "max_steps": 50, "tolerance": PRESET_TOL, **cfg}
    return TruckEnv(num_envs=n, config=config, seed=seed)


def params_of(n=1, **over):
    """Hand-picked trucks: a_tk 0.3 m, L_ka 8 m, trailer rear overhang 2 m (rear 10.3 m back)."""
    env = dock_env(n)
    env.reset()
    p = {k: v.clone() for k, v in env.get_state()["params"].items()}
    base = {"kingpin_offset": 0.3, "trailer_wheelbase": 8.0, "trailer_rear_overhang": 2.0}
    for k, v in {**base, **over}.items():
        p[k] = torch.full((n,), float(v))
    return env, p


def test_specs_and_observation_size():
    env = dock_env()
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["observation"].shape == (8, NUM_FEATURES + 4)
    assert env.task.reverse and env.task.error_keys == (
        "trailer_rear_error",
        "trailer_heading_error",
    )
    assert set(env.task.reward_keys) == {
        "r_progress",
        "r_trailer_heading",
        "r_time",
        "r_success",
        "r_collision",
        "r_timeout",
    }


def test_errors_on_the_trailer_by_hand():
    env, p = params_of(2)
    # theta 0, phi pi/2: trailer heading pi/2; kingpin (9.7, 5), trailer axle (9.7, -3),
    # trailer rear-centre (9.7, -5)
    pose = torch.tensor([[10.0, 5.0, 0.0, math.pi / 2]] * 2)
    # goal rear axle at the origin: its trailer rear-centre 10.3 m behind along the goal heading
    goal = torch.tensor([[0.0, 0.0, math.pi / 2], [0.0, 0.0, 0.0]])
    err = env.task.errors({"pose": pose, "goal": goal, "params": p})
    expect_pos = torch.tensor([math.hypot(9.7, -5.0 + 10.3), math.hypot(9.7 + 10.3, -5.0)])
    torch.testing.assert_close(err["trailer_rear_error"], expect_pos)
    torch.testing.assert_close(err["trailer_heading_error"], torch.tensor([0.0, math.pi / 2]))
    # the goal itself, at articulation 0: both errors 0
    at_goal = torch.cat((goal, torch.zeros(2, 1)), -1)
    err = env.task.errors({"pose": at_goal, "goal": goal, "params": p})
    torch.testing.assert_close(err["trailer_rear_error"], torch.zeros(2), atol=1e-5, rtol=0)


def at_goal_state(env, speed):
    """The env's state with every truck at its goal pose, articulation 0, at ``speed``."""
    env.reset()
    s = env.get_state()
    s["pose"] = torch.cat((s["goal"], torch.zeros(env.num_envs, 1)), -1)
    s["speed"] = torch.full((env.num_envs,), float(speed))
    s.update(env.task.errors(s))
    return s


def test_success_needs_rest():
    env = dock_env(4)
    env.set_difficulty(7.0)
    zero = torch.zeros(4, 2)
    td = env.set_state(at_goal_state(env, 0.0))
    nxt = env.step(td.set("action", zero))["next"]  # accel 0: stays at rest
    assert nxt["success"].all() and (nxt["r_success"] == 5.0).all()
    # rolling back at 0.5 m/s: within 0.15 m after one step but not at rest -> no success
    td = env.set_state(at_goal_state(env, 0.5))
    nxt = env.step(td.set("action", zero))["next"]
    assert (nxt["trailer_rear_error"] < 0.15).all() and not nxt["success"].any()
    # just below the rest threshold counts
    td = env.set_state(at_goal_state(env, 0.09))
    nxt = env.step(td.set("action", zero))["next"]
    assert nxt["success"].all()


def test_one_step_rewards_by_hand():
    """Pulled straight out D metres, full reverse accel, no steering: the trailer rear moves
    straight back by max_accel dt^2 (semi-implicit Euler), heading unchanged."""
    env = dock_env(4, tolerance={"position": 0.2, "heading_deg": 1.0})
    env.reset()
    s = env.get_state()
    D = 5.0
    u = torch.stack((s["goal"][:, 2].cos(), s["goal"][:, 2].sin()), -1)
    s["pose"] = torch.cat((s["goal"][:, :2] + D * u, s["goal"][:, 2:], torch.zeros(4, 1)), -1)
    s.update(env.task.errors(s))
    torch.testing.assert_close(s["trailer_rear_error"], torch.full((4,), D))
    td = env.set_state(s)
    action = torch.tensor([[-1.0, 0.0]] * 4)
    nxt = env.step(td.set("action", action))["next"]
    dt, a = 0.1, s["params", "max_accel"]
    torch.testing.assert_close(nxt["trailer_rear_error"][:, 0], D - a * dt * dt)
    torch.testing.assert_close(nxt["r_progress"][:, 0], 0.1 * a * dt * dt)
    torch.testing.assert_close(nxt["r_trailer_heading"][:, 0], torch.zeros(4), atol=1e-6, rtol=0)
    for k in ("r_time", "r_success", "r_collision", "r_timeout"):
        assert (nxt[k] == 0).all()
    torch.testing.assert_close(nxt["reward"][:, 0], 0.1 * a * dt * dt)
    # observation extras: goal straight behind the trailer rear; speed / reverse limit
    obs = nxt["observation"][:, NUM_FEATURES:]
    torch.testing.assert_close(obs[:, 0], -(D - a * dt * dt) / 50.0)
    torch.testing.assert_close(obs[:, 1], torch.zeros(4), atol=1e-6, rtol=0)
    rev = s["params", "max_reverse_speed"]
    torch.testing.assert_close(obs[:, 2], (rev - 2.25) / 0.75)
    torch.testing.assert_close(obs[:, 3], -a * dt / rev)


def test_terminal_rewards_and_heading_term():
    env = dock_env(2, max_steps=1)
    s = at_goal_state(env, 0.0)
    s["pose"][:, 3] = 0.2  # trailer turned by 0.2 rad; heading error 0.2
    s["mask"][:] = False  # (its rear would touch a bay wall)
    s.update(env.task.errors(s))
    env.set_difficulty(7.0)  # 0.1 rad: no success
    td = env.set_state(s)
    nxt = env.step(td.set("action", torch.zeros(2, 2)))["next"]
    assert (nxt["r_timeout"] == -8.0).all() and nxt["truncated"].all()
    before, after = 0.2, nxt["trailer_heading_error"][:, 0]
    torch.testing.assert_close(nxt["r_trailer_heading"][:, 0], 0.5 * (before - after))
    # collision: push the trailer 1 m into the dock face
    env = dock_env(2)
    s = at_goal_state(env, 0.0)
    u = torch.stack((s["goal"][:, 2].cos(), s["goal"][:, 2].sin()), -1)
    s["pose"][:, :2] -= 1.0 * u
    td = env.set_state(s)
    nxt = env.step(td.set("action", torch.zeros(2, 2)))["next"]
    assert nxt["collision"].all() and (nxt["r_collision"] == -7.0).all()


def test_reverse_speed_reachable():
    env = dock_env(4, control={"longitudinal": "accel", "lateral": "rate"})
    env.reset()
    s = env.get_state()
    s["mask"][:] = False  # an empty plane: nothing to hit while reversing
    td = env.set_state(s)
    for _ in range(40):  # 3 m/s at >= 1.5 m/s^2 takes <= 2 s
        td = env.step(td.set("action", torch.tensor([[-1.0, 0.0]] * 4)))["next"]
    torch.testing.assert_close(env.get_state()["speed"], -s["params", "max_reverse_speed"])


def test_tolerance_floors():
    env = dock_env(1)
    for d, pos, ang in (
        (0.0, 19.2, math.pi),
        (3.0, 2.4, math.pi / 8),
        (5.0, 0.6, 0.1),
        (7.0, 0.15, 0.1),
        (9.0, 0.15, 0.1),
    ):
        env.set_difficulty(d)
        p, a = env.tolerances()
        assert p.item() == pytest.approx(pos, rel=1e-5) and a.item() == pytest.approx(ang, rel=1e-5)


def test_start_curriculum_moves_the_start_closer():
    n = 400
    env = dock_env(n, seed=3)
    starts = {}
    for d in (0.0, 1.0, 3.5, 5.0, 7.0):
        env.set_seed(3)  # the same scenes at every difficulty
        env.set_difficulty(d)
        env.reset()
        starts[d] = env.get_state()
    s0, s7 = starts[0.0], starts[7.0]
    assert torch.equal(s0["goal"], s7["goal"]) and torch.equal(s0["segments"], s7["segments"])
    kind = {d: s["scene_info", "start_kind"] for d, s in starts.items()}
    assert (kind[0.0] == START_PULLED).all() and (kind[1.0] == START_PULLED).all()
    assert (kind[5.0] == START_APRON).all() and (kind[7.0] == START_APRON).all()
    frac = (kind[3.5] == START_APRON).float().mean()  # share (3.5 - 2) / (5 - 2) = 0.5
    assert 0.4 < frac < 0.6
    # difficulty 0: within [2, 4] m of the goal, straight out of the bay; 1: within [7, 14] m
    for d, lo, hi in ((0.0, 2.0, 4.0), (1.0, 7.0, 14.0)):
        e = starts[d]["trailer_rear_error"]
        room = starts[d]["scene_info", "pull_room"]
        assert (e >= torch.minimum(torch.tensor(lo), room) - 1e-3).all() and (e <= hi + 1e-3).all()
        assert (starts[d]["trailer_heading_error"] < 1e-5).all()
        torch.testing.assert_close(starts[d]["scene_info", "start_goal_distance"], e)
    assert starts[0.0]["trailer_rear_error"].mean() < 0.2 * s7["trailer_rear_error"].mean()
    # the apron starts at 7 are the generator's, untouched; every start is collision-free
    for s in starts.values():
        p = {k: s["params", k] for k in s["params"].keys()}
        assert not truck_collides(s["pose"], p, s["segments"], s["mask"]).any()
        assert (s["pose"][:, 3] == 0).all() and (s["speed"] == 0).all()
    # partial resets go through the hook too: a finished truck restarts pulled out at d = 0
    env.set_difficulty(0.0)
    td = env.reset()
    reset = torch.zeros(n, 1, dtype=torch.bool)
    reset[:5] = True
    env.reset(td.set("_reset", reset))
    assert (env.get_state()["scene_info", "start_kind"][:5] == START_PULLED).all()


def test_curriculum_off_and_forward_tasks_unaffected():
    env = dock_env(16, seed=2, task={"name": "dock", "start": {"enabled": False}})
    env.reset()
    assert (env.get_state()["scene_info", "start_kind"] == START_APRON).all()
    task = make_task(EnvConfig())
    marker = object()
    assert task.on_reset(marker, torch.zeros(1)) is marker


def test_bays_must_fit_the_truck():
    with pytest.raises(ConfigError, match="bay_width"):
        make_task(
            EnvConfig(
                task={
                    "name": "dock",
                    "scene": {"bay_width": [2.5, 3.0], "parked_width": [2.0, 2.2]},
                }
            )
        )
