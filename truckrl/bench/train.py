"""Training-iteration profile: frames/s and where one PPO iteration's time goes.

Times the real :meth:`Trainer.iterate <truckrl.rl.trainer.Trainer.iterate>` (what ``python -m
truckrl.train`` runs) on the ``train`` config composed as ``truckrl train`` composes
it, in a temporary run dir. The arguments are all ``KEY=VALUE``: the keys below are this
benchmark's own; every other one is a Hydra override of the training config, as for ``python -m
truckrl.train`` (``collector.num_envs=256``, ``experiment=paper``, ``seed=1``, ``device=cuda``).

The benchmark leaves out what is not per-iteration work: the planning and cloning that
``experiment=demos`` does first (its cloning term, ``demos.bc_coeff > 0``, runs on stand-in
samples: observations of a reset and random actions, the same work per minibatch as real
demonstrations), rollout videos, held-out checks, the progress bar and the final checkpoint.
After ``warmup`` untimed iterations (they absorb ``torch.compile``), each of ``iterations``
timed iterations is split into:

* ``collect_s``: ``next(collector)`` (env steps and policy forwards);
* ``stats_s``: difficulty check, episode statistics, start-order feed and curriculum update;
* ``gae_s``, ``loss_forward_s``, ``backward_s``, ``optimizer_s``, ``ppo_metrics_s``: the spans of
  :meth:`PPO.update <truckrl.rl.ppo.PPO.update>` (its ``timings`` argument);
* ``weights_s``: ``collector.update_policy_weights_()``;
* ``log_s``: the iteration's scalars to TensorBoard (every ``log.interval`` iterations) and the
  progress line;
* ``other_s``: the rest of ``total_s`` (a checkpoint when ``checkpoint.interval`` is due), so the
  parts add up to the total.

``frames/s`` is frames per iteration / ``total_s``. ``profile=ROWS`` adds one more iteration
(recorded, left out of the medians) under ``torch.profiler`` and prints the ops with the most
self time. Device work is synchronised at the span ends (CUDA), so each span holds its own
kernels.
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from truckrl.bench.report import fill_unset, print_table, write_json
from truckrl.config.fields import param, validate

#: ``quick=true``: a small eager run (no compile): a check that the benchmark runs, not a figure.
QUICK_OVERRIDES = (
    "collector.num_envs=64",
    "collector.steps_per_env=32",
    "ppo.num_epochs=2",
    "env.compile=false",
    "ppo.compile=false",
    "collector.compile_policy=false",
)
#: What ``quick=true`` sets unless given (one torch thread: a small batch on a shared machine).
QUICK = {"iterations": 2, "warmup": 1, "threads": 1}

#: Parts of an iteration, in order; they and ``other_s`` add up to ``total_s``.
PARTS = ("collect_s", "stats_s", "gae_s", "loss_forward_s", "backward_s", "optimizer_s")
PARTS += ("ppo_metrics_s", "weights_s", "log_s")
_PPO_SPANS = {"gae": "gae_s", "loss_forward": "loss_forward_s", "backward": "backward_s",
              "optimizer": "optimizer_s", "metrics": "ppo_metrics_s"}  # fmt: skip


@dataclass
class TrainBenchConfig:
    """``truckrl bench train``'s own keys (every other key is a training override)."""

    iterations: int = param(5, lo=1, hi=1e6, unit="iterations", doc="timed training iterations")
    warmup: int = param(
        2, lo=0, hi=1e6, unit="iterations", doc="untimed iterations first (absorb torch.compile)"
    )
    quick: bool = param(
        False,
        doc="a short run: 64 trucks x 32 steps, 2 epochs, eager, 1 warm-up + 2 timed "
        "iterations, 1 torch thread (keys and overrides given still apply)",
    )
    profile: int = param(
        0, lo=0, hi=10_000, unit="rows",
        doc="one more iteration under torch.profiler; print its ROWS ops with most self time "
        "(0: off)",
    )  # fmt: skip
    threads: int | None = param(None, lo=1, hi=4096, doc="torch threads (null: torch's choice)")
    out: str | None = param(
        None, doc="JSON record: a .json path or a folder (null: outputs/bench/train-<time>.json)"
    )

    def __post_init__(self) -> None:
        validate(self)


def parse(argv: list[str]) -> tuple[TrainBenchConfig, Any, list[str]]:
    """Split ``argv`` into this benchmark's keys and training overrides; apply ``quick``; return
    the options, the composed, validated :class:`~truckrl.config.schemas.TrainConfig` and the
    overrides. Bad input: one line, exit 2, before any work."""
    from truckrl.cli import fail, key_value_config

    own_keys = {f.name for f in dataclasses.fields(TrainBenchConfig)}
    own, overrides = [], []
    for arg in argv:
        key, sep, _ = arg.partition("=")
        mine = arg.startswith("-") or key in own_keys or not (sep or arg.startswith("~"))
        (own if mine else overrides).append(arg)
    opts = key_value_config(TrainBenchConfig, own, "truckrl bench train", __doc__)
    if opts.quick:
        fill_unset(opts, own, QUICK)
        overrides = [*QUICK_OVERRIDES, *overrides]
    if opts.out is not None and Path(opts.out).suffix != ".json" and Path(opts.out).is_file():
        fail(f"out = {opts.out!r}: is a file, not a .json path or a folder")
    return opts, compose_train_config(overrides), overrides


def compose_train_config(overrides: list[str]) -> Any:
    """``conf/train.yaml`` with ``overrides``, composed and validated as ``truckrl.train`` does;
    a user error prints one line and exits 2."""
    from truckrl.cli import compose_config, fail
    from truckrl.config.fields import ConfigError
    from truckrl.config.schemas import TrainConfig

    try:
        return compose_config("train", TrainConfig, overrides)
    except ConfigError as e:
        fail(str(e))


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


def _bench_trainer(tc: Any, run_dir: Path) -> Any:
    """A :class:`~truckrl.rl.trainer.Trainer` whose demonstrations are stand-ins (imported here:
    ``--help`` answers before torchrl and the env load)."""
    from truckrl.cli import seed_everything
    from truckrl.env import LIDAR_KEY, OBS_KEY
    from truckrl.rl.trainer import Trainer

    class BenchTrainer(Trainer):
        def demonstration_samples(self, fresh: Any) -> Any:
            """Observations of a reset and random actions: the cloning term's work, no planning."""
            td = self.env.reset()
            td.set("action", self.env.action_spec.rand())
            return td.select(OBS_KEY, LIDAR_KEY, "action").reshape(-1).clone()

    trainer = BenchTrainer(tc, run_dir, sync_timings=True)
    seed_everything(tc.seed)
    return trainer


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _row(label: Any, frames: int, total: float, spans: dict[str, float]) -> dict[str, Any]:
    """One iteration's record: frames/s, total and :data:`PARTS` [s], ``other_s`` the rest."""
    row: dict[str, Any] = {"iteration": label, "frames": frames, "frames/s": frames / total,
                           "total_s": total, "collect_s": spans["collect_s"],
                           "stats_s": spans["stats_s"]}  # fmt: skip
    row.update({name: spans.get(span, 0.0) for span, name in _PPO_SPANS.items()})
    row.update(weights_s=spans["weights_s"], log_s=spans["log_s"])
    row["other_s"] = max(0.0, total - sum(row[p] for p in PARTS))
    return row


def run(parsed: tuple[TrainBenchConfig, Any, list[str]]) -> dict:
    """Time ``warmup + iterations`` (+1 profiled) :meth:`Trainer.iterate` calls; print the table,
    write the JSON record; return the summary."""
    opts, tc, overrides = parsed
    t_start = time.perf_counter()
    if opts.threads:
        torch.set_num_threads(opts.threads)
    threads = torch.get_num_threads()
    _print_header(opts, tc, threads)
    rows, prof = _iterations(opts, tc)
    top_ops = _top_ops(prof, opts.profile) if opts.profile else []
    if top_ops:
        print_table(f"torch.profiler: one iteration, top {len(top_ops)} ops by self CPU", top_ops)
    timed = rows[opts.warmup : opts.warmup + opts.iterations]
    median = _median_row(timed)
    columns = ["iteration", "frames/s", "total_s", *PARTS, "other_s"]
    title = f"PPO training iteration ({threads} torch threads, {_compiles(tc)})"
    table = print_table(title, [*timed, median], columns)
    share = _print_shares(median)
    wall = time.perf_counter() - t_start
    print(f"bench train took {wall:.1f} s" + (" (quick)" if opts.quick else ""))
    summary = {"median": median, "share": share, "torch_threads": threads, "wall_s": wall}
    payload = {"rows": rows, "summary": summary, "config": _config_record(tc, overrides),
               "table": table, "profile": top_ops, "args": dataclasses.asdict(opts)}  # fmt: skip
    summary["path"] = str(write_json("train", payload, opts.out))
    return summary


def _print_header(opts: TrainBenchConfig, tc: Any, threads: int) -> None:
    """The run's first line: batch shape, compile switches, PPO passes, threads, iterations."""
    c = tc.collector
    print(
        f"bench train: {c.frames_per_batch:,} frames/iteration ({c.workers} x {c.num_envs} "
        f"trucks x {c.steps_per_env} steps), {_compiles(tc)}, "
        f"{tc.ppo.num_epochs} epochs x {tc.ppo.num_minibatches} minibatches, "
        f"{threads} torch threads, {opts.warmup} warm-up + {opts.iterations} timed iterations",
        flush=True,
    )


def _iterations(opts: TrainBenchConfig, tc: Any) -> tuple[list[dict[str, Any]], Any]:
    """Run the warm-up, timed and (``profile > 0``) profiled iterations in a throw-away run dir,
    with videos, held-out checks, the progress bar and demonstrations off (not per-iteration
    work). Returns one :func:`_row` per iteration, in order, and the last iteration's profiler
    (``None`` when not profiled)."""
    log = dataclasses.replace(
        tc.log, video_interval=0, eval_interval_min=0, eval_interval_frames=None, progress_bar=False
    )
    timed_tc = dataclasses.replace(tc, log=log, demos=dataclasses.replace(tc.demos, episodes=0))
    device = torch.device(tc.device)
    rows: list[dict[str, Any]] = []
    last = opts.warmup + opts.iterations  # one more, profiled and not timed, if asked
    prof = None
    with tempfile.TemporaryDirectory(prefix="truckrl-bench-train-") as run_dir:
        trainer = _bench_trainer(timed_tc, Path(run_dir))
        trainer.setup()
        try:
            for it in range(last + (1 if opts.profile else 0)):
                label = "warm-up" if it < opts.warmup else it - opts.warmup + 1
                row, prof = _time_iteration(trainer, device, "profiled" if it == last else label)
                rows.append(row)
        finally:
            trainer.close(None)  # no final checkpoint: the run dir is thrown away
    return rows, prof


def _time_iteration(trainer: Any, device: torch.device, label: Any) -> tuple[dict, Any]:
    """One :meth:`Trainer.iterate`, synchronised at both ends, under the profiler when
    ``label == "profiled"``; prints its progress line. Returns its row (with ``loss_bc`` when
    the cloning term ran) and the profiler (``None`` when off)."""
    spans: dict[str, float] = {}
    _sync(device)
    t0 = time.perf_counter()
    with _profiler(label == "profiled") as prof:
        metrics = trainer.iterate(timings=spans)
    _sync(device)
    total = time.perf_counter() - t0
    row = _row(label, int(metrics["frames"]), total, spans)
    if "loss_bc" in metrics:  # the cloning term ran (its time is in the PPO spans)
        row["loss_bc"] = metrics["loss_bc"]
    print(
        f"  iteration {row['iteration']}: {row['frames/s']:,.0f} frames/s "
        f"({total:.2f} s, collect {row['collect_s']:.2f} s, "
        f"update {spans['update_s']:.2f} s)",
        flush=True,
    )
    return row, prof


def _median_row(timed: list[dict[str, Any]]) -> dict[str, Any]:
    """The median over the timed iterations of frames, frames/s and every time [s]."""
    median: dict[str, Any] = {"iteration": "median"}
    for k in ("frames", "frames/s", "total_s", *PARTS, "other_s"):
        median[k] = statistics.median(float(r[k]) for r in timed)
    return median


def _print_shares(median: dict[str, Any]) -> dict[str, float]:
    """Each part's share of the median ``total_s``; prints the median line. Returns the shares."""
    share = {p: median[p] / median["total_s"] for p in (*PARTS, "other_s")}
    update = sum(median[p] for p in PARTS[2:7])
    print(
        f"\nmedian: {median['frames/s']:,.0f} frames/s; collection "
        f"{share['collect_s']:.0%}, PPO update {update / median['total_s']:.0%} "
        f"(loss forward {share['loss_forward_s']:.0%}, backward {share['backward_s']:.0%}, "
        f"optimizer {share['optimizer_s']:.0%}, GAE {share['gae_s']:.0%})"
    )
    return share


def _config_record(tc: Any, overrides: list[str]) -> dict[str, Any]:
    """The JSON record's ``config``: the overrides and the settings that set the work per
    iteration."""
    c = tc.collector
    return {
        "overrides": overrides,
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
