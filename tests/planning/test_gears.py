"""The gear-sequence planner (truckrl/planning/gears.py, ``planner.search=gears``): it solves a
held-out turnaround that the knot planner does not, every leg drives in its own gear in the
replay, its path helpers match hand-computed points, and bad input is one line and exit 2."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from truckrl.config.fields import ConfigError
from truckrl.env import TruckEnv
from truckrl.planning import held_out_states, plan_states
from truckrl.planning.gears import (
    GearPlanner,
    gear_values,
    path_lengths,
    path_point,
    piecewise,
    piecewise_inverse,
)

#: Held-out uturn scenes (``truckrl eval``'s seed) at difficulty 2 (7.5 m, 15 deg).
UTURN = {"task": {"name": "uturn"}, "max_steps": 1000}
DIFFICULTY = 2.0
#: Eager CEM, one scene.
BUDGET = {"samples": 64, "iterations": 8, "attempts": 2, "scenes_per_batch": 1, "compile": False}
#: Dock at its final tolerance (0.15 m, 0.1 rad: experiment=dock's env at difficulty 7).
DOCK = {"task": {"name": "dock"}, "max_steps": 400,
        "tolerance": {"position": 19.2, "heading_deg": 180.0}}  # fmt: skip


@pytest.mark.slow
def test_gears_solve_a_turnaround_the_knot_planner_does_not():
    """Success is the replay's: the plan's actions through a fresh TruckEnv (plan_states); the
    knot planner with the same budget does not find the forward-reverse-forward sequence."""
    torch.set_num_threads(1)
    states = held_out_states(UTURN, 1, 12345, difficulty=4.0)  # from d = 4 on: the road start
    gears, _, _ = plan_states(UTURN, states, DIFFICULTY, {**BUDGET, "search": "gears"})
    assert bool(gears["success"][0]) and not bool(gears["replay_mismatch"][0])
    knots, _, _ = plan_states(UTURN, states, DIFFICULTY, {**BUDGET, "search": "knots"})
    assert not bool(knots["success"][0])


def test_every_leg_drives_in_its_gear():
    """The mean plan's actions on a dock scene replayed step by step through a TruckEnv: the
    speed while each leg's action is applied has that leg's sign (up to the switch speed at a
    gear change), and the plan drives forwards, then backwards."""
    torch.set_num_threads(1)
    states = held_out_states(DOCK, 2, 12345, difficulty=7.0)[1:]  # scene 1: it reverses
    planner = GearPlanner(DOCK, {"search": "gears", "compile": False})
    x = torch.zeros(1, planner.num_params)
    acc, actions = planner.rollout(states, x, 7.0)
    legs = planner.legs(states, x)
    env = TruckEnv(num_envs=1, config=planner.env_cfg, seed=0)
    env.set_difficulty(7.0)
    env.set_state(states)
    speeds = []
    for t in range(int(acc["length"][0])):
        nxt = env.step(TensorDict({"action": actions[t]}, batch_size=[1]))["next"]
        speeds.append(float(env.get_state()["speed"][0]))
        if bool(nxt["done"].any()):
            break
    env.close()
    leg = acc["leg_trace"][: len(speeds), 0]
    gear = legs["gear"][0, leg]
    speed = torch.tensor(speeds)
    assert (speed * gear >= -0.05).all()
    assert torch.unique_consecutive(gear).tolist()[:2] == [1.0, -1.0]
    assert (speed < -0.5).any() and (speed > 0.5).any()


def test_path_helpers_match_hand_computed_points():
    """An L-shaped polyline (0,0) -> (3,0) -> (3,4): arc lengths 0, 3, 7; the point at s = 5 is
    (3, 2); past the end it continues along the last segment; before the start along the
    first."""
    path = torch.tensor([[[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]]])
    cum, tan = path_lengths(path)
    assert cum.tolist() == [[0.0, 3.0, 7.0]]
    assert tan.tolist() == [[[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]]]
    pts = path_point(path.expand(3, 3, 2), cum.expand(3, 3), tan.expand(3, 3, 2),
                     torch.tensor([5.0, 9.0, -1.0]))  # fmt: skip
    assert pts.tolist() == [[3.0, 2.0], [3.0, 6.0], [-1.0, 0.0]]


def test_parameter_maps_pass_through_the_nominal_value():
    """piecewise: -1, 0, 1 -> lo, mid, hi, linear on each side; its inverse clamps."""
    u = torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0])
    assert piecewise(u, 2.0, 5.0, 10.0).tolist() == [2.0, 3.5, 5.0, 7.5, 10.0]
    assert piecewise_inverse(3.5, 2.0, 5.0, 10.0) == -0.5
    assert piecewise_inverse(20.0, 2.0, 5.0, 10.0) == 1.0
    assert gear_values(torch.zeros(1, 7))["heading_gain"].tolist() == [1.5]


def test_gears_refuse_a_forward_task_and_a_steering_prior():
    with pytest.raises(ConfigError, match="drives forward only") as e:
        GearPlanner({"task": {"name": "intersection"}}, {"search": "gears"})
    assert len(str(e.value).splitlines()) == 1
    with pytest.raises(ConfigError, match="steer_prior=none"):
        GearPlanner({"task": {"name": "dock"}}, {"search": "gears", "steer_prior": "arc"})


@pytest.mark.parametrize(
    ("arg", "says"),
    [
        ("planner.search=wheels", "planner.search"),
        ("planner.gears_init_std=0", "gears_init_std"),
        ("env.task.name=intersection", "drives forward only"),
    ],
)
def test_bad_gear_keys_exit_2_with_one_line(arg, says, capsys):
    from truckrl.plan import main

    args = ["episodes=1", "planner.search=gears", "env.task.name=dock", arg, "quiet=true"]
    try:
        code = main(args)
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and says in err and len(err.splitlines()) == 1
