"""TruckEnv through its public API: TorchRL spec checks, hand-computed rewards, resets, seeding,
state get/set, vehicle params, control modes."""

import itertools
import math

import pytest
import torch
from torchrl.envs import ParallelEnv
from torchrl.envs.utils import check_env_specs

from truckrl.config.fields import ConfigError
from truckrl.env import TruckEnv
from truckrl.sim.control import CONTROL_KEYS, LATERAL_MODES, LONGITUDINAL_MODES
from truckrl.sim.vehicle import truck_corners
from truckrl.tasks import NUM_FEATURES, EnvConfig


def make(n=4, seed=0, **cfg):
    return TruckEnv(num_envs=n, config=cfg, seed=seed)


@pytest.mark.parametrize("n", [1, 7, 256])
def test_check_env_specs(n):
    env = make(n)
    check_env_specs(env, seed=1)
    td = env.reset()
    assert td["observation"].shape == (n, NUM_FEATURES)
    assert td["lidar"].shape == (n, env.config.lidar.num_beams)


def _make_worker():
    return TruckEnv(num_envs=8)


def test_parallel_env_specs_and_distinct_workers():
    penv = ParallelEnv(2, _make_worker)
    try:
        check_env_specs(penv, seed=3)
        penv.set_seed(5)
        td = penv.reset()
        assert td.batch_size == (2, 8)
        assert not torch.allclose(td["observation"][0], td["observation"][1])
        penv.set_difficulty(1.5)
        assert penv.get_difficulty() == [1.5, 1.5]
    finally:
        penv.close()


def clear_scene(env, goal=(40.0, 0.0, 0.0), **overrides):
    """Start every truck at the origin heading +x, at rest, with no segments and ``goal``;
    ``overrides`` set state entries (e.g. ``speed``). Returns the reset tensordict."""
    s = env.get_state()
    n = env.num_envs
    s["pose"] = torch.zeros(n, 4)
    s["goal"] = torch.tensor(goal).expand(n, 3).clone()
    s["mask"] = torch.zeros_like(s["mask"])
    for k in CONTROL_KEYS:
        s[k] = torch.zeros(n)
    for k, v in overrides.items():
        s[k] = v
    s.update(env.task.errors(s))
    return env.set_state(s)


def test_progress_reward_driving_straight_at_goal():
    env = make(3, control={"longitudinal": "speed", "lateral": "angle"})
    env.reset()
    td = clear_scene(env, goal=(40.0, 0.0, 0.0))
    vmax = env.params["max_speed"].clone()
    nxt = env.step(td.set("action", torch.tensor([[1.0, 0.0]] * 3)))["next"]
    # speed mode: +1 commands max_speed; one Euler step moves the rear axle v*dt toward the goal
    expected = 0.05 * vmax * 0.1
    torch.testing.assert_close(nxt["r_progress"][:, 0], expected, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(nxt["reward"][:, 0], expected, atol=1e-5, rtol=1e-5)
    assert torch.all(nxt["r_tractor_heading"] == 0) and torch.all(nxt["r_trailer_heading"] == 0)
    assert not nxt["done"].any()


def test_heading_correction_reward():
    env = make(2, control={"longitudinal": "accel", "lateral": "rate"})
    env.reset()
    pose = torch.tensor([[0.0, 0.0, 0.3, 0.0]] * 2)  # tractor and trailer 0.3 rad off the goal
    td = clear_scene(env, pose=pose, speed=torch.full((2,), 5.0))
    nxt = env.step(td.set("action", torch.tensor([[0.0, -1.0]] * 2)))["next"]
    p = env.get_state()["pose"]
    d_tractor = 0.3 - p[:, 2].abs()
    d_trailer = 0.3 - (p[:, 2] + p[:, 3]).abs()
    torch.testing.assert_close(nxt["r_tractor_heading"][:, 0], 0.5 * d_tractor)
    torch.testing.assert_close(nxt["r_trailer_heading"][:, 0], 0.5 * d_trailer)


def test_success_gives_plus_five_and_terminates():
    env = make(2, control={"longitudinal": "speed", "lateral": "angle"})
    env.reset()
    env.set_difficulty(6.0)  # 0.47 m and 0.94 deg: the paper's hardest level
    td = clear_scene(env, goal=(0.5, 0.0, 0.0))
    nxt = env.step(td.set("action", torch.tensor([[-1.0, 0.0]] * 2)))["next"]  # stay at rest
    assert not nxt["success"].any()
    td = clear_scene(env, goal=(0.3, 0.0, 0.0))
    nxt = env.step(td.set("action", torch.tensor([[-1.0, 0.0]] * 2)))["next"]
    assert nxt["success"].all() and nxt["terminated"].all() and nxt["done"].all()
    assert torch.all(nxt["r_success"] == 5.0)
    assert not nxt["truncated"].any()


@pytest.mark.parametrize("kind", [0, 1])
def test_collision_with_curb_or_obstacle(kind):
    env = make(1, control={"longitudinal": "speed", "lateral": "angle"})
    env.reset()
    clear_scene(env)
    s = env.get_state()
    tractor, _, _ = truck_corners(s["pose"], s["params"])
    bumper = float(tractor[0, :, 0].max())
    s["segments"][0, 0] = torch.tensor([bumper + 0.2, -5.0, bumper + 0.2, 5.0])  # 0.2 m ahead
    s["mask"][0, 0] = True
    s["kind"][0, 0] = kind
    td = env.set_state(s)
    nxt = env.step(td.set("action", torch.tensor([[1.0, 0.0]])))["next"]  # >= 0.6 m per step
    assert nxt["collision"].all() and nxt["terminated"].all()
    assert float(nxt["r_collision"]) == -7.0
    terms = sum(nxt[k] for k in env.task.reward_keys)
    torch.testing.assert_close(nxt["reward"], terms, msg="terms must sum to the reward")


def test_timeout_after_200_steps():
    env = make(2, control={"longitudinal": "accel", "lateral": "rate"})
    td = env.reset()
    env.set_difficulty(20.0)  # no accidental success
    action = torch.zeros(2, 2)  # at rest forever
    for step in range(1, 201):
        nxt = env.step(td.set("action", action))["next"]
        if step < 200:
            assert not nxt["done"].any(), step
            td = nxt
    assert nxt["truncated"].all() and not nxt["terminated"].any()
    assert torch.all(nxt["r_timeout"] == -8.0)
    assert torch.all(nxt["step_count"] == 200)


def test_partial_reset_keeps_other_envs_bit_for_bit():
    env = make(6, seed=4)
    td = env.reset()
    for _ in range(5):
        td = env.step(td.set("action", env.action_spec.rand()))["next"]
    before = env.get_state()
    reset = torch.tensor([False, True, False, False, True, False])
    env.reset(td.set("_reset", reset[:, None]))
    after = env.get_state()
    keep = ~reset
    for key in before.keys(include_nested=True, leaves_only=True):
        assert torch.equal(before[key][keep], after[key][keep]), key
    assert torch.all(after["step_count"][reset] == 0)
    assert not torch.equal(before["goal"][reset], after["goal"][reset])


def test_partial_reset_observation_is_the_restarted_state_observed():
    # Independent answer: Task.observe run on the env's state rows after the reset (the pool's
    # precomputed first observation must be exactly what observing the new episode gives).
    n = 16
    env = make(n, seed=8, max_steps=5)
    env.set_difficulty(1.5)
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    checked = 0
    for _ in range(12):
        out, td = env.step_and_maybe_reset(td.set("action", torch.rand(n, 2, generator=gen)))
        idx = out["next", "done"].squeeze(-1).nonzero().squeeze(-1)
        if not idx.numel():
            continue
        state = env.get_state()[idx]
        flat = {k: state[k] for k in env._state_keys}
        flat["params"] = {k: state["params", k] for k in env._param_keys}
        want = env.task.observe(flat, torch.full((idx.numel(),), 1.5))
        for key, value in want.items():
            assert torch.equal(td[key][idx], value), key
        checked += idx.numel()
    assert checked >= n


@pytest.mark.parametrize("task", [{"name": "dock"}], ids=lambda task: task["name"])
def test_restart_after_a_difficulty_change_starts_at_the_new_difficulty(task):
    # Independent answer: a twin of the same seed at the new difficulty from the start draws the
    # same episodes in the same order (a task whose draws do not depend on the difficulty; the
    # network task's depend on its level: tests/tasks/network), so its restarts must match bit
    # for bit. The pool prepares
    # its episodes (a task's start curriculum) for the difficulty of the first take; a pool that
    # kept them after set_difficulty, or a curriculum that wrote into the drawn episodes, would
    # restart the trucks at the old one.
    cfg = {"task": task, "max_steps": 1, "episode_pool": 16}
    changed, twin, old = (make(4, seed=6, **cfg) for _ in range(3))
    action = torch.zeros(4, 2)
    outs = []
    for env, d in ((changed, 0.0), (twin, 3.0), (old, 0.0)):
        env.set_difficulty(d)
        td = env.reset()
        changed.set_difficulty(3.0)  # after its first episodes were drawn and started
        _, td = env.step_and_maybe_reset(td.set("action", action))  # every truck restarts
        outs.append((env.get_state(), td))
    (a, ta), (b, tb), (c, _) = outs
    assert torch.all(a["step_count"] == 0)
    for key in b.keys(include_nested=True, leaves_only=True):
        assert torch.equal(a[key], b[key]), key
    for key in ("observation", "lidar", "difficulty"):
        assert torch.equal(ta[key], tb[key]), key
    assert not torch.equal(a["pose"], c["pose"])  # the difficulty moves these starts


def test_same_seed_same_observations_different_seed_differs():
    a = make(5, seed=123).reset()
    b = make(5, seed=123).reset()
    c = make(5, seed=124).reset()
    assert torch.equal(a["observation"], b["observation"]) and torch.equal(a["lidar"], b["lidar"])
    assert not torch.equal(a["observation"], c["observation"])


def test_set_state_replays_the_saved_start_and_keeps_the_scene_sequence():
    env, twin = make(2, seed=9), make(2, seed=9)
    first = env.reset()
    start = env.get_state()
    for _ in range(4):
        env.step(first.clone().set("action", torch.ones(2, 2)))
    again = env.set_state(start)
    assert torch.equal(again["observation"], first["observation"])
    assert torch.equal(again["lidar"], first["lidar"])
    assert torch.all(env.get_state()["step_count"] == 0)
    twin.reset()
    assert torch.equal(env.reset()["observation"], twin.reset()["observation"])  # next scenes agree
    with pytest.raises(ValueError, match="batch size"):
        env.set_state(start[:1])


def test_params_are_readable_and_writable():
    env = make(3, control={"longitudinal": "speed", "lateral": "angle"})
    env.reset()
    td = clear_scene(env)
    env.params["max_speed"][:] = torch.tensor([4.0, 6.0, 8.0])  # write: takes effect next step
    env.step(td.set("action", torch.tensor([[1.0, 0.0]] * 3)))
    torch.testing.assert_close(env.get_state()["speed"], torch.tensor([4.0, 6.0, 8.0]))
    assert env.params.batch_size == (3,)


@pytest.mark.parametrize("lon,lat", list(itertools.product(LONGITUDINAL_MODES, LATERAL_MODES)))
def test_every_control_pairing_respects_bounds(lon, lat):
    env = make(16, seed=7, control={"longitudinal": lon, "lateral": lat})
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(30):
        action = torch.rand(16, 2, generator=gen) * 4 - 2  # outside [-1, 1] on purpose
        td = env.step(td.set("action", action))["next"]
        s = env.get_state()
        p = s["params"]
        assert torch.all(s["speed"] <= p["max_speed"] + 1e-5)
        assert torch.all(s["speed"] >= env.config.vehicle.min_speed - 1e-5)
        assert torch.all(s["steer"].abs() <= p["max_steer"] + 1e-5)
        assert torch.all(s["accel"].abs() <= p["max_accel"] + 1e-4)
        assert torch.all(s["steer_rate"].abs() <= p["max_steer_rate"] + 1e-4)
        assert torch.isfinite(td["observation"]).all()
        td = env.reset(td) if td["done"].any() else td


def test_nonfinite_actions_are_zeroed_and_flagged():
    env = make(3)
    td = env.reset()
    action = torch.tensor([[math.nan, 0.5], [0.2, math.inf], [0.3, 0.1]])
    td = env.step(td.set("action", action))["next"]
    assert td["action_nonfinite"][:, 0].tolist() == [True, True, False]
    s = env.get_state()
    for key in s.keys(include_nested=True, leaves_only=True):
        if s[key].is_floating_point():
            assert torch.isfinite(s[key]).all(), key
    strict = make(2, nonfinite_action="error")
    td = strict.reset()
    with pytest.raises(ValueError, match="non-finite action"):
        strict.step(td.set("action", torch.tensor([[0.0, 0.0], [math.nan, 0.0]])))


def test_difficulty_sets_paper_tolerances():
    env = make(2)
    env.set_difficulty(6.0)
    pos, ang = env.tolerances()
    torch.testing.assert_close(pos, torch.full((2,), 30.0 / 64))  # paper: 0.47 m at difficulty 6
    torch.testing.assert_close(ang, torch.full((2,), math.radians(60.0) / 64))
    with pytest.raises(ConfigError, match="difficulty"):
        env.set_difficulty(-1.0)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"dt": 0.0}, "env.dt"),
        ({"max_steps": 0}, "env.max_steps"),
        ({"max_steps": 200.5}, "env.max_steps"),
        ({"substeps": 1.5}, "env.substeps"),
        ({"control": {"longitudinal": "warp", "lateral": "rate"}}, "control.longitudinal"),
        ({"task": {"reward": {"progres": 1.0}}}, "unknown field"),
        ({"task": {"name": "nosuchtask"}}, "env.task.name"),
        ({"vehicle": "default"}, "env.vehicle"),
    ],
)
def test_bad_config_names_the_field(kwargs, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        EnvConfig(**kwargs)


@pytest.mark.parametrize("n", [0, 2.5, "4", True])
def test_bad_num_envs(n):
    with pytest.raises(ConfigError, match="num_envs"):
        TruckEnv(num_envs=n)


def test_compacted_scene_gives_the_outputs_of_the_full_scene():
    # The env hands the step a valid-first scene cut to the largest valid count (padding
    # dropped). Independent answer: Task.transition on the full, uncompacted state. Half the
    # trucks are moved onto a valid segment's midpoint so collisions occur; row 0 has every slot
    # valid (nothing to cut), row 1 none; partial resets change the rows and the cut between steps.
    n = 64
    env = make(n, seed=4)
    env.reset()
    s = env.get_state()
    s["mask"][0] = True
    s["mask"][1] = False
    x, y = s["pose"][0, 0], s["pose"][0, 1]
    s["segments"][0, -1] = torch.stack(
        (x - 1, y - 1, x + 1, y + 1)
    )  # the last slot, under the truck
    first = s["mask"].float().argmax(-1)
    mid = s["segments"][torch.arange(n), first].view(n, 2, 2).mean(-2)
    s["pose"][2::2, :2] = mid[2::2]
    td = env.set_state(s)
    gen = torch.Generator().manual_seed(0)
    collided = resets = 0
    for _ in range(8):
        state = env.get_state()
        flat = {k: state[k] for k in env._state_keys}
        flat["params"] = {k: state["params", k] for k in env._param_keys}
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        _, want = env.task.transition(action, flat, env._difficulty)
        out, td = env.step_and_maybe_reset(td.set("action", action))
        for k, v in want.items():
            assert torch.equal(out["next", k], v), k
        if _ == 0:
            assert want["collision"][0]  # row 0: its last slot lies under the truck
        collided += int(out["next", "collision"].sum())
        resets += int(out["next", "done"].sum())
    assert collided >= n // 4 and resets >= collided  # collisions and partial resets happened


@pytest.mark.slow
def test_compiled_env_matches_eager_across_partial_resets():
    # env.compile runs the step, the full reset's observation and a partial reset's observation
    # (batch size symbolic) through torch.compile; the independent answer is the eager env on
    # the same seed and actions. Short episodes force partial resets of varying counts (1 and
    # more trucks) on most steps. Fused float arithmetic may differ in the last bits.
    n, cfg = 32, {"max_steps": 6}
    eager, compiled = make(n, seed=7, **cfg), make(n, seed=7, compile=True, **cfg)
    td_e, td_c = eager.reset(), compiled.reset()
    gen = torch.Generator().manual_seed(0)
    counts = set()
    for _ in range(24):
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        out_e, td_e = eager.step_and_maybe_reset(td_e.set("action", action))
        out_c, td_c = compiled.step_and_maybe_reset(td_c.set("action", action))
        counts.add(int(out_e["next", "done"].sum()))
        for key in ("observation", "lidar", "reward", "done"):
            torch.testing.assert_close(out_c["next", key], out_e["next", key], atol=1e-4, rtol=1e-4)
        for key in ("observation", "lidar", "done", "step_count"):  # reset rows: the new starts
            torch.testing.assert_close(td_c[key], td_e[key], atol=1e-4, rtol=1e-4)
    assert len(counts - {0}) >= 2  # partial resets of at least two different sizes
