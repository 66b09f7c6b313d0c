"""The CEM planner baseline: solves an easy scene (confirmed by replay), reports a blocked one
unsolved, returns ``evaluate_policy``'s result keys, and its CLI rejects bad options."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from tests.conftest import run_cli
from truckrl import plan as plan_cli
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.planning import (
    Planner,
    PlannerConfig,
    knot_matrix,
    plan_episodes,
    plan_states,
    replay,
)
from truckrl.sim.vehicle import VehicleConfig
from truckrl.tasks import EnvConfig, make_task

#: Eager (no compile), tiny budget: one scene, 48 candidates.
FAST = {"samples": 48, "iterations": 3, "scenes_per_batch": 1, "compile": False}
ENV = EnvConfig(max_steps=120)


def straight_scene(wall: bool = False):
    """One mid-range truck on a 12 m straight road along +x, goal 30 m ahead in its lane; with
    ``wall``, a segment across the whole road 15 m ahead."""
    bounds = VehicleConfig().bounds()
    params = {k: torch.tensor([0.5 * (lo + hi)]) for k, (lo, hi) in bounds.items()}
    segments = torch.tensor(
        [[[-100.0, -6.0, 100.0, -6.0], [-100.0, 6.0, 100.0, 6.0], [15.0, -6.0, 15.0, 6.0]]]
    )
    mask = torch.tensor([[True, True, wall]])
    scene = {
        "start": torch.tensor([[0.0, -3.0, 0.0]]),
        "goal": torch.tensor([[30.0, -3.0, 0.0]]),
        "segments": segments * mask[..., None],
        "mask": mask,
        "kind": torch.zeros(1, 3, dtype=torch.int8),
    }
    return make_task(ENV).initial_state(params, scene, torch.device("cpu"))


def test_knot_matrix_interpolates_linearly():
    w = knot_matrix(5, 3)
    assert torch.allclose(w.sum(-1), torch.ones(5))
    assert torch.allclose(
        w @ torch.tensor([0.0, 1.0, 4.0]), torch.tensor([0.0, 0.5, 1.0, 2.5, 4.0])
    )
    assert torch.equal(knot_matrix(4, 1), torch.ones(4, 1))


def test_solves_easy_scene_and_replay_reproduces_it():
    state = straight_scene()
    res, (tol_m, tol_deg), errors = plan_states(ENV, state, 2.0, FAST)
    assert tol_m == pytest.approx(7.5) and tol_deg == pytest.approx(15.0)
    assert bool(res["success"][0]) and bool(res["planned_success"][0])
    assert not res["replay_mismatch"][0]
    n = int(res["length"][0])
    assert 1 <= n < ENV.max_steps and res["pos_error"][0] <= tol_m
    # the reported action sequence, replayed again, gives the same outcome and final errors
    again = replay(ENV, state, res["actions"], 2.0)
    assert bool(again["success"][0]) and int(again["length"][0]) == n
    for q in errors:
        assert again[q.key][0] == pytest.approx(float(res[q.key][0]), abs=1e-5)
    assert (res["actions"][0, n:] == 0).all() and res["actions"].abs().max() <= 1.0


def test_wall_across_the_road_is_unsolved():
    res, _, _ = plan_states(ENV, straight_scene(wall=True), 2.0, {**FAST, "iterations": 2})
    assert not bool(res["success"][0]) and not bool(res["planned_success"][0])
    assert bool(res["collision"][0] | res["truncated"][0])
    assert res["best_ratio"][0] > 1.0  # never within the tolerances


def test_result_keys_match_evaluate_policy():
    env = EnvConfig(max_steps=6)
    actor = TensorDictModule(
        lambda obs: torch.zeros(obs.shape[0], 2), in_keys=["observation"], out_keys=["action"]
    )
    ev, ev_tol, ev_err = evaluate_policy(actor, env, 3.0, episodes=3, seed=11)
    cfg = {**FAST, "samples": 4, "iterations": 1}
    res, tol, err = plan_episodes(env, 3.0, episodes=3, seed=11, config=cfg, indices=[0, 2])
    assert tol == pytest.approx(ev_tol) and err == ev_err
    for k, v in ev.items():
        if k == "motion":  # evaluate's per-step record [E, T, 4], not a per-episode value
            continue
        assert k in res and res[k].dtype == v.dtype and res[k].shape == (2,), k
    assert res["scene_index"].tolist() == [0, 2]
    assert set(res) >= {"route", "turn_angle", "start_road_width", "goal_distance"}
    assert torch.equal(res["route"], ev["route"][[0, 2]])
    assert "trailer_wheelbase" in res["params"] and res["actions"].shape == (2, 6, 2)


def test_bad_planner_config_is_rejected():
    from truckrl.config.fields import ConfigError

    with pytest.raises(ConfigError, match="planner.samples"):
        PlannerConfig(samples=1)
    with pytest.raises(ConfigError, match="steer_axis"):
        PlannerConfig(steer_axis="space")
    with pytest.raises(ConfigError, match="pursuit"):
        PlannerConfig(pursuit="trailer")  # the fixed-weight laws are gone: blend plans the weight


def test_pursuit_none_leaves_the_knots_to_steer():
    # switch distance inf: the pursuit never takes over; the straight scene is still solved
    planner = Planner(ENV, {**FAST, "pursuit": "none"})
    x = torch.zeros(3, planner.config.num_params)
    params = {"max_speed": torch.full((3,), 8.0)}
    assert torch.isinf(planner._extras(x, params, torch.full((3,), 50.0))[:, 0]).all()
    blend = Planner(ENV, FAST)._extras(x, params, torch.full((3,), 50.0))
    assert torch.equal(blend[:, 0], torch.full((3,), 25.0))  # halfway: x = 0 maps to 0.5
    res, _, _ = plan_states(ENV, straight_scene(), 2.0, {**FAST, "pursuit": "none"})
    assert bool(res["success"][0])


def _arc_prior(start, goal, last):
    """The arc prior ``[N, 3]`` of mid-range trucks at ``start`` / ``goal`` poses ``[N, 3]`` for
    candidates whose last parameter is ``last [N]``, and those trucks' parameters."""
    planner = Planner(ENV, {**FAST, "steer_prior": "arc"})
    bounds = VehicleConfig().bounds()
    n = start.shape[0]
    params = {k: torch.full((n,), 0.5 * (lo + hi)) for k, (lo, hi) in bounds.items()}
    pose = torch.cat((start, torch.zeros(n, 1)), -1)
    x = torch.zeros(n, planner.config.num_params)
    x[:, -1] = last
    return planner._arc({"pose": pose, "goal": goal, "params": params}, x), params


def test_arc_prior_is_the_circle_tangent_to_both_lanes():
    # start at the origin heading +x; goal lanes: x = 20 heading +y (a 90 deg left turn, corner
    # (20, 0): 20 m to the corner, 30 m after it), x = 20 heading -y (a right turn), y = -3
    # heading +x (parallel lanes: no corner)
    start = torch.zeros(4, 3)
    goal = torch.tensor(
        [
            [20.0, 30.0, math.pi / 2],
            [20.0, 30.0, math.pi / 2],
            [20.0, -30.0, -math.pi / 2],
            [40.0, -3.0, 0.0],
        ]
    )
    arc, p = _arc_prior(start, goal, torch.tensor([1.0, -1.0, -1.0, 0.0]))
    wheelbase, steer_max, l_ka = (
        float(p[k][0]) for k in ("wheelbase", "max_steer", "trailer_wheelbase")
    )
    r_lo = max(wheelbase / math.tan(steer_max), l_ka)
    # largest circle: R = min(20, 30) / tan(45 deg) = 20, tangent to the start lane at the start
    assert arc[0].tolist() == pytest.approx([0.0, 20.0 * math.pi / 2, math.atan(wheelbase / 20.0)])
    # tightest: R_lo, entered R_lo before the corner
    left = [20.0 - r_lo, 20.0 - r_lo + r_lo * math.pi / 2, math.atan(wheelbase / r_lo)]
    assert arc[1].tolist() == pytest.approx(left, rel=1e-5)
    assert arc[2].tolist() == pytest.approx([left[0], left[1], -left[2]], rel=1e-5)  # right turn
    assert arc[3, 2] == 0.0  # parallel lanes: no prior


def test_arc_prior_refuses_a_task_that_reverses():
    from truckrl.config.fields import ConfigError

    for prior in ("arc", "alternate"):
        with pytest.raises(ConfigError, match="steer_prior"):
            Planner(EnvConfig(task={"name": "dock"}), {**FAST, "steer_prior": prior})
    with pytest.raises(ConfigError, match="steer_prior"):
        PlannerConfig(steer_prior="spiral")


@pytest.mark.parametrize("prior", ["arc", "alternate"])
def test_arc_prior_solves_a_straight_scene(prior):
    # parallel lanes: the prior is 0, and the knots alone solve it
    res, _, _ = plan_states(ENV, straight_scene(), 2.0, {**FAST, "steer_prior": prior})
    assert bool(res["success"][0]) and not res["replay_mismatch"][0]


def test_alternate_attempts_take_the_arc_first_then_the_knots_alone():
    # a walled-off scene is never solved, so it uses all its attempts; the rollouts see which
    planner = Planner(ENV, {**FAST, "steer_prior": "alternate", "attempts": 3, "iterations": 1})
    seen: list[list[bool]] = []
    rollout = planner.rollout

    def spy(start, x, difficulty, arc_on=None):
        seen.append(arc_on.tolist())
        return rollout(start, x, difficulty, arc_on)

    planner.rollout = spy
    out = planner.plan(straight_scene(wall=True), 2.0)
    assert out["attempts"].tolist() == [3]
    assert [rows[0] for rows in seen] == [True, False, True]
    assert all(len(set(rows)) == 1 for rows in seen)  # one attempt per batch here


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["episodes=0"], "episodes"),
        (["planner.samples=1"], "planner.samples"),
        (["env.max_steps=-3"], "env.max_steps"),
        (["nonsense"], "KEY=VALUE"),
        (["seed=-1"], "seed"),
    ],
)
def test_bad_options_exit_2_with_one_line(args, needle, capsys):
    try:
        code = plan_cli.main(args)  # a bad value found while running returns 2
    except SystemExit as exit_:  # one found while parsing exits 2
        code = exit_.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and needle in err and len(err.splitlines()) == 1


@pytest.mark.e2e
def test_cli_bad_options_exit_2_with_one_line():
    proc = run_cli("plan", "difficulty=lots", timeout=60)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert err.startswith("error:") and "difficulty" in err and "Traceback" not in err
    assert len(err.splitlines()) == 1


# ---------------------------------------------------------------------------------- reversing
REVERSE = {"name": "tests.tasks.reverse_reach_task"}


def _backed_up(env: EnvConfig, res) -> torch.Tensor:
    """Replay the reported plans; per scene the lowest speed [m/s] and the final displacement
    along the start heading [m] (negative = behind the start)."""
    from truckrl.env import TruckEnv
    from truckrl.planning import held_out_states

    states = held_out_states(env, int(res["scene_index"].numel()), 0, difficulty=4.0)
    n = states.batch_size[0]
    sim = TruckEnv(num_envs=n, config=env, seed=0)
    sim.set_difficulty(4.0)
    sim.set_state(states)
    lowest, end = torch.zeros(n), states["pose"][:, :2].clone()
    for t in range(int(res["length"].max())):
        live = t < res["length"]
        a = torch.where(live[:, None], res["actions"][:, t], torch.zeros(n, 2))
        sim.step(TensorDict({"action": a}, batch_size=[n]))
        s = sim.get_state()
        lowest = torch.where(live, torch.minimum(lowest, s["speed"]), lowest)
        end = torch.where(live[:, None], s["pose"][:, :2], end)
        assert (s["speed"] >= -s["params", "max_reverse_speed"] - 1e-5).all()
    th = states["pose"][:, 2]
    moved = end - states["pose"][:, :2]
    return lowest, moved[:, 0] * th.cos() + moved[:, 1] * th.sin()


def test_reverses_straight_back_to_a_goal_behind():
    # goal 15-25 m straight behind, same heading; difficulty 4: 1.875 m, 3.75 deg
    env = EnvConfig(max_steps=160, task=REVERSE)
    cfg = {**FAST, "samples": 32, "iterations": 4, "attempts": 2, "scenes_per_batch": 10}
    res, (tol_m, _), _ = plan_episodes(env, 4.0, episodes=10, seed=0, config=cfg)
    assert tol_m == pytest.approx(1.875)
    assert int(res["success"].sum()) >= 9, res["success"]
    assert not res["replay_mismatch"].any()
    lowest, along = _backed_up(env, res)
    ok = res["success"]
    assert (lowest[ok] < -0.5).all() and (along[ok] < -13.0).all()


@pytest.mark.parametrize(
    ("episodes", "need"), [(6, 5), pytest.param(20, 18, marks=pytest.mark.slow)]
)
def test_reverses_to_a_goal_behind_and_sideways(episodes, need):
    # 3-5 m sideways: more than the 1.875 m tolerance, so backing straight does not succeed
    env = EnvConfig(max_steps=300, task={**REVERSE, "offset": [3.0, 5.0]})
    cfg = {**FAST, "samples": 48, "iterations": 6, "attempts": 2, "scenes_per_batch": episodes}
    res, _, _ = plan_episodes(env, 4.0, episodes=episodes, seed=0, config=cfg)
    assert int(res["success"].sum()) >= need, res["success"]
    lowest, along = _backed_up(env, res)
    ok = res["success"]
    assert (lowest[ok] < -0.5).all() and (along[ok] < -10.0).all()


def test_planned_scenes_are_evaluate_policys_at_the_difficulty_for_a_start_curriculum():
    # the dock task moves its starts by the difficulty (Task.on_reset): the planner must plan
    # the scenes evaluate_policy scores at that difficulty, not the difficulty-0 ones
    env = EnvConfig(max_steps=4, task={"name": "dock"})
    actor = TensorDictModule(
        lambda obs: torch.zeros(obs.shape[0], 2), in_keys=["observation"], out_keys=["action"]
    )
    cfg = {**FAST, "samples": 4, "iterations": 1, "attempts": 1, "scenes_per_batch": 6}
    kinds = []
    for d in (0.0, 8.0):
        ev, _, _ = evaluate_policy(actor, env, d, episodes=6, seed=3)
        res, _, _ = plan_episodes(env, d, episodes=6, seed=3, config=cfg)
        for k in res["scene_info_keys"]:
            assert torch.equal(res[k], ev[k]), (d, k)
        kinds.append(res["start_kind"])
    assert not torch.equal(kinds[0], kinds[1])  # the difficulty did move starts


# ------------------------------------------------------------ a policy beside the planner
def _steering_actor():
    """A closed-loop scripted policy: half throttle, steering against the first observation
    entry, so its actions depend on the state and an open-loop replay is a real check."""
    return TensorDictModule(
        lambda obs: torch.stack(
            [torch.full_like(obs[:, 0], 0.5), (-0.3 * obs[:, 0]).clamp(-1, 1)], -1
        ),
        in_keys=["observation"],
        out_keys=["action"],
    )


def test_policy_actions_replayed_open_loop_reproduce_the_closed_loop_episodes():
    from truckrl.evaluation.rollout import policy_actions
    from truckrl.planning import held_out_states

    env, actor = EnvConfig(max_steps=40), _steering_actor()
    closed, _, _ = evaluate_policy(actor, env, 2.0, episodes=6, seed=5)
    states = held_out_states(env, 6, 5, difficulty=2.0)
    acts = policy_actions(actor, env, states, 2.0)
    assert acts.shape == (6, 40, 2)
    for i, n in enumerate(closed["length"].long().tolist()):
        assert (acts[i, :n, 0] == 0.5).all() and (acts[i, n:] == 0).all()
    opened = replay(env, states, acts, 2.0)
    for k in ("success", "collision", "jackknife", "truncated", "length", "pos_error"):
        assert torch.equal(opened[k], closed[k]), k


def test_an_extra_sequence_solves_a_scene_the_planner_misses():
    solution = plan_states(ENV, straight_scene(), 2.0, FAST)[0]
    assert bool(solution["success"][0])
    starved = {**FAST, "samples": 2, "iterations": 1, "attempts": 1}
    states = torch.cat([straight_scene(), straight_scene(wall=True)])
    extra = torch.stack([solution["actions"][0], torch.zeros_like(solution["actions"][0])])
    res, _, _ = plan_states(ENV, states, 2.0, starved, extra=extra)
    planner, policy = res["by_source"]["planner"], res["by_source"]["extra"]
    assert not planner["success"].any()  # the precondition: 2 candidates do not find the goal
    assert policy["success"].tolist() == [True, False]
    assert res["success"].tolist() == [True, False]
    assert res["solved_by_extra"].tolist() == [True, False]
    assert torch.equal(res["actions"][0], solution["actions"][0])
    assert res["length"][0] == solution["length"][0]
    with pytest.raises(ValueError, match=r"extra must be \[2, T, 2\]"):
        plan_states(ENV, states, 2.0, starved, extra=extra[:1])


def test_cli_policy_reports_planner_policy_and_either(tmp_path, capsys):
    import dataclasses
    import json

    from truckrl.planning import held_out_states
    from truckrl.rl.policy import load_policy

    out = tmp_path / "plan.json"
    args = ["checkpoint=pretrained", "episodes=3", "seed=7", "planner.samples=4"]
    args += ["planner.iterations=1", "planner.attempts=1", "planner.compile=false", "quiet=true"]
    args += ["difficulty=0"]  # 30 m: the planner and the policy reach some goals within 30 steps
    assert plan_cli.main([*args, "env.max_steps=30", f"out={out}"]) == 0
    s = json.loads(out.read_text())
    assert s["policy"]["checkpoint"].endswith("pretrained.pt")  # the task folder's policy
    eps = s["per_episode"]
    # the planner alone solves scene 1 of this seed (planned, then confirmed by its replay)
    assert [e["scene_index"] for e in eps if e["solved_by"] == "planner"] == [1]
    assert eps[1]["success"] and eps[1]["planned_success"] and not eps[0]["success"]
    # the written action sequences, replayed from the same scenes, give the written outcomes
    loaded = load_policy("pretrained")
    env = dataclasses.replace(loaded.env_config, max_steps=30)
    states = held_out_states(env, 3, 7, difficulty=0.0)
    actions = torch.zeros(3, 30, 2)
    for i, e in enumerate(eps):
        actions[i, : len(e["actions"])] = torch.tensor(e["actions"])
    again = replay(env, states, actions, 0.0)
    assert again["success"].tolist() == [e["success"] for e in eps]
    assert again["length"].tolist() == [e["length"] for e in eps]
    # the policy alone, scored by evaluate_policy's closed loop on the same scenes
    ev, _, _ = evaluate_policy(loaded.actor, env, 0.0, episodes=3, seed=7)
    assert s["policy"]["success_rate"] == pytest.approx(ev["success"].float().mean().item())
    # a scene the planner solves reports "planner"; one only the policy solves, "policy"
    for e, policy_ok in zip(eps, ev["success"].tolist(), strict=True):
        assert (e["solved_by"] == "policy") == (policy_ok and e["solved_by"] != "planner")
    solved_by = [e["solved_by"] for e in eps]
    assert s["planner_alone"]["success_rate"] == pytest.approx(solved_by.count("planner") / 3)
    assert s["success_rate"] == pytest.approx((3 - solved_by.count(None)) / 3)
    assert "planner policy either" in " ".join(capsys.readouterr().out.split())
    assert plan_cli.main([f"checkpoint={tmp_path / 'none.pt'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and len(err.splitlines()) == 1


def test_cli_skip_solved_plans_only_the_policys_failures(tmp_path, capsys):
    import dataclasses
    import json

    from truckrl.planning import held_out_states
    from truckrl.rl.policy import load_policy

    out = tmp_path / "plan.json"
    args = ["checkpoint=pretrained", "episodes=6", "seed=7", "planner.samples=4", "difficulty=0"]
    args += ["planner.iterations=1", "planner.attempts=1", "planner.compile=false", "quiet=true"]
    assert plan_cli.main([*args, "skip_solved=true", "env.max_steps=30", f"out={out}"]) == 0
    s = json.loads(out.read_text())
    eps = s["per_episode"]
    # the policy alone, by evaluate_policy's closed loop (not the plan's replay) on the same scenes
    loaded = load_policy("pretrained")
    env = dataclasses.replace(loaded.env_config, max_steps=30)
    ev, _, _ = evaluate_policy(loaded.actor, env, 0.0, episodes=6, seed=7)
    policy_ok = ev["success"].tolist()
    assert 0 < sum(policy_ok) < 6  # the precondition: the policy solves some scenes, not all
    # searched: exactly the scenes the policy fails; the others are never planned
    assert [e["searched"] for e in eps] == [not ok for ok in policy_ok]
    assert s["searched"] == s["planner_alone"]["scenes"] == 6 - sum(policy_ok)
    for e, ok in zip(eps, policy_ok, strict=True):
        if ok:
            assert e["solved_by"] == "policy" and e["iterations"] == 0
            assert not e["planned_success"]
        else:
            assert e["solved_by"] in ("planner", None) and e["iterations"] >= 1
    # the searched scenes' written sequences, replayed from the same scenes, give the written
    # outcomes; the others' are the policy's own (not written)
    assert ["actions" in e for e in eps] == [e["searched"] for e in eps]
    states = held_out_states(env, 6, 7, difficulty=0.0)
    actions = torch.zeros(6, 30, 2)
    for i, e in enumerate(eps):
        if e["searched"]:
            actions[i, : len(e["actions"])] = torch.tensor(e["actions"])
    again = replay(env, states, actions, 0.0)
    searched = [i for i, e in enumerate(eps) if e["searched"]]
    assert again["success"][searched].tolist() == [eps[i]["success"] for i in searched]
    # solvable = policy or planner over every scene; the policy's column covers every scene
    searched_ok = [e["success"] for e in eps if e["searched"]]
    assert s["success_rate"] == pytest.approx((sum(policy_ok) + sum(searched_ok)) / 6)
    assert s["policy"]["success_rate"] == pytest.approx(sum(policy_ok) / 6)
    assert s["planner_alone"]["success_rate"] == pytest.approx(sum(searched_ok) / len(searched_ok))
    assert "the planner searched only the" in capsys.readouterr().out
    with pytest.raises(SystemExit) as stop:  # before any work: no checkpoint to take failures of
        plan_cli.main(["skip_solved=true"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "skip_solved" in err and "checkpoint" in err and len(err.splitlines()) == 1
