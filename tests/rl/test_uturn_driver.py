"""The scripted turnaround (truckrl/tasks/uturn/expert.py): it turns a truck round on a fixed
scene in two control modes, its set-point tracking is the hand-computed action, and its
demonstrations are real, repeatable, successful episodes."""

import math

import pytest
import torch
from tensordict import TensorDict

from truckrl.config.fields import build
from truckrl.planning import held_out_states
from truckrl.planning.controller import setpoint_action
from truckrl.sim.control import ControlConfig
from truckrl.tasks import EnvConfig
from truckrl.tasks.uturn.expert import (
    GRID,
    TurnaroundDriver,
    drive,
    driven_demos,
)
from truckrl.tasks.uturn.scene import generate_uturn_scenes
from truckrl.tasks.uturn.task import UTurnTask

#: A mid-range truck (16 m long, R = 5.3 m) and a scene of the default ranges' middle; right
#: branch, so the mirroring is exercised.
FIXED_TRUCK = dict(
    wheelbase=3.8,
    front_overhang=1.4,
    rear_overhang=0.9,
    tractor_width=2.45,
    kingpin_offset=0.0,
    cab_gap=0.95,
    trailer_wheelbase=8.5,
    trailer_front_overhang=1.25,
    trailer_rear_overhang=2.25,
    trailer_width=2.5,
    max_steer=0.62,
    max_articulation=1.3,
    max_speed=8.0,
    max_accel=2.25,
    max_jerk=3.5,
    max_steer_rate=0.6,
    max_steer_accel=2.0,
    max_reverse_speed=2.25,
)
FIXED_SCENE = dict(
    road_width=(10.5, 10.5),
    branch_width=(11.0, 11.0),
    branch_depth_factor=(1.3, 1.3),
    branch_angle=(math.pi / 2, math.pi / 2),
    left_prob=0.0,
    mouth_chamfer=(6.0, 6.0),
    dead_end_prob=0.0,
    start_gap=(10.0, 10.0),
    goal_back=(5.0, 5.0),
    shoulder_gap=(0.5, 0.5),
)


def core_drive(task, cfg, state, driver, difficulty, steps):
    """Run ``driver`` through the task core (no env, no LiDAR); returns (success, failed, min
    speed)."""
    s = {k: state[k] for k in state.keys() if k not in ("params", "route")}
    s["params"] = {k: state["params", k] for k in state["params"].keys()}
    n = state.batch_size[0]
    diff = torch.full((n,), float(difficulty))
    success = torch.zeros(n, dtype=torch.bool)
    failed = torch.zeros(n, dtype=torch.bool)
    v_min = torch.zeros(n)
    for _ in range(steps):
        action = setpoint_action(*driver.setpoints(s), s, cfg.control, cfg.dt)
        s = {**s, **task.step(s, action)}
        out = task.outcome(s, diff)
        failed |= (out["collision"] | out["jackknife"]) & ~success
        success |= out["success"] & ~failed
        v_min = torch.minimum(v_min, s["speed"])
    return success, failed, v_min


@pytest.mark.parametrize("control", ["speed_angle", "accel_rate"])
def test_scripted_turnaround_reaches_the_goal(control):
    """Forward past the branch, reverse the trailer into it, forward out: the goal region at
    difficulty 2 (7.5 m, 15 deg), without collision or jack-knife, on one fixed scene, with
    set-points (speed / angle) and with the tracked rates of the default control (accel /
    rate)."""
    lon, lat = control.split("_")
    cfg = EnvConfig(
        task={"name": "uturn", "scene": FIXED_SCENE},
        control={"longitudinal": lon, "lateral": lat},
    )
    task = UTurnTask(cfg)
    params = {k: torch.tensor([v]) for k, v in FIXED_TRUCK.items()}
    g = torch.Generator().manual_seed(1)
    sc = generate_uturn_scenes(cfg.task.scene, params, g)
    state = task.initial_state(
        params, {k: getattr(sc, k) for k in ("start", "goal", "segments", "mask", "kind")}, "cpu"
    )
    state["route"] = TensorDict(sc.info, batch_size=[1])
    assert sc.info["branch_side"].item() == -1.0
    driver = TurnaroundDriver(
        state, lane_y=0.0, arc_radius=13.0, pass_margin=3.0, exit_look=14.0, exit_shift=2.0
    )
    success, failed, v_min = core_drive(task, cfg, state, driver, difficulty=2.0, steps=1000)
    assert success.all() and not failed.any()
    assert (v_min < -1.0).all(), "the truck reversed"
    assert (driver.phase == 3).all(), "it drove out forwards and stopped at the goal"


def test_setpoint_action_by_mode():
    """Hand-computed actions: speed maps [-max_reverse_speed, max_speed] onto [-1, 1]; angle
    divides by max_steer; accel and rate reach the set-point in one step of dt, clamped."""
    p = {"max_reverse_speed": torch.tensor([2.0, 2.0]), "max_speed": torch.tensor([8.0, 8.0]),
         "max_steer": torch.tensor([0.5, 0.5]), "max_accel": torch.tensor([2.0, 2.0]),
         "max_steer_rate": torch.tensor([0.5, 0.5])}  # fmt: skip
    s = {"params": p, "speed": torch.tensor([1.0, 1.0]), "steer": torch.tensor([0.1, 0.1])}
    speed, steer = torch.tensor([3.0, -2.0]), torch.tensor([0.2, -0.5])
    a = setpoint_action(speed, steer, s, ControlConfig("speed", "angle"), 0.1)
    assert torch.allclose(a, torch.tensor([[0.0, 0.4], [-1.0, -1.0]]))
    a = setpoint_action(speed, steer, s, ControlConfig("accel", "rate"), 0.1)
    # (3 - 1) / 0.1 = 20 m/s^2 -> clamped 1; (0.2 - 0.1) / 0.1 = 1 rad/s -> 1; second truck -1
    assert torch.allclose(a, torch.tensor([[1.0, 1.0], [-1.0, -1.0]]))
    a = setpoint_action(torch.tensor([1.1]), torch.tensor([0.12]), {
        "params": {k: v[:1] for k, v in p.items()}, "speed": torch.tensor([1.0]),
        "steer": torch.tensor([0.1])}, ControlConfig("accel", "rate"), 0.1)  # fmt: skip
    assert torch.allclose(a, torch.tensor([[0.5, 0.4]]))  # 1 / 2 and 0.2 / 0.5
    with pytest.raises(ValueError, match="control.longitudinal"):
        setpoint_action(speed, steer, s, ControlConfig("jerk", "rate"), 0.1)
    with pytest.raises(ValueError, match="control.lateral"):
        setpoint_action(speed, steer, s, ControlConfig("accel", "accel"), 0.1)


@pytest.fixture(scope="module")
def demo_setup():
    cfg = build(EnvConfig, {"task": {"name": "uturn"}, "max_steps": 1000}, "env")
    states = held_out_states(cfg, 8, 99991, difficulty=4.0)
    # GRID[152] turns scenes 0 and 3 of these 8, GRID[264] those and 2 and 7: a scene's first
    # successful setting differs between scenes, so a wrong pairing or pick shows
    settings = [GRID[i] for i in (152, 264)]
    samples, solved = driven_demos(cfg, states, 2.0, settings)
    return cfg, states, settings, samples, solved


def test_driven_demos_are_successful_repeatable_episodes(demo_setup):
    """A scene counts as solved when any setting solves it; the samples are those scenes'
    episodes driven with their first successful setting, step for step (the same again when
    driven again), and whole turnarounds (hundreds of steps each)."""
    cfg, states, settings, samples, solved = demo_setup
    assert solved.any(), "the driver solves some of 8 default scenes"
    grid = torch.tensor(settings)
    k = len(settings)
    # every (setting, scene) pair in one batch, setting-major (driven_demos goes scene-major)
    ok, _ = drive(cfg, states[torch.arange(8).repeat(k)], grid.repeat_interleave(8, 0), 2.0, False)
    per = ok.view(k, 8).T
    assert torch.equal(per.any(1), solved)
    idx = solved.nonzero().squeeze(-1)
    first = grid[per[idx].float().argmax(1)]
    ok, again = drive(cfg, states[idx], first, 2.0)
    assert ok.all()
    for key in ("observation", "lidar", "action"):
        assert torch.equal(samples[key], again[key]), key
    assert samples["lidar"].shape[-1] == cfg.lidar.num_beams
    assert samples.batch_size[0] > 300 * idx.numel(), "whole turnarounds, not fragments"
    assert (samples["action"].abs() <= 1.0).all()
    assert (samples["action"][:, 0] < 0).any(), "someone brakes or reverses"


def test_driver_demos_refuse_a_task_without_a_scripted_demonstrator():
    """``demos.source=driver`` asks the task folder's expert for ``demonstrations``: the
    intersection's expert has none, the test-only reach folder no expert at all."""
    from types import SimpleNamespace

    from truckrl.config.fields import ConfigError
    from truckrl.rl.imitation import bootstrap

    dc = SimpleNamespace(source="driver", episodes=2, seed=1, difficulty=2.0)
    for name in ("intersection", "tests.tasks.reach"):
        cfg = build(EnvConfig, {"task": {"name": name}}, "env")
        with pytest.raises(ConfigError, match="demos.source = driver needs a demonstrations") as e:
            bootstrap(None, cfg, dc)
        assert name in str(e.value) and len(str(e.value).splitlines()) == 1


def test_driver_demos_come_from_the_task_folders_expert(monkeypatch):
    """``bootstrap`` with ``source=driver`` calls the uturn expert's ``demonstrations`` with the
    run's env config and ``demos`` settings (a stub here that solves nothing)."""
    from types import SimpleNamespace

    import truckrl.tasks.uturn.expert as expert
    from truckrl.rl.imitation import bootstrap

    calls = []

    def stub(env_cfg, episodes, seed, difficulty):
        calls.append((env_cfg.task.name, episodes, seed, difficulty))
        return torch.zeros(episodes, dtype=torch.bool), TensorDict({}, batch_size=[0])

    monkeypatch.setattr(expert, "demonstrations", stub)
    cfg = build(EnvConfig, {"task": {"name": "uturn"}}, "env")
    dc = SimpleNamespace(source="driver", episodes=3, seed=7, difficulty=2.0)
    with pytest.raises(ValueError, match="the driver solved none of 3 scenes"):
        bootstrap(None, cfg, dc)
    assert calls == [("uturn", 3, 7, 2.0)]


def test_expert_demonstrations_drive_the_held_out_road_starts(monkeypatch):
    """The uturn expert's ``demonstrations`` drives the held-out starts of the run's seed drawn
    at the top of the start curriculum (road starts) with :func:`driven_demos`."""
    import truckrl.tasks.uturn.expert as expert
    from truckrl.tasks import MAX_DIFFICULTY

    seen = {}

    def fake(env_cfg, states, difficulty):
        seen["states"], seen["difficulty"] = states, difficulty
        return TensorDict({}, batch_size=[0]), torch.zeros(states.batch_size[0], dtype=torch.bool)

    monkeypatch.setattr(expert, "driven_demos", fake)
    cfg = build(EnvConfig, {"task": {"name": "uturn"}}, "env")
    solved, samples = expert.demonstrations(cfg, 4, 5, 2.0)
    assert solved.shape == (4,) and samples.batch_size[0] == 0 and seen["difficulty"] == 2.0
    road = held_out_states(cfg, 4, 5, difficulty=MAX_DIFFICULTY)
    assert torch.equal(seen["states"]["pose"], road["pose"])


@pytest.mark.slow
def test_scripted_driver_solves_most_default_scenes():
    """A lower bound on solvability: 200 default scenes (seed 11), each tried with the 288
    driver settings of :data:`GRID`; a scene counts as solvable when any setting reaches the
    goal at difficulty 2 without collision or jack-knife (default control, accel / rate)."""
    cfg = build(EnvConfig, {"task": {"name": "uturn"}, "max_steps": 1000}, "env")
    n, k = 200, len(GRID)
    states = held_out_states(cfg, n, 11, difficulty=4.0)
    ok, _ = drive(cfg, states[torch.arange(n).repeat_interleave(k)],
                  torch.tensor(GRID).repeat(n, 1), 2.0, record=False)  # fmt: skip
    solved = ok.view(n, k).any(1).float().mean().item()
    print(f"scripted driver: {solved:.3f} of {n} default scenes solved at difficulty 2")
    assert solved >= 0.65
