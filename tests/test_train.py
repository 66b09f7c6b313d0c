"""End-to-end runs of ``python -m truckrl.train`` with tiny settings (real env, real entry point)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import ROOT, TINY_BATCH, TINY_TRAIN, compose_config, run_cli
from tests.reliability.harness import Result, assert_one_line_error, run_main
from truckrl.cli import to_config
from truckrl.config.fields import ConfigError
from truckrl.config.schemas import TrainConfig
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.collection import make_env, set_difficulty
from truckrl.rl.trainer import frames_due
from truckrl.tasks import EnvConfig

BATCH = TINY_BATCH
pytestmark = pytest.mark.e2e


def train(*args: str, check: bool = True, multirun: bool = False) -> subprocess.CompletedProcess:
    flags = ["--multirun"] if multirun else []
    proc = run_cli("train", *flags, *TINY_TRAIN, *args)
    if check:
        assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


def train_here(capsys, *args: str) -> Result:
    """``truckrl train`` with the tiny config in this process (no interpreter start): for the
    runs that stop with a one-line error before any training."""
    return run_main(capsys, "train", *TINY_TRAIN, *args)


def scalar_steps(run_dir: Path, tag: str = "perf/fps") -> list[int]:
    return [e.step for e in _accumulator(run_dir).Scalars(tag)]


#: Held-out checks after every iteration, on 4 short scenes: counted in frames, since a check by
#: the minute is due only when an iteration spans a multiple of its interval, which a fast
#: iteration can miss.
EVALS = [f"log.eval_interval_frames={BATCH}", "log.eval_episodes=4", "env.max_steps=20"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """The module's run: 4 iterations with held-out checks (best.pt kept); tests that resume or
    fine-tune from it share it (:func:`resumed` continues it to 6 iterations)."""
    d = tmp_path_factory.mktemp("run")
    train(f"total_frames={4 * BATCH}", "checkpoint.interval=2", *EVALS, f"hydra.run.dir={d}")
    return d


@pytest.fixture(scope="module")
def resumed(run_dir) -> tuple[Path, list[tuple[int, float]], dict]:
    """:func:`run_dir` continued to 6 iterations with the same held-out checks; returns it, the
    held-out success rates ``(frames, value)`` logged before the resume and best.pt's record
    then."""
    before = [(e.step, e.value) for e in _accumulator(run_dir).Scalars("eval/success_rate")]
    best = load_checkpoint(run_dir / "checkpoints" / "best.pt")["heldout"]
    proc = train(f"resume={run_dir}", f"total_frames={6 * BATCH}", *EVALS)
    assert "resumed" in proc.stdout
    return run_dir, before, best


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> Path:
    """One iteration with held-out checks, ``checkpoint.keep_best=false`` and a training-only
    tolerance (``train_env.tolerance.position=12``)."""
    d = tmp_path_factory.mktemp("evaluated")
    off, own = "checkpoint.keep_best=false", "train_env.tolerance.position=12"
    train(f"total_frames={BATCH}", *EVALS, off, own, f"hydra.run.dir={d}")
    return d


def _accumulator(run_dir: Path) -> EventAccumulator:
    acc = EventAccumulator(str(run_dir / "tb"), purge_orphaned_data=True)
    acc.Reload()
    return acc


def test_run_writes_events_config_and_checkpoint(run_dir):
    state = load_checkpoint(run_dir)
    assert state["counters"]["iteration"] == 4
    assert state["counters"]["frames"] == 4 * BATCH
    assert state["num_beams"] == 32 and state["num_obs"] == 26  # experiment=demos: 32 beams
    assert "ppo:" in state["config"]
    assert scalar_steps(run_dir) == [BATCH * i for i in range(1, 5)]
    acc = EventAccumulator(str(run_dir / "tb"))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    expected = {
        "loss/objective",
        "loss/critic",
        "loss/entropy",
        "train/kl",
        "train/lr",
        "train/action_std",
        "train/action_std_longitudinal",
        "train/action_std_lateral",
        "episode/success_ema",
        "curriculum/difficulty",
        "curriculum/tolerance_position_m",
        "curriculum/tolerance_heading_deg",
        "reward_step/r_progress",
        "perf/fps_collect",
        "perf/learn_s",
    }
    assert expected <= tags, expected - tags
    tol = acc.Scalars("curriculum/tolerance_position_m")[0].value
    assert tol == pytest.approx(30.0)  # paper: 30 m at difficulty 0
    assert (run_dir / ".hydra" / "config.yaml").is_file()
    source = json.loads((run_dir / "source.json").read_text())
    assert len(source["commit"]) == 40 and isinstance(source["dirty"], bool)
    assert load_checkpoint(run_dir)["source"] == source


def test_heldout_evaluation_is_logged(evaluated):
    """Held-out checks are logged when due; ``checkpoint.keep_best=false`` keeps no best.pt."""
    assert not (evaluated / "checkpoints" / "best.pt").exists()
    assert (evaluated / "checkpoints" / "last.pt").exists()
    acc = _accumulator(evaluated)
    tags = set(acc.Tags()["scalars"])
    assert {"eval/success_rate", "eval/collision_rate", "eval/timeout_rate"} <= tags, tags
    assert any(t.startswith("eval/route/") and t.endswith("/success") for t in tags), tags
    steps = [e.step for e in acc.Scalars("eval/success_rate")]
    assert steps == [BATCH]
    assert all(0.0 <= e.value <= 1.0 for e in acc.Scalars("eval/success_rate"))


def test_best_checkpoint_keeps_the_best_heldout_result_across_a_resume(resumed):
    """best.pt is the checkpoint of the first held-out evaluation with the highest (difficulty,
    success); a resumed run replaces it only with a strictly better one; last.pt has no record."""
    run, before, best_before = resumed
    seen = [(e.step, e.value) for e in _accumulator(run).Scalars("eval/success_rate")]
    assert [s for s, _ in seen] == [BATCH * i for i in range(1, 7)]
    assert seen[:4] == before
    top = max(v for _, v in before)
    assert best_before["success_rate"] == pytest.approx(top)
    assert best_before["frames"] == next(s for s, v in before if v == top)
    top = max(v for _, v in seen)
    first_top = next(s for s, v in seen if v == top)
    best = load_checkpoint(run / "checkpoints" / "best.pt")
    assert best["heldout"]["success_rate"] == pytest.approx(top)
    assert best["heldout"]["difficulty"] == 0.0
    assert best["counters"]["frames"] == best["heldout"]["frames"] == first_top
    assert "heldout" not in load_checkpoint(run)  # last.pt


def test_heldout_checks_can_count_frames():
    """``log.eval_interval_frames``: due at the first iteration that ends at or past each
    multiple (tests/test_determinism.py runs it end to end)."""
    due = [frames_due(1000, f, 384) for f in range(384, 4000, 384)]
    # iterations end at 384, 768, 1152 (past 1000), ..., 2304 (past 2000), ..., 3072 (past 3000)
    assert [i for i, d in enumerate(due) if d] == [2, 5, 7]
    assert frames_due(256, 256, 256) and not frames_due(256, 255, 255)


def test_demonstrations_start_the_run_and_a_resume_does_not_plan_again(tmp_path, capsys):
    """``demos.episodes=N``: the run plans N scenes, clones the solutions (demos.json says how
    it went), then trains; resuming it never plans again. With ``demos.bc_coeff`` the samples
    are kept in demos.pt, the cloning term is logged, and a resume without them is one line."""
    demos = ["demos.episodes=3", "demos.difficulty=0", "demos.samples=32", "demos.iterations=2",
             "demos.compile=false", "demos.epochs=3", "demos.seed=12345", "env.max_steps=40",
             "demos.bc_coeff=1", f"demos.bc_frames={4 * BATCH}"]  # fmt: skip
    proc = train(f"total_frames={BATCH}", *demos, f"hydra.run.dir={tmp_path}")
    assert "demonstrations: planning 3 scenes (seed 12345) at difficulty 0" in proc.stdout
    info = json.loads((tmp_path / "demos.json").read_text())
    assert info["scenes"] == 3 and 1 <= info["plans_kept"] <= 3 and info["samples"] > 0
    assert len(info["losses"]) == 3 and info["losses"][-1] < info["losses"][0]
    std = load_checkpoint(tmp_path)["model"]
    log_std = next(v for k, v in std.items() if k.endswith("log_std"))
    assert torch.allclose(log_std.exp(), torch.tensor(0.3), atol=0.05)  # set, then one update
    saved = torch.load(tmp_path / "demos.pt", weights_only=True)
    assert len(saved["action"]) == info["samples"] and saved["lidar"].shape[1] == 32
    assert scalar_steps(tmp_path, "train/bc_coeff") == [BATCH]
    proc = train(f"resume={tmp_path}", f"total_frames={2 * BATCH}", *demos)
    assert "demonstrations:" not in proc.stdout
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    weights = [e.value for e in acc.Scalars("train/bc_coeff")]
    assert weights == pytest.approx([1.0, 0.75])  # falls linearly over 4 batches
    assert all(e.value > 0 for e in acc.Scalars("loss/bc"))
    (tmp_path / "demos.pt").unlink()
    r = train_here(capsys, f"resume={tmp_path}", f"total_frames={3 * BATCH}")
    assert assert_one_line_error(r) == (
        f"error: demos.bc_coeff = 1 needs demonstrations: a resumed run reads "
        f"{tmp_path}/demos.pt, which does not exist (put it back, or start a new run from "
        f"these weights: init={tmp_path} demos.bc_coeff=0)"
    )


def test_demonstrations_that_solve_nothing_are_one_line(tmp_path, capsys):
    demos = ["demos.episodes=2", "demos.difficulty=30", "demos.samples=4", "demos.iterations=1",
             "demos.compile=false", "env.max_steps=5"]  # fmt: skip
    r = train_here(capsys, f"total_frames={BATCH}", *demos, f"hydra.run.dir={tmp_path}")
    assert_one_line_error(r, "demos: the planner solved none")


def test_resume_continues_counters_and_steps(resumed):
    run_dir = resumed[0]
    state = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    assert state["counters"]["iteration"] == 6
    assert state["counters"]["frames"] == 6 * BATCH
    assert scalar_steps(run_dir) == [BATCH * i for i in range(1, 7)]


def test_init_starts_a_new_run_from_another_runs_weights(run_dir, tmp_path):
    """``init=``: a new run (counters from zero, its own config) whose network starts as the
    given checkpoint's; with a learning rate of ~0 it ends one iteration where it started. Its
    seed differs from the given run's, so without init its weights would be another draw."""
    frozen = ["ppo.lr=1e-12", "ppo.lr_min=1e-12", "ppo.lr_schedule=fixed", f"total_frames={BATCH}"]
    it = load_checkpoint(run_dir)["counters"]["iteration"]  # shared: other tests resume run_dir
    demos = ("demos.episodes=3", "demos.bc_coeff=1")  # a fine-tune skips both
    proc = train(f"init={run_dir}", "seed=5", *frozen, *demos, f"hydra.run.dir={tmp_path}")
    assert f"init: weights of {run_dir}/checkpoints/last.pt (iteration {it}," in proc.stdout
    assert "demos skipped" in proc.stdout and "demonstrations:" not in proc.stdout
    new, old = load_checkpoint(tmp_path)["model"], load_checkpoint(run_dir)["model"]
    assert load_checkpoint(tmp_path)["counters"]["iteration"] == 1
    assert all(torch.allclose(new[k], old[k], atol=1e-6) for k in old)


def test_fine_tune_of_the_shipped_policy_names_its_beams(tmp_path, capsys):
    """The fine-tune of docs/training.md: the shipped policy sees the default run's 32 beams; a
    run whose env gives 16 stops in one line that names the setting, the default env starts from
    those weights."""
    r = train_here(capsys, "init=pretrained", "env.lidar.num_beams=16",
                   f"hydra.run.dir={tmp_path / 'a'}")  # fmt: skip
    line = assert_one_line_error(r)
    assert line.endswith(
        "32 LiDAR beams; this run's env gives 26 and 16 (set env.lidar.num_beams=32)"
    )
    ok = tmp_path / "b"
    train("init=pretrained", f"total_frames={BATCH}", f"hydra.run.dir={ok}")
    assert load_checkpoint(ok)["num_beams"] == 32


def test_train_env_changes_the_training_envs_only(evaluated):
    """``train_env.tolerance.position=12``: the training envs run with 12 m at difficulty 0 (the
    logged tolerance), while the checkpoint's ``env`` keeps the paper's 30 m and the default scene
    mix for evaluation."""
    acc = _accumulator(evaluated)
    assert acc.Scalars("curriculum/tolerance_position_m")[0].value == pytest.approx(12.0)
    saved = yaml.safe_load(load_checkpoint(evaluated)["config"])
    # the command line adds to the default's train_env (crossings only), it does not replace it
    assert saved["train_env"] == {
        "task": {"scene": {"crossing_prob": 1.0}},
        "tolerance": {"position": 12},
    }
    assert saved["env"]["tolerance"]["position"] == 30.0
    assert saved["env"]["task"]["scene"]["crossing_prob"] == 0.7


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("init=no/such/run", "error: checkpoint not found: no/such/run"),
        (
            "env.lidar.num_beams=16",
            "32 LiDAR beams; this run's env gives 26 and 16 (set env.lidar.num_beams=32)",
        ),
    ],
)
def test_init_that_does_not_fit_is_one_line(run_dir, tmp_path, override, message, capsys):
    r = train_here(capsys, f"init={run_dir}", override, f"hydra.run.dir={tmp_path / 'r'}")
    assert_one_line_error(r, message)
    assert not (tmp_path / "r" / "checkpoints").exists()


def test_sigkill_then_resume_loses_nothing_before_the_checkpoint(tmp_path):
    run = tmp_path / "killed"
    cmd = [sys.executable, "-m", "truckrl.train", *TINY_TRAIN, "total_frames=10000000"]
    cmd += ["checkpoint.interval=1", f"hydra.run.dir={run}"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            last = run / "checkpoints" / "last.pt"
            if last.is_file() and load_checkpoint(last)["counters"]["iteration"] >= 2:
                break
            time.sleep(0.2)
        else:
            pytest.fail("no checkpoint within 120 s")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    saved = load_checkpoint(run)  # the atomic write left a readable file
    k = saved["counters"]["iteration"]
    assert saved["counters"]["frames"] == k * BATCH
    train(f"resume={run}", f"total_frames={(k + 1) * BATCH}")
    after = load_checkpoint(run)
    assert after["counters"]["iteration"] == k + 1
    assert after["counters"]["frames"] == (k + 1) * BATCH
    assert after["counters"]["wall_time_s"] > saved["counters"]["wall_time_s"]
    # events logged after the checkpoint by the killed process are purged: one value per step
    assert scalar_steps(run) == [BATCH * i for i in range(1, k + 2)]


def test_bad_config_is_one_clear_line_before_any_work(tmp_path, capsys):
    r = train_here(capsys, "ppo.num_minibatches=7", f"hydra.run.dir={tmp_path}")
    assert_one_line_error(r, "ppo.num_minibatches")
    assert not (tmp_path / "checkpoints").exists()


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("ppo.lr=-1e-4", "ppo.lr"),
        ("collector.steps_per_env=0", "collector.steps_per_env"),
        ("curriculum.threshold=1.2", "curriculum.threshold"),
        ("model.kernel_size=4", "model.kernel_size"),
        ("env.dt=-0.1", "env.dt"),
        ("threads=0", "threads"),
        ("log.eval_interval_frames=0", "log.eval_interval_frames"),
    ],
)
def test_bad_values_name_the_field(override, field):
    with pytest.raises(ConfigError, match=field):
        to_config(TrainConfig, compose_config("train", override))


def test_paper_preset_has_the_paper_numbers():
    tc = to_config(TrainConfig, compose_config("train", "experiment=paper"))
    assert tc.collector.num_envs * tc.collector.workers == 24
    assert tc.collector.steps_per_env == 512
    p = tc.ppo
    assert (p.lr, p.num_epochs, p.num_minibatches, p.gamma, p.lmbda) == (1e-4, 8, 96, 0.99, 0.95)
    assert (p.clip_epsilon, p.entropy_coeff, p.value_coeff, p.max_grad_norm) == (
        0.2,
        0.005,
        0.5,
        4.0,
    )
    assert p.lr_schedule == "adaptive" and p.desired_kl == 0.01
    assert p.check_batch(tc.collector.frames_per_batch) == 128  # paper: minibatch 128
    assert not tc.env.compile


def test_demos_experiment_is_the_default():
    """``make train``: planner demonstrations, cloning, then PPO that keeps cloning them, on the
    fast rollout shape, for the full 60 minutes."""
    tc = to_config(TrainConfig, compose_config("train"))
    assert tc.collector.frames_per_batch == 1024 * 64 and tc.env.compile
    assert (tc.ppo.num_epochs, tc.ppo.num_minibatches, tc.ppo.lr) == (5, 16, 3e-4)
    assert (tc.demos.episodes, tc.demos.bc_coeff, tc.stop_difficulty) == (600, 1.0, None)
    assert tc.log.eval_interval_frames == 5_000_000  # held-out checks (and best.pt) by frames


def test_difficulty_reaches_every_parallel_worker():
    env = make_env(EnvConfig(), workers=2, num_envs=2, seed=0)
    try:
        pos, deg = set_difficulty(env, 1.5)
        assert pos == pytest.approx(30.0 * 2**-1.5)  # paper: 30 m x 2^-d
        assert deg == pytest.approx(60.0 * 2**-1.5)  # paper: 60 deg x 2^-d
        td = env.rollout(2, break_when_any_done=False)
        assert td.batch_size == (2, 2, 2)
        assert torch.all(td["next", "difficulty"] == 1.5)
        assert not torch.equal(td["observation"][0], td["observation"][1])  # workers differ
    finally:
        env.close()
