"""Training-iteration profile: frames/s and where one PPO iteration's time goes.

Runs the real training loop's pieces on the ``train`` config composed as ``python -m
truckrl.train`` composes it (Hydra overrides as positional arguments or ``--override
KEY=VALUE``; the planning and cloning that ``experiment=demos`` does first are not timed, and
its cloning term, ``demos.bc_coeff > 0``, runs on stand-in samples: the first batch's
observations and actions, the same work per minibatch as real demonstrations): the env from
``make_env``, the actor-critic, the ``Collector``, the curriculum bookkeeping, :class:`~truckrl.rl.ppo.PPO` and the TensorBoard
logger (into a temporary folder). After ``--warmup`` untimed iterations (they absorb
``torch.compile``), each of ``--iterations`` timed iterations is split into:

* ``collect_s``: ``next(collector)`` (env steps and policy forwards);
* ``stats_s``: difficulty check, episode statistics, start-order feed and curriculum update;
* ``gae_s``, ``loss_forward_s``, ``backward_s``, ``optimizer_s``, ``ppo_metrics_s``: the spans of
  :meth:`PPO.update <truckrl.rl.ppo.PPO.update>` (its ``timings`` argument);
* ``weights_s``: ``collector.update_policy_weights_()``;
* ``log_s``: the iteration's scalars written to TensorBoard (every iteration here, whatever
  ``log.interval`` says);
* ``other_s``: the rest of ``total_s``, so the parts add up to the total.

``frames/s`` is frames per iteration / ``total_s``. ``--profile ROWS`` adds one more iteration
(recorded, left out of the medians) with ``torch.profiler`` around its PPO update and prints the
ops with the most self time. Device work is synchronised at the span
ends (CUDA), so each span holds its own kernels.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from truckrl.bench.report import print_table, write_json

#: ``--quick``: a small eager run (no compile) that finishes well under a minute on 2 cores.
QUICK_OVERRIDES = (
    "collector.num_envs=64",
    "collector.steps_per_env=32",
    "ppo.num_epochs=2",
    "env.compile=false",
    "ppo.compile=false",
    "collector.compile_policy=false",
)
QUICK = {"iterations": 2, "warmup": 1}

#: Parts of an iteration, in order; they and ``other_s`` add up to ``total_s``.
PARTS = ("collect_s", "stats_s", "gae_s", "loss_forward_s", "backward_s", "optimizer_s")
PARTS += ("ppo_metrics_s", "weights_s", "log_s")
_PPO_SPANS = {"gae": "gae_s", "loss_forward": "loss_forward_s", "backward": "backward_s",
              "optimizer": "optimizer_s", "metrics": "ppo_metrics_s"}  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument(
        "overrides", nargs="*", metavar="KEY=VALUE",
        help="Hydra overrides of the train config, as for python -m truckrl.train "
        "(e.g. collector.num_envs=256 experiment=paper)",
    )  # fmt: skip
    parser.add_argument(
        "--override", action="append", default=[], metavar="KEY=VALUE",
        help="one more Hydra override (repeatable; same as a positional KEY=VALUE)",
    )  # fmt: skip
    parser.add_argument(
        "--iterations",
        type=int,
        default=5,
        metavar="N",
        help="timed training iterations (default: 5)",
    )
    parser.add_argument(
        "--warmup", type=int, default=2, metavar="N",
        help="untimed iterations first, absorbing torch.compile; with ppo.compile the first "
        "iteration after compiling still ran ~30 %% slower (default: 2)",
    )  # fmt: skip
    parser.add_argument(
        "--quick", action="store_true",
        help="a short run (under ~60 s on 2 cores): 64 trucks x 32 steps, 2 epochs, eager env, "
        "1 warm-up + 2 timed iterations, 1 torch thread unless --threads; explicit overrides "
        "still apply on top",
    )  # fmt: skip
    parser.add_argument(
        "--profile", type=int, default=0, metavar="ROWS",
        help="after the timed iterations, one more (left out of the medians) with torch.profiler "
        "over its PPO update; print its ROWS most expensive ops by self time (default: 0 = off)",
    )  # fmt: skip
    parser.add_argument(
        "--threads", type=int, metavar="N", help="torch threads (default: torch's choice)"
    )
    parser.add_argument(
        "--output",
        metavar="PATH",
        help="JSON record path (default: outputs/bench/train-<date>-<time>.json)",
    )


def check_args(args: argparse.Namespace) -> Any:
    """Apply ``--quick``, reject bad values with one line (SystemExit 2) before any work and
    return the composed, validated :class:`~truckrl.config.schemas.TrainConfig`."""
    if args.quick:
        for k, v in QUICK.items():
            setattr(args, k, v)
        if args.threads is None:  # a shared 2-core machine: 2 threads can be ~20x slower
            args.threads = 1
    overrides = [*(QUICK_OVERRIDES if args.quick else ()), *args.overrides, *args.override]
    args.all_overrides = overrides
    bad = []
    if args.iterations < 1:
        bad.append(f"--iterations must be >= 1 (got {args.iterations})")
    if args.warmup < 0:
        bad.append(f"--warmup must be >= 0 (got {args.warmup})")
    if args.profile < 0:
        bad.append(f"--profile must be >= 0 (got {args.profile})")
    if args.threads is not None and args.threads < 1:
        bad.append(f"--threads must be >= 1 (got {args.threads})")
    bad += [f"override {o!r}: write KEY=VALUE" for o in overrides if "=" not in o.lstrip("+~")]
    if args.output is not None and Path(args.output).is_dir():
        bad.append(f"--output {args.output}: is a folder; give a file path")
    if bad:
        _fail(bad[0])
    return compose_train_config(overrides)


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def compose_train_config(overrides: list[str]) -> Any:
    """``conf/train.yaml`` with ``overrides``, composed and validated as ``truckrl.train`` does;
    a user error prints one line and exits 2."""
    from truckrl.cli import compose_config
    from truckrl.config.fields import ConfigError
    from truckrl.config.schemas import TrainConfig

    try:
        return compose_config("train", TrainConfig, overrides)
    except ConfigError as e:
        _fail(str(e))


def _profiler(on: bool) -> Any:
    """``torch.profiler.profile`` (CPU, plus CUDA when available) when ``on``, else a no-op."""
    import contextlib

    if not on:
        return contextlib.nullcontext()
    acts = [torch.profiler.ProfilerActivity.CPU]
    if torch.cuda.is_available():
        acts.append(torch.profiler.ProfilerActivity.CUDA)
    return torch.profiler.profile(activities=acts)


def _top_ops(prof: Any, rows: int) -> list[dict[str, Any]]:
    """The ``rows`` ops of a finished profile with the most self CPU time [ms], with call counts."""
    if prof is None:
        return []
    events = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
    total = sum(e.self_cpu_time_total for e in events) or 1.0
    return [
        {
            "op": e.key,
            "self_cpu_ms": e.self_cpu_time_total / 1e3,
            "share": e.self_cpu_time_total / total,
            "calls": e.count,
        }  # fmt: skip
        for e in events[:rows]
    ]


def _compiles(tc: Any) -> str:
    """The three compile switches of a train config, for the headers."""
    return (
        f"env.compile={tc.env.compile}, ppo.compile={tc.ppo.compile}, "
        f"collector.compile_policy={tc.collector.compile_policy}"
    )


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def run(args: argparse.Namespace) -> dict:
    tc = check_args(args)
    t_start = time.perf_counter()
    if args.threads:
        torch.set_num_threads(args.threads)

    from truckrl.cli import seed_everything
    from truckrl.rl.cohorts import StartOrderFeed
    from truckrl.rl.collection import (
        check_difficulty,
        make_collector,
        make_env,
        set_difficulty,
    )
    from truckrl.rl.curriculum import Curriculum
    from truckrl.rl.logger import RunLogger
    from truckrl.rl.metrics import EpisodeTracker, iteration_scalars
    from truckrl.rl.network import LIDAR_KEY, OBS_KEY, make_actor_critic
    from truckrl.rl.ppo import PPO
    from truckrl.tasks import make_task

    device = torch.device(tc.device)
    seed_everything(tc.seed)
    c = tc.collector
    env = make_env(tc.env, c.workers, c.num_envs, tc.seed, 0, tc.device)
    task = make_task(tc.env)
    num_obs = env.observation_spec["observation"].shape[-1]
    num_beams = env.observation_spec["lidar"].shape[-1]
    ac = make_actor_critic(tc.model, num_obs, num_beams, env.action_spec.shape[-1])
    ac.model.to(tc.device)
    ppo = PPO(ac, tc.ppo)
    curriculum = Curriculum(tc.curriculum)
    tolerance = set_difficulty(env, curriculum.difficulty)
    collector = make_collector(env, ac, c.frames_per_batch, c.compile_policy, tc.device)
    tracker = EpisodeTracker(task.reward_keys, task.error_quantities)
    feed = StartOrderFeed()
    threads = torch.get_num_threads()
    print(
        f"bench train: {c.frames_per_batch:,} frames/iteration ({c.workers} x {c.num_envs} "
        f"trucks x {c.steps_per_env} steps), {_compiles(tc)}, "
        f"{tc.ppo.num_epochs} epochs x {tc.ppo.num_minibatches} minibatches, "
        f"{threads} torch threads, {args.warmup} warm-up + {args.iterations} timed iterations",
        flush=True,
    )
    rows: list[dict[str, Any]] = []
    frames_total = 0
    with tempfile.TemporaryDirectory(prefix="truckrl-bench-train-") as tb_dir:
        logger = RunLogger(tb_dir)
        batches = iter(collector)
        try:
            last = args.warmup + args.iterations  # one more, profiled and not timed, if asked
            for it in range(last + (1 if args.profile else 0)):
                spans: dict[str, float] = {}
                _sync(device)
                t0 = time.perf_counter()
                batch = next(batches)
                _sync(device)
                t1 = time.perf_counter()
                check_difficulty(batch, curriculum.difficulty)
                stats = tracker.update(batch)
                if curriculum.update(*feed.update(batch)):
                    tolerance = set_difficulty(env, curriculum.difficulty)
                _sync(device)
                t2 = time.perf_counter()
                if tc.demos.bc_coeff > 0 and ppo.demos is None:  # stand-in demonstrations
                    ppo.demos = batch.reshape(-1).select(OBS_KEY, LIDAR_KEY, "action").clone()
                    ppo.bc_coeff, ppo.bc_batch = tc.demos.bc_coeff, tc.demos.bc_batch
                with _profiler(it == last) as prof:
                    learn = ppo.update(batch, timings=spans)
                if "loss_bc" in learn:
                    learn["bc_coeff"] = ppo.bc_coeff
                t3 = time.perf_counter()
                collector.update_policy_weights_()
                _sync(device)
                t4 = time.perf_counter()
                frames = batch.numel()
                frames_total += frames
                timing = {"perf/fps": frames / (t4 - t0), "perf/collect_s": t1 - t0}
                cur = {**curriculum.state_dict(), "tolerance_position_m": tolerance[0],
                       "tolerance_heading_deg": tolerance[1]}  # fmt: skip
                scalars = iteration_scalars(stats, learn, cur, timing, task.error_quantities)
                logger.scalars(scalars, frames_total)
                t5 = time.perf_counter()
                total = t5 - t0
                label = "warm-up" if it < args.warmup else it - args.warmup + 1
                row: dict[str, Any] = {
                    "iteration": "profiled" if it == last else label,
                    "frames": frames,
                    "frames/s": frames / total,
                    "total_s": total,
                    "collect_s": t1 - t0,
                    "stats_s": t2 - t1,
                    **{name: spans.get(span, 0.0) for span, name in _PPO_SPANS.items()},
                    "weights_s": t4 - t3,
                    "log_s": t5 - t4,
                }
                row["other_s"] = max(0.0, total - sum(row[p] for p in PARTS))
                if "loss_bc" in learn:  # the cloning term ran (its time is in the PPO spans)
                    row["loss_bc"] = learn["loss_bc"]
                rows.append(row)
                print(
                    f"  iteration {row['iteration']}: {row['frames/s']:,.0f} frames/s "
                    f"({total:.2f} s, collect {row['collect_s']:.2f} s, "
                    f"update {t3 - t2:.2f} s)",
                    flush=True,
                )
        finally:
            logger.close()
            collector.shutdown()
            if not env.is_closed:
                env.close()

    top_ops = _top_ops(prof, args.profile) if args.profile else []
    if top_ops:
        print_table(f"torch.profiler: last PPO update, top {len(top_ops)} ops by self CPU", top_ops)
    timed = rows[args.warmup : last]
    median = {"iteration": "median"}
    for k in ("frames", "frames/s", "total_s", *PARTS, "other_s"):
        median[k] = statistics.median(float(r[k]) for r in timed)
    columns = ["iteration", "frames/s", "total_s", *PARTS, "other_s"]
    table = print_table(
        f"PPO training iteration ({threads} torch threads, {_compiles(tc)})",
        [*timed, median],
        columns,
    )
    share = {p: median[p] / median["total_s"] for p in (*PARTS, "other_s")}
    update = sum(median[p] for p in PARTS[2:7])
    print(
        f"\nmedian: {median['frames/s']:,.0f} frames/s; collection "
        f"{share['collect_s']:.0%}, PPO update {update / median['total_s']:.0%} "
        f"(loss forward {share['loss_forward_s']:.0%}, backward {share['backward_s']:.0%}, "
        f"optimizer {share['optimizer_s']:.0%}, GAE {share['gae_s']:.0%})"
    )
    wall = time.perf_counter() - t_start
    print(f"bench train took {wall:.1f} s" + (" (--quick)" if args.quick else ""))
    summary = {"median": median, "share": share, "torch_threads": threads, "wall_s": wall}
    config = {
        "overrides": args.all_overrides,
        "frames_per_batch": c.frames_per_batch,
        "workers": c.workers,
        "num_envs": c.num_envs,
        "steps_per_env": c.steps_per_env,
        "env_compile": tc.env.compile,
        "ppo_compile": tc.ppo.compile,
        "compile_policy": c.compile_policy,
        "num_epochs": tc.ppo.num_epochs,
        "num_minibatches": tc.ppo.num_minibatches,
        "bc_coeff": tc.demos.bc_coeff,
        "device": tc.device,
    }
    args_json = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    payload = {"rows": rows, "summary": summary, "config": config, "table": table,
               "profile": top_ops, "args": args_json}  # fmt: skip
    path = write_json("train", payload, path=args.output)
    summary["path"] = str(path)
    return summary
