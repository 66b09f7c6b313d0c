"""Trainers side by side: truckrl's, SB3 PPO and a CleanRL-style PPO, one wall-clock budget each.

``truckrl bench trainers minutes=4 seeds=[0,1]`` trains each of ``trainers`` once per seed on
``task`` for ``minutes`` of wall clock, each run in its own subprocess (one run's threads,
compile caches and allocator do not leak into the next) with ``threads`` torch threads, then
scores the final policy's mean action with
:func:`~truckrl.evaluation.rollout.evaluate_policy` on the same held-out scenes (``eval_seed``,
``episodes`` episodes) at ``eval_difficulty`` and at the difficulty the run reached. It prints
one table (trainer, seed, frames, frames/s, difficulty reached, held-out success) and writes
the JSON record (``benchmark: "trainers"``).

What is equal: the task and its experiment=quick env (for the intersection task: straight
roads, the larger progress reward and the cost per step; :func:`quick_env_overrides`),
the control (``control``, default ``accel_angle``: steering by angle, the one SB3 PPO learns
with, ``docs/gymnasium.md``), ``envs`` trucks x 32 steps per update, 4 minibatches, 5 epochs,
lr 3e-4 at the start, gamma 0.998, GAE lambda 0.95, clip 0.2, entropy weight 0.005, the
curriculum rule (the paper's, :class:`~truckrl.rl.curriculum.Curriculum`), the seed numbers,
the thread count and the budget (checked between updates: a run ends with the first update
that starts after it), and the held-out scenes. truckrl's trainer runs ``experiment=quick``
from scratch (no planner demonstrations).

What is not: the networks (truckrl's two-branch trunk with a LiDAR CNN; SB3's
``MultiInputPolicy`` MLP ``[128, 64]`` shared by both heads' inputs; the CleanRL-style separate
tanh MLPs ``[128, 64]``), truckrl's learning rate adapting to the KL divergence (the others keep
it fixed), truckrl applying a promotion once per update (SB3's callback: at the step; the
CleanRL-style loop: after each rollout), and the random streams behind a seed number (each
trainer draws its scenes and initial weights its own way). ``frames`` counts env steps of all
trucks; SB3's includes the one step of the rollout that found the budget spent. Set-up
(building the env and the network) and scoring are outside the budget.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from truckrl.bench.report import print_table, write_json
from truckrl.config.fields import param, validate
from truckrl.tasks.config import DEFAULT_TASK

#: The trainers, in the table's order.
TRAINERS = ("truckrl", "sb3", "cleanrl")
#: Steps per truck per update and minibatches per update: experiment=quick's, for all three.
STEPS, MINIBATCHES = 32, 4
#: The table's columns (JSON row keys).
COLUMNS = ("trainer", "seed", "frames", "train_s", "frames/s", "difficulty", "success_fixed",
           "success_reached")  # fmt: skip


@dataclass
class TrainersBenchConfig:
    """``truckrl bench trainers``'s keys."""

    minutes: float = param(
        4.0, lo=0.0, lo_open=True, hi=1440.0, unit="min", doc="wall-clock training budget per run"
    )
    seeds: tuple[int, ...] = param(
        (0, 1), lo=0, hi=2**31 - 1, doc="seeds; one run per trainer each"
    )
    trainers: tuple[str, ...] = param(TRAINERS, choices=TRAINERS, doc="trainers to run")
    task: str = param(DEFAULT_TASK, doc="task folder (truckrl tools configs env lists them)")
    control: str = param(
        "accel_angle",
        doc="LONGITUDINAL_LATERAL control of all runs (truckrl/conf/control/; SB3 PPO learns "
        "only with a steering angle)",
    )
    threads: int = param(1, lo=1, hi=4096, doc="torch threads of each run")
    envs: int = param(128, lo=4, hi=1_000_000, unit="trucks", doc="trucks per batch (x 32 steps)")
    episodes: int = param(100, lo=1, hi=1_000_000, doc="held-out episodes per score")
    eval_seed: int = param(12345, lo=0, hi=2**31 - 1, doc="seed of the held-out scenes")
    eval_difficulty: float = param(
        2.0, lo=0.0, hi=30.0, doc="the fixed difficulty of the first held-out score"
    )
    out: str | None = param(
        None, doc="JSON record: a .json path or a folder (null: outputs/bench/trainers-<time>.json)"
    )

    def __post_init__(self) -> None:
        validate(self)


def controls() -> list[str]:
    """The control presets: ``truckrl/conf/control/*.yaml`` stems."""
    folder = Path(__file__).resolve().parent.parent / "conf" / "control"
    return sorted(p.stem for p in folder.glob("*.yaml"))


def parse(argv: list[str]) -> TrainersBenchConfig:
    """``KEY=VALUE`` arguments into the options; bad input: one line, exit 2, before any work."""
    from truckrl.cli import fail, key_value_config
    from truckrl.tasks import task_names

    opts = key_value_config(TrainersBenchConfig, argv, "truckrl bench trainers", __doc__)
    if opts.task not in task_names():
        fail(f"task = {opts.task!r} is not one of {list(task_names())}")
    if opts.control not in controls():
        fail(f"control = {opts.control!r} is not one of {controls()}")
    if opts.out is not None and Path(opts.out).suffix != ".json" and Path(opts.out).is_file():
        fail(f"out = {opts.out!r}: is a file, not a .json path or a folder")
    return opts


# ---------------------------------------------------------------------------- one run (worker)
def _dotted(node: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested config mapping as ``{"a.b.c": value}``."""
    out: dict[str, Any] = {}
    for k, v in node.items():
        key = f"{prefix}{k}"
        out.update(_dotted(v, key + ".") if isinstance(v, dict) else {key: v})
    return out


def quick_env_overrides(task: str, control: str) -> dict[str, Any]:
    """The env fields where ``truckrl train experiment=quick task=TASK control=CONTROL`` differs
    from the task's plain env config (``make_env``'s), as dotted keys for ``make_env``: read from the composed
    configs (``conf/experiment/quick.yaml`` and the task's ``train_scenes/quick_<task>.yaml``),
    so the Gymnasium/SB3 runs train on the scenes and rewards truckrl's run does."""
    from truckrl.bench.train import compose_train_config
    from truckrl.config.fields import build
    from truckrl.tasks import EnvConfig

    quick = compose_train_config(["experiment=quick", f"task={task}", f"control={control}"])
    plain = build(EnvConfig, {"task": {"name": task}}, "env")  # make_env's starting point
    a, b = _dotted(dataclasses.asdict(quick.env)), _dotted(dataclasses.asdict(plain))
    return {k: v for k, v in a.items() if v != b.get(k)}


def env_overrides(task: str, control: str) -> dict[str, Any]:
    """The env overrides of every run: experiment=quick's for ``task`` and the control."""
    return quick_env_overrides(task, control)


def _train_truckrl(
    job: dict[str, Any], overrides: dict[str, Any]
) -> tuple[Any, int, float, Any, float]:
    """truckrl's :class:`~truckrl.rl.trainer.Trainer` on ``experiment=quick`` (from scratch), its
    loop driven here so that the budget starts after set-up as for the others."""
    from truckrl.bench.train import compose_train_config
    from truckrl.cli import seed_everything
    from truckrl.rl.trainer import Trainer

    tc = compose_train_config([
        "experiment=quick", f"task={job['task']}", f"control={job['control']}",
        f"seed={job['seed']}", f"threads={job['threads']}", f"collector.num_envs={job['envs']}",
        f"collector.steps_per_env={STEPS}", f"ppo.num_minibatches={MINIBATCHES}",
        "log.progress_bar=false",
    ])  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="truckrl-bench-trainers-") as run_dir:
        trainer = Trainer(tc, Path(run_dir))
        seed_everything(tc.seed)
        trainer.setup()
        try:
            t0 = time.perf_counter()
            while time.perf_counter() < t0 + job["seconds"]:
                trainer.iterate()
            train_s = time.perf_counter() - t0
        finally:
            trainer.close(None)  # no final checkpoint: the run dir is thrown away
    frames, difficulty = trainer.counters.frames, trainer.curriculum.difficulty
    return trainer.ac.actor, frames, difficulty, tc.env, train_s


def _train_sb3(
    job: dict[str, Any], overrides: dict[str, Any]
) -> tuple[Any, int, float, Any, float]:
    """SB3 PPO with :data:`~truckrl.gym.sb3.PPO_KWARGS` and the curriculum callback."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList
    from stable_baselines3.common.vec_env import VecMonitor

    from truckrl.gym.sb3 import PPO_KWARGS, CurriculumCallback, TruckSB3VecEnv
    from truckrl.rl.curriculum import Curriculum, CurriculumConfig

    class Budget(BaseCallback):
        """Stops at the first step after the update that ended past the deadline."""

        def __init__(self, seconds: float) -> None:
            super().__init__()
            self.deadline, self.spent = time.perf_counter() + seconds, False

        def _on_rollout_end(self) -> None:
            self.spent = time.perf_counter() >= self.deadline

        def _on_step(self) -> bool:
            return not self.spent

    venv = TruckSB3VecEnv(num_envs=job["envs"], task=job["task"], seed=job["seed"], **overrides)
    curriculum = Curriculum(CurriculumConfig())
    kwargs = {**PPO_KWARGS, "n_steps": STEPS, "batch_size": job["envs"] * STEPS // MINIBATCHES}
    model = PPO("MultiInputPolicy", VecMonitor(venv), seed=job["seed"], device="cpu", **kwargs)
    callback = CallbackList([CurriculumCallback(curriculum), Budget(job["seconds"])])
    t0 = time.perf_counter()
    model.learn(total_timesteps=10**12, callback=callback)
    train_s = time.perf_counter() - t0

    def policy(observation: Any, lidar: Any) -> Any:
        obs = {"observation": observation.cpu().numpy(), "lidar": lidar.cpu().numpy()}
        return torch.as_tensor(model.predict(obs, deterministic=True)[0])

    frames, config = int(model.num_timesteps), venv.venv.env.config
    return policy, frames, curriculum.difficulty, config, train_s


def _train_cleanrl(
    job: dict[str, Any], overrides: dict[str, Any]
) -> tuple[Any, int, float, Any, float]:
    """:mod:`truckrl.bench.cleanrl_ppo` on a ``TruckVectorEnv(tensors=True)``."""
    from truckrl.bench.cleanrl_ppo import PPOSettings, train
    from truckrl.gym.vector import TruckVectorEnv
    from truckrl.rl.curriculum import Curriculum, CurriculumConfig

    env = TruckVectorEnv(job["envs"], job["task"], seed=job["seed"], tensors=True, **overrides)
    curriculum = Curriculum(CurriculumConfig())
    settings = PPOSettings(steps=STEPS, minibatch=job["envs"] * STEPS // MINIBATCHES)
    t0 = time.perf_counter()
    agent, frames = train(env, curriculum, job["seconds"], settings, job["seed"])
    train_s = time.perf_counter() - t0
    return agent.act, frames, curriculum.difficulty, env.env.config, train_s


RUNNERS = {"truckrl": _train_truckrl, "sb3": _train_sb3, "cleanrl": _train_cleanrl}


def run_one(job: dict[str, Any]) -> dict[str, Any]:
    """Train one ``job`` (trainer, seed, task, control, threads, envs, seconds, episodes,
    eval_seed, eval_difficulty) and score it; returns its row (:data:`COLUMNS` and more)."""
    import torch

    from truckrl.env.make import make_env
    from truckrl.evaluation.rollout import evaluate_policy

    torch.set_num_threads(job["threads"])
    overrides = env_overrides(job["task"], job["control"])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    t0 = time.perf_counter()
    policy, frames, difficulty, train_cfg, train_s = RUNNERS[job["trainer"]](job, overrides)
    total_s = time.perf_counter() - t0
    # the held-out scenes: one env config for every trainer (the SB3 / CleanRL runs' own)
    eval_cfg = make_env(job["task"], 1, **overrides).config

    def success(d: float) -> float:
        results, _, _ = evaluate_policy(policy, eval_cfg, d, job["episodes"], job["eval_seed"])
        return results["success"].float().mean().item()

    return {
        "trainer": job["trainer"],
        "seed": job["seed"],
        "frames": frames,
        "train_s": train_s,
        "frames/s": frames / train_s,
        "difficulty": difficulty,
        "success_fixed": success(job["eval_difficulty"]),
        "success_reached": success(difficulty),
        "setup_and_train_s": total_s,
        "same_env_as_scored": train_cfg == eval_cfg,
        "load_avg_1min_at_start": load,
    }


# ---------------------------------------------------------------------------- the harness
def _spawn(job: dict[str, Any], threads: int) -> dict[str, Any]:
    """:func:`run_one` in a fresh ``python -m truckrl.bench.trainers`` process; its row, or a row
    with ``error`` when it failed."""
    with tempfile.TemporaryDirectory(prefix="truckrl-bench-trainers-") as d:
        result = Path(d) / "row.json"
        env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
        cmd = [sys.executable, "-m", "truckrl.bench.trainers", json.dumps(job), str(result)]
        proc = subprocess.run(cmd, env=env)
        if proc.returncode != 0 or not result.exists():
            return {
                "trainer": job["trainer"],
                "seed": job["seed"],
                "error": f"exit {proc.returncode}",
            }
        return json.loads(result.read_text())


def run(opts: TrainersBenchConfig) -> dict[str, Any]:
    """Every (seed, trainer) run in its own subprocess, seeds outermost; print the table, write
    the JSON record; returns ``{"rows", "path"}``."""
    t_start = time.perf_counter()
    seconds = opts.minutes * 60.0
    print(
        f"bench trainers: {list(opts.trainers)} x seeds {list(opts.seeds)}, {opts.minutes:g} min "
        f"each, task={opts.task}, control={opts.control}, {opts.envs} trucks x {STEPS} steps, "
        f"{opts.threads} torch threads; held-out: {opts.episodes} episodes, seed "
        f"{opts.eval_seed}, difficulty {opts.eval_difficulty:g} and reached",
        flush=True,
    )
    rows = []
    for seed in opts.seeds:
        for trainer in opts.trainers:
            job = {"trainer": trainer, "seed": seed, "seconds": seconds, "task": opts.task,
                   "control": opts.control, "threads": opts.threads, "envs": opts.envs,
                   "episodes": opts.episodes, "eval_seed": opts.eval_seed,
                   "eval_difficulty": opts.eval_difficulty}  # fmt: skip
            row = _spawn(job, opts.threads)
            print(f"  {trainer} seed {seed}: " + ", ".join(f"{k} {v}" for k, v in row.items()
                                                          if k not in ("trainer", "seed")),
                  flush=True)  # fmt: skip
            rows.append(row)
    title = (
        f"Trainers, {opts.minutes:g} min each ({opts.threads} torch threads, control "
        f"{opts.control}); held-out success at difficulty {opts.eval_difficulty:g} "
        "(success_fixed) and at the difficulty reached"
    )
    table = print_table(
        title, rows, list(COLUMNS) + (["error"] if any("error" in r for r in rows) else [])
    )
    wall = time.perf_counter() - t_start
    print(f"bench trainers took {wall:.0f} s")
    payload = {"args": dataclasses.asdict(opts), "rows": rows, "table": table, "wall_s": wall,
               "steps_per_env": STEPS, "num_minibatches": MINIBATCHES}  # fmt: skip
    return {"rows": rows, "path": str(write_json("trainers", payload, opts.out))}


def _worker(argv: list[str]) -> int:
    """``python -m truckrl.bench.trainers JOB_JSON ROW_PATH``: :func:`run_one`, row to a file."""
    job, path = json.loads(argv[0]), Path(argv[1])
    path.write_text(json.dumps(run_one(job)))
    return 0


if __name__ == "__main__":
    sys.exit(_worker(sys.argv[1:]))
