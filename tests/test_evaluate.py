"""``python -m truckrl.evaluate``: deterministic, self-consistent results and clear errors."""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

import truckrl.evaluate as evaluate_module
import truckrl.evaluation.rollout as rollout_module
from tests.conftest import run_cli
from tests.reliability.harness import assert_one_line_error, run_main
from truckrl.config.fields import ConfigError
from truckrl.config.schemas import EvaluateConfig
from truckrl.evaluate import evaluate
from truckrl.evaluation.categories import summarize_by_category
from truckrl.evaluation.interval import wilson_interval
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.rl.checkpoint import CheckpointError
from truckrl.sim.vehicle import sample_vehicle_params
from truckrl.tasks.intersection.bins import TRAILER_DIM, episode_bins, scene_info
from truckrl.tasks.intersection.scene import ROUTE_KEYS, generate_scenes

MAX_STEPS = 40  # the tiny checkpoint's env.max_steps
SCENE_KEYS = (*ROUTE_KEYS, "trailer_length")


def generated_scenes(env_cfg, episodes: int, seed: int) -> dict:
    """The first ``episodes`` scenes of ``seed``, made without the env: the intersection task draws
    the vehicles, then the scenes, ``max(episodes, episode_pool)`` at a time."""
    g = torch.Generator().manual_seed(seed)
    n = max(episodes, env_cfg.episode_pool)
    params = sample_vehicle_params(env_cfg.vehicle, n, g)
    info = scene_info(generate_scenes(env_cfg.task.scene, params, g), params)
    return {k: v[:episodes] for k, v in info.items()}


def test_scene_info_lines_up_with_generated_scenes_and_results(tiny_checkpoint):
    _, _, tc = tiny_checkpoint
    cfg = dataclasses.replace(tc.env, max_steps=3)

    def stand_still(td):  # a plain callable policy: zero acceleration and steering rate
        return td.set("action", torch.zeros(td.batch_size[0], 2))

    res, _, _ = evaluate_policy(stand_still, cfg, 6.0, episodes=12, seed=21)  # 0.47 m: no success
    expected = generated_scenes(cfg, 12, 21)
    for k in SCENE_KEYS:
        torch.testing.assert_close(res[k], expected[k].to(res[k].dtype), msg=k)
    # the truck never moved: each episode's final error is its own scene's start-goal distance
    torch.testing.assert_close(res["pos_error"], expected["goal_distance"], atol=1e-4, rtol=0)
    assert res["truncated"].all() and (res["length"] == 3).all()


def test_category_rows_match_an_independent_recomputation(tiny_checkpoint):
    _, ac, tc = tiny_checkpoint
    res, _, _ = evaluate_policy(ac.actor, tc.env, 1.0, episodes=24, seed=5)
    rows = summarize_by_category(res, episode_bins(res))
    expected_bins = episode_bins(generated_scenes(tc.env, 24, 5))
    assert rows == summarize_by_category(res, expected_bins)
    assert rows[0]["dimension"] == "route"
    by_dim = {}
    for r in rows:
        by_dim[r["dimension"]] = by_dim.get(r["dimension"], 0) + r["count"]
    assert by_dim["route"] == by_dim[TRAILER_DIM] == 24
    for r in rows:  # each bin's success rate, counted by hand from the recomputed bins
        mask = expected_bins[r["dimension"]][r["bin"]]
        assert r["count"] == int(mask.sum())
        assert r["success_rate"] == pytest.approx(res["success"][mask].float().mean().item())


def test_outcomes_agree_with_final_errors(tiny_checkpoint):
    _, _, tc = tiny_checkpoint
    # a scripted closed-loop driver (half throttle, steering against the lateral goal offset):
    # it reaches some goals, hits some curbs and times out elsewhere (the untrained checkpoint
    # only times out)
    actor = TensorDictModule(
        lambda obs: torch.stack(
            [torch.full_like(obs[:, 0], 0.6), (-0.3 * obs[:, 1]).clamp(-1, 1)], -1
        ),
        in_keys=["observation"],
        out_keys=["action"],
    )
    res, (tol_m, tol_deg), _ = evaluate_policy(actor, tc.env, 0.0, episodes=24, seed=5)
    assert tol_m == pytest.approx(30.0) and tol_deg == pytest.approx(60.0)  # paper: difficulty 0
    s, t = res["success"], res["truncated"]
    assert s.any() and t.any() and res["collision"].any()  # every check below selects something
    ended = s.int() + res["collision"].int() + res["jackknife"].int() + t.int()
    assert (ended == 1).all()  # exactly one outcome per episode
    within = (
        (res["pos_error"] <= tol_m)
        & (res["tractor_heading_error"] <= tol_deg + 1e-4)
        & (res["trailer_heading_error"] <= tol_deg + 1e-4)
    )
    assert within[s].all() and not within[t].any()  # a time-out never ends within tolerance
    assert (res["length"][t] == MAX_STEPS).all()


@pytest.mark.e2e
def test_cli_is_deterministic_and_matches_in_process_run(tiny_checkpoint, tmp_path):
    run, ac, tc = tiny_checkpoint
    out = tmp_path / "eval.json"
    args = [f"checkpoint={run}", "episodes=12", "seed=7", "difficulty=1", f"output={out}"]
    proc = run_cli("evaluate", *args, "threads=1", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout.strip().splitlines()[-1])
    written = json.loads(out.read_text())
    assert written["provenance"]["threads"] == 1  # threads= set before the episodes ran
    assert printed["success_rate"] == written["success_rate"]
    assert written["episodes"] == 12 and written["difficulty"] == 1.0
    assert written["tolerance_position_m"] == pytest.approx(15.0)  # 30 m x 2^-1
    res, _, _ = evaluate_policy(ac.actor, tc.env, 1.0, episodes=12, seed=7)
    assert written["success_rate"] == pytest.approx(res["success"].float().mean().item())
    k = int(res["success"].sum())
    assert written["success_ci95"] == pytest.approx(list(wilson_interval(k, 12)))
    lo, hi = written["success_ci95"]
    assert f"success 95 % interval {lo:.3f}-{hi:.3f} (Wilson, 12 scenes)" in proc.stdout
    assert written["pos_error_m_mean"] == pytest.approx(res["pos_error"].mean().item(), rel=1e-5)
    # p95: linear interpolation between the order statistics, numpy's default percentile
    errors = res["pos_error"].double().numpy()
    assert len(set(errors.tolist())) == 12  # distinct errors: the rank convention matters
    assert written["pos_error_m_p95"] == pytest.approx(np.percentile(errors, 95), rel=1e-5)


@pytest.mark.e2e
def test_cli_prints_categories_and_writes_them_beside_the_run(tiny_checkpoint, tmp_path):
    run, ac, tc = tiny_checkpoint
    args = [f"checkpoint={run}", "episodes=12", "seed=8", "difficulty=1.5"]
    proc = run_cli("evaluate", *args, f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    out = run / "eval" / "1.5-8.json"
    written = json.loads(out.read_text())
    printed = json.loads(proc.stdout.strip().splitlines()[-1])
    assert printed["output"] == str(out)
    assert written["categories"] == printed["categories"]
    res, _, _ = evaluate_policy(ac.actor, tc.env, 1.5, episodes=12, seed=8)
    expected = summarize_by_category(res, episode_bins(generated_scenes(tc.env, 12, 8)))
    assert [(r["dimension"], r["bin"], r["count"]) for r in written["categories"]] == [
        (r["dimension"], r["bin"], r["count"]) for r in expected
    ]
    for got, want in zip(written["categories"], expected, strict=True):
        assert got["success_rate"] == pytest.approx(want["success_rate"])
    table = proc.stdout.split("by scene category")[1]
    assert "dimension" in table and "turn [deg]" in table and "goal distance [m]" in table
    assert proc.stdout.index("final error") < proc.stdout.index("by scene category")


@pytest.mark.e2e
def test_env_overrides_change_the_scenes_of_this_evaluation_only(tiny_checkpoint, tmp_path):
    """``env.task.scene.crossing_prob=0``: every scene is one straight road, the JSON says which
    override made it and goes to its own file; the checkpoint's config is unchanged."""
    run, _, tc = tiny_checkpoint
    args = [f"checkpoint={run}", "episodes=12", "seed=8", "env.task.scene.crossing_prob=0.0"]
    proc = run_cli("evaluate", *args, f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    written = json.loads((run / "eval" / f"{tc.curriculum.start_difficulty:g}-8-task.scene.crossing_prob=0.0.json").read_text())  # fmt: skip
    assert written["env_overrides"] == {"env.task.scene.crossing_prob": 0.0}
    routes = {r["bin"]: r["count"] for r in written["categories"] if r["dimension"] == "route"}
    assert routes == {"straight road": 12}
    assert tc.env.task.scene.crossing_prob > 0  # the default mix has crossings


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"task": {"scene": {"crossing_prob": 2.0}}}, "env.task.scene.crossing_prob = 2.0 is outside"),
        ({"lidar": {"num_beams": 32}}, "env.lidar.num_beams = 32: the env has 16 beams"),
        ({"task": {"name": "dock"}}, "env.task.name = 'dock': the env's task is 'intersection'"),
        ({"task": {"scene": {"nope": 1}}}, "unknown field(s) ['nope'] for env.task.scene"),
        ({"dt": {"x": 1}}, "env.dt is a value, not a group"),
    ],
)  # fmt: skip
def test_bad_env_overrides_are_one_line(override, message):
    from truckrl.tasks import EnvConfig
    from truckrl.tasks.config import with_env_overrides

    with pytest.raises(ConfigError) as e:
        with_env_overrides(EnvConfig(), override, fixed=True)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_env_overrides_merge_into_the_rest():
    from truckrl.tasks import EnvConfig
    from truckrl.tasks.config import flat_overrides, with_env_overrides

    base = EnvConfig()
    got = with_env_overrides(
        base, {"task": {"scene": {"crossing_prob": 1.0}}, "max_steps": 300}, True
    )
    assert got.task.scene.crossing_prob == 1.0 and got.max_steps == 300
    assert got.task.scene.road_width == base.task.scene.road_width and got.lidar == base.lidar
    assert with_env_overrides(base, {}, True) is base
    assert flat_overrides({"task": {"scene": {"a": 1}}, "b": 2}) == {
        "env.task.scene.a": 1,
        "env.b": 2,
    }


@pytest.mark.e2e
def test_unwritable_output_is_one_line_before_any_episode(tiny_checkpoint, tmp_path, capsys):
    run, _, _ = tiny_checkpoint
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    out = blocker / "sub" / "eval.json"  # its folder cannot be made, even by root
    args = [f"checkpoint={run}", "episodes=12", f"output={out}"]
    r = run_main(capsys, "evaluate", *args, f"hydra.run.dir={tmp_path}")
    assert r.out == ""  # no results: a late failure would print them first
    assert assert_one_line_error(r, str(out)).startswith("error: output=")


def test_output_is_checked_before_the_episodes_run(tiny_checkpoint, tmp_path, monkeypatch):
    run, _, _ = tiny_checkpoint
    (tmp_path / "eval.json").mkdir()

    def fail(*args, **kwargs):
        raise AssertionError("episodes ran before the output check")

    monkeypatch.setattr(rollout_module, "evaluate_policy", fail)
    ec = EvaluateConfig(checkpoint=str(run), episodes=2, output=str(tmp_path / "eval.json"))
    with pytest.raises(ConfigError, match="cannot write"):
        evaluate(ec)


def test_late_write_failure_prints_the_results_first(
    tiny_checkpoint, tmp_path, monkeypatch, capsys
):
    run, _, _ = tiny_checkpoint

    def full_disk(path, data):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(evaluate_module, "write_json", full_disk)
    ec = EvaluateConfig(checkpoint=str(run), episodes=4, seed=3, output=str(tmp_path / "e.json"))
    with pytest.raises(ConfigError, match="results above were not written") as err:
        evaluate(ec)
    assert len(str(err.value).splitlines()) == 1 and "No space left" in str(err.value)
    stdout = capsys.readouterr().out
    assert "by scene category" in stdout
    assert json.loads(stdout.strip().splitlines()[-1])["episodes"] == 4
    assert not list(tmp_path.iterdir())  # no stray probe or temporary files


def test_missing_checkpoint_is_one_line(tmp_path, capsys):
    before = logging.getLogger().handlers[:]
    r = run_main(
        capsys, "evaluate", f"checkpoint={tmp_path / 'nope.pt'}", f"hydra.run.dir={tmp_path}"
    )
    assert_one_line_error(r, "nope.pt")
    # the harness leaves no handler on this test's captured streams for a later test to log to
    assert logging.getLogger().handlers == before


def test_corrupt_checkpoint_raises_checkpoint_error(tiny_checkpoint, tmp_path):
    run, _, _ = tiny_checkpoint
    bad = tmp_path / "bad.pt"
    bad.write_bytes((run / "checkpoints" / "last.pt").read_bytes()[:500])
    with pytest.raises(CheckpointError, match="cannot read"):
        evaluate(EvaluateConfig(checkpoint=str(bad), episodes=2, seed=0))


def test_planner_policy_plays_the_checkpoints_scenes_and_writes_beside_the_run(
    tiny_checkpoint, monkeypatch
):
    """``policy=planner`` plans the scenes the checkpoint is scored on (same env config, seed and
    difficulty): its per-route counts equal the policy's, and the JSON lands beside the run."""
    import truckrl.planning as planner_module

    run, _, _ = tiny_checkpoint
    small = planner_module.PlannerConfig(compile=False, samples=8, iterations=1)
    monkeypatch.setattr(evaluate_module, "planner_config", lambda: small)
    base = dict(checkpoint=str(run), episodes=3, seed=7, difficulty=0.0)
    planned = evaluate(EvaluateConfig(policy="planner", **base))
    scored = evaluate(EvaluateConfig(**base))
    assert planned["policy"] == "planner" and scored["policy"] == "checkpoint"
    assert planned["planner_rollouts"] > 0
    out = planned["output"]
    assert out.endswith("eval/planner-0-7.json") and str(run) in out
    assert json.loads(open(out).read())["policy"] == "planner"
    route = [(r["bin"], r["count"]) for r in planned["categories"] if r["dimension"] == "route"]
    assert route == [
        (r["bin"], r["count"]) for r in scored["categories"] if r["dimension"] == "route"
    ]
    assert planned["tolerance_position_m"] == scored["tolerance_position_m"] == 30.0


def test_planner_policy_needs_no_checkpoint_but_the_policy_does():
    assert EvaluateConfig(policy="planner").checkpoint is None
    with pytest.raises(ConfigError, match="checkpoint is required"):
        EvaluateConfig()
    with pytest.raises(ConfigError, match="policy"):
        EvaluateConfig(policy="oracle")


# ---------------------------------------------------------------------------------- policy=SPEC
def doc_block(marker: str) -> str:
    """The python block of docs/evaluation.md that contains ``marker``."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "evaluation.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    (block,) = [b for b in blocks if marker in b]
    return block


def test_the_docs_callable_example_runs_as_the_same_torchrl_module():
    """docs/evaluation.md's ``obs -> action`` example gives the results of the same controller
    written as a TorchRL module (a path that needs no convention)."""
    scope: dict = {}
    exec(doc_block("evaluate_policy(drive"), scope)
    results = scope["results"]
    module = TensorDictModule(
        lambda obs: scope["drive"](obs, None), in_keys=["observation"], out_keys=["action"]
    )
    from truckrl.tasks import EnvConfig

    ref, _, _ = evaluate_policy(module, EnvConfig(), 0.0, 20, 12345)
    assert results.keys() == ref.keys() and results["success"].shape == (20,)
    for k in ref:  # "motion" is NaN after each episode's end
        torch.testing.assert_close(results[k], ref[k], rtol=0, atol=0, equal_nan=True, msg=k)
    assert results["success"].any() and not results["success"].all()


def test_onnx_file_through_eval_matches_its_numpy_oracle(tmp_path, monkeypatch):
    """``policy=onnx:FILE``: the model card's env and difficulty, results equal to the same
    linear map run as a torch callable, the JSON under outputs/eval/."""
    from tests.test_policy_specs import card_for, linear_onnx
    from truckrl.tasks import EnvConfig

    monkeypatch.chdir(tmp_path)
    env_cfg = EnvConfig(max_steps=30)
    a, b = linear_onnx(tmp_path / "lin.onnx", card=card_for(env_cfg, 2.5))
    got = evaluate(EvaluateConfig(policy=f"onnx:{tmp_path / 'lin.onnx'}", episodes=8, seed=3))
    assert got["policy"] == "onnx" and got["difficulty"] == 2.5 and got["checkpoint"] is None
    assert got["output"] == "outputs/eval/onnx-lin-2.5-3.json"
    written = json.loads((tmp_path / got["output"]).read_text())
    assert written["onnx"] == str(tmp_path / "lin.onnx")
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    ref, _, errors = evaluate_policy(lambda o, li: o @ ta + li @ tb, env_cfg, 2.5, 8, 3)
    expected = rollout_module.summarize(ref, errors)
    for k in ("success_rate", "collision_rate", "timeout_rate", "mean_length"):
        assert written[k] == pytest.approx(expected[k]), k
    assert written["pos_error_m_mean"] == pytest.approx(expected["pos_error_m_mean"], abs=1e-3)


def test_module_policy_in_another_task(tmp_path, monkeypatch):
    """docs/evaluation.md's ``my_drivers.py`` example, by ``policy=my_drivers:make task=dock``."""
    import sys

    from truckrl.evaluate import prepare_argv

    monkeypatch.chdir(tmp_path)
    monkeypatch.delitem(sys.modules, "my_drivers", raising=False)
    (tmp_path / "my_drivers.py").write_text(doc_block("def make(env_config)"))
    assert prepare_argv(["task=dock", "episodes=4"]) == ["+env.task.name=dock", "episodes=4"]
    ec = EvaluateConfig(policy="my_drivers:make", env={"task": {"name": "dock"}}, episodes=4)
    got = evaluate(ec)
    assert got["task"] == "dock" and got["policy"] == "module" and got["difficulty"] == 6.0
    assert got["output"] == "outputs/eval/module-my_drivers.make-6-12345-task.name=dock.json"
    assert got["episodes"] == 4
    with pytest.raises(ConfigError, match="env.task.name = 'dock': the env's task is"):
        evaluate(EvaluateConfig(checkpoint="pretrained", env={"task": {"name": "dock"}}))


def test_bad_policy_specs_on_the_command_line_are_one_line(tmp_path, monkeypatch, capsys):
    from tests.reliability.harness import run_main

    monkeypatch.chdir(tmp_path)
    for args, fragment in [
        (["policy=onnx:none.onnx"], "error: policy = 'onnx:none.onnx': file not found"),
        (["policy=tflite"], "error: policy = 'tflite' is not a policy; use checkpoint:PATH"),
        (["policy=pretrained", "checkpoint=x"], "give one (checkpoint=PATH is short for"),
        (["policy=no_such_mod_q:make"], "module 'no_such_mod_q' does not import"),
        (["policy=planner", "task=nope"], "task = 'nope' is not a task"),
    ]:
        r = run_main(capsys, "evaluate", *args, "episodes=2")
        assert r.code == 2 and len(r.err.strip().splitlines()) == 1, (args, r.err)
        assert fragment in r.err, (args, r.err)
    assert list(tmp_path.iterdir()) == []  # nothing ran, nothing written


def test_motion_records_the_commanded_rates(tiny_checkpoint):
    """accel_rate control: the realised acceleration and steering rate are the command times the
    truck's bound (``u * max_q``) while nothing saturates; a constant command has zero jerk after
    its first step."""
    _, _, tc = tiny_checkpoint
    cfg = dataclasses.replace(tc.env, max_steps=5)
    u = torch.tensor([0.25, 0.1])

    def constant(td):
        return td.set("action", u.expand(td.batch_size[0], 2).clone())

    res, _, _ = evaluate_policy(constant, cfg, 6.0, episodes=6, seed=4)
    m = res["motion"]  # [E, T, 4]: accel, jerk, steer_rate, steer_accel
    assert m.shape == (6, 5, len(rollout_module.MOTION))
    g = torch.Generator().manual_seed(4)
    params = sample_vehicle_params(cfg.vehicle, max(6, cfg.episode_pool), g)
    max_accel, max_rate = params["max_accel"][:6], params["max_steer_rate"][:6]
    torch.testing.assert_close(m[:, :3, 0], (u[0] * max_accel)[:, None].expand(6, 3))
    torch.testing.assert_close(m[:, :3, 2], (u[1] * max_rate)[:, None].expand(6, 3))
    torch.testing.assert_close(m[:, 1:3, 1], torch.zeros(6, 2))


def test_motion_holds_one_row_per_step_of_each_episode(tiny_checkpoint):
    _, _, tc = tiny_checkpoint

    def full_throttle_left(td):  # drives into a curb, each scene at its own step
        return td.set("action", torch.tensor([1.0, 1.0]).expand(td.batch_size[0], 2).clone())

    res, _, _ = evaluate_policy(full_throttle_left, tc.env, 1.0, episodes=24, seed=5)
    live = ~res["motion"].isnan().any(-1)  # [E, T]
    assert res["length"].unique().numel() > 1  # episodes of different lengths
    torch.testing.assert_close(live.sum(1).float(), res["length"])
    assert (live[:, :-1] | ~live[:, 1:]).all()  # live steps first, then NaN


def test_smoothness_pools_the_steps_of_successful_episodes_only():
    # two successes of 2 and 3 live steps (NaN after the end) and one failure that is ignored
    nan = float("nan")
    jerk = torch.tensor([[1.0, -3.0, nan], [2.0, -4.0, 5.0], [100.0, 100.0, 100.0]])
    motion = torch.zeros(3, 3, len(rollout_module.MOTION))
    motion[..., 1] = jerk
    motion[0, 2] = nan
    res = {"motion": motion, "success": torch.tensor([True, True, False])}
    sm = rollout_module.smoothness(res)
    assert sm["steps"] == 5
    # |jerk| pooled: 1, 2, 3, 4, 5 -> linear percentiles: p50 = 3, p95 = 4.8, p99 = 4.96
    assert sm["jerk_m/s^3_p50"] == pytest.approx(3.0)
    assert sm["jerk_m/s^3_p95"] == pytest.approx(4.8)
    assert sm["jerk_m/s^3_p99"] == pytest.approx(4.96)
    assert sm["accel_m/s^2_p99"] == 0.0
    assert rollout_module.smoothness({**res, "success": torch.zeros(3, dtype=torch.bool)}) is None
