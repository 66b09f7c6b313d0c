"""Environment throughput: env-steps/s of TruckEnv, batched vs. the paper's process layout.

Measured with a uniformly random policy (``action_spec.rand()``), resets included
(``step_and_maybe_reset``), after a warm-up that also absorbs ``torch.compile``:

* one batched ``TruckEnv`` (no extra processes) at N trucks, eager and compiled;
* ``ParallelEnv`` with W worker processes, each a batched ``TruckEnv`` of N / W trucks;
* the paper's layout: 24 worker processes each stepping one truck (``ParallelEnv(24, n=1)``),
  measured in the same run so the ratio is side by side;
* optionally (``--collector``) ``Collector`` frames/s with the real two-branch policy.

Two other sections replace those rows when asked for (both may be given):

* ``--scaling``: env-steps/s against the number of trucks N (1 ... 65,536), LiDAR beams
  (16 ... 256 at N = 1,024) and obstacle slots of the scene (``env.task.scene.max_obstacles``:
  0, 4, 16, 64, i.e. 8 ... 264 segment slots, at N = 1,024), compiled and (up to
  ``--eager-max-envs``) eager; a table, the JSON record and a PNG of three log-log panels
  (``--plot``, default ``docs/env_scaling.png``).
* ``--peers``: VMAS (optional ``bench`` extra) with the closest scenario it can express
  (:mod:`truckrl.bench.peers`) beside TruckEnv eager and compiled at the same N, measured in
  the same run, with the ratios.
"""

from __future__ import annotations

import argparse
import functools
import sys
import time

import torch
from torchrl.envs import EnvBase, ParallelEnv

from truckrl.bench import peers
from truckrl.bench.report import draw_loglog_panels, print_table, write_json
from truckrl.env import TruckEnv
from truckrl.tasks import NUM_FEATURES

TARGET_STEPS_PER_S = 100_000  # issue target on a 2-core CPU, 16 beams
TARGET_RATIO_VS_PAPER = 30.0  # best config >= 30x the paper layout in the same run
PAPER_WORKERS = 24  # paper: 24 single-truck worker processes


QUICK = {"envs": [1, 256], "parallel_envs": [], "steps": 10, "warmup": 2, "compile": "off"}

#: Sweeps of ``--scaling`` (full, ``--quick``): trucks N, beams R at N_ref, obstacle slots at N_ref.
SCALING = {
    "envs": [1, 16, 256, 1024, 4096, 16384, 65536],
    "beams": [16, 32, 64, 128, 256],
    "obstacles": [0, 4, 16, 64],
    "ref_envs": 1024,
}
SCALING_QUICK = {"envs": [1, 16, 64], "beams": [16, 32], "obstacles": [0, 4], "ref_envs": 16}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument(
        "--quick", action="store_true",
        help="a short run (under ~15 s): eager only, N = 1 and 256, no ParallelEnv or paper rows",
    )  # fmt: skip
    parser.add_argument(
        "--envs", type=int, nargs="+", default=[1, 24, 256, 1024, 4096],
        help="trucks N of the batched TruckEnv rows (default: 1 24 256 1024 4096)",
    )  # fmt: skip
    parser.add_argument("--workers", type=int, default=2, help="W of the ParallelEnv rows (>= 1)")
    parser.add_argument(
        "--parallel-envs", type=int, nargs="*", default=[1024, 4096],
        help="total trucks of the ParallelEnv rows, split over --workers (none: skip those rows)",
    )  # fmt: skip
    parser.add_argument("--steps", type=int, default=50, help="timed steps per measurement")
    parser.add_argument(
        "--warmup", type=int, default=5, help="untimed steps first (absorb compile)"
    )
    parser.add_argument(
        "--compile", choices=["both", "on", "off"], default="both",
        help="eager (off), torch.compile'd (on) or both rows",
    )  # fmt: skip
    parser.add_argument("--no-paper", action="store_true", help="skip the 24-process paper layout")
    parser.add_argument(
        "--collector", action="store_true", help="also Collector frames/s with the real policy"
    )
    parser.add_argument(
        "--scaling", action="store_true",
        help="instead of the rows above: steps/s against N, beams and obstacles; table, JSON, PNG",
    )  # fmt: skip
    parser.add_argument(
        "--eager-max-envs", type=int, default=4096,
        help="--scaling: largest N also measured eager (default 4096)",
    )  # fmt: skip
    parser.add_argument(
        "--plot", default="docs/env_scaling.png", help="--scaling: PNG path (three log-log panels)"
    )
    parser.add_argument(
        "--peers", action="store_true",
        help="instead of the rows above: VMAS beside TruckEnv at --peer-envs (needs the bench extra)",
    )  # fmt: skip
    parser.add_argument(
        "--peer-envs", type=int, default=1024, help="--peers: N of the side-by-side rows"
    )
    parser.add_argument("--device", default="cpu", help="torch device of the batched rows")
    parser.add_argument("--threads", type=int, help="torch threads in the main process")
    parser.add_argument("--seed", type=int, default=0, help="scene seed")
    parser.add_argument("--out", default="outputs/bench", help="folder for the JSON record")


def check_args(args: argparse.Namespace) -> None:
    """Apply ``--quick`` and reject bad values with one line (SystemExit 2) before any work."""
    if args.quick:
        for k, v in QUICK.items():
            setattr(args, k, v)
        args.no_paper = True
    bad = []
    if any(n < 1 for n in args.envs):
        bad.append(f"--envs {args.envs}: every N must be >= 1")
    if args.workers < 1:
        bad.append(f"--workers {args.workers}: must be >= 1")
    if any(n < args.workers for n in args.parallel_envs):
        bad.append(f"--parallel-envs {args.parallel_envs}: each must be >= --workers")
    if args.steps < 1:
        bad.append(f"--steps {args.steps}: must be >= 1")
    if args.warmup < 0:
        bad.append(f"--warmup {args.warmup}: must be >= 0")
    if args.threads is not None and args.threads < 1:
        bad.append(f"--threads {args.threads}: must be >= 1")
    try:
        torch.device(args.device)
    except (RuntimeError, TypeError):
        bad.append(f"--device {args.device!r}: not a torch device")
    if args.peer_envs < 1:
        bad.append(f"--peer-envs {args.peer_envs}: must be >= 1")
    if args.peers and not peers.vmas_available():
        bad.append(f"--peers needs VMAS: {peers.INSTALL_HINT}")
    if bad:
        print(f"error: {bad[0]}", file=sys.stderr)
        raise SystemExit(2)


def _make_env(
    n: int, compile: bool, device: str, seed: int, overrides: dict | None = None
) -> TruckEnv:
    if compile:
        # Every env of a new size or config compiles new graphs of the same functions (step,
        # observation): without a reset, dynamo stops compiling them after
        # torch._dynamo.config.recompile_limit (8) graphs and runs the later rows eagerly.
        torch._dynamo.reset()
    config = {"compile": compile, **(overrides or {})}
    return TruckEnv(num_envs=n, device=device, config=config, seed=seed)


def steps_per_second(env: EnvBase, steps: int, warmup: int) -> tuple[float, float]:
    """Random-policy env-steps/s (trucks x steps / wall time) and the warm-up seconds."""
    t0 = time.perf_counter()
    td = env.reset()
    for _ in range(warmup):
        td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
    warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(steps):
        td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
    if env.device.type == "cuda":
        torch.cuda.synchronize(env.device)
    return env.batch_size.numel() * steps / (time.perf_counter() - t0), warm


def run(args: argparse.Namespace) -> dict:
    check_args(args)
    t_start = time.perf_counter()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.scaling or args.peers:
        summary = {}
        if args.scaling:
            summary["scaling"] = run_scaling(args)
        if args.peers:
            summary["peers"] = run_peers(args)
        summary["wall_s"] = time.perf_counter() - t_start
        print(f"bench env took {summary['wall_s']:.1f} s" + (" (--quick)" if args.quick else ""))
        return summary
    modes = {"both": [False, True], "on": [True], "off": [False]}[args.compile]
    rows = []

    def record(layout, workers, per_worker, compiled, sps, warm):
        rows.append(
            {
                "layout": layout,
                "workers": workers,
                "envs/worker": per_worker,
                "trucks": workers * per_worker,
                "compile": compiled,
                "steps/s": sps,
                "warmup_s": warm,
            }
        )
        print(
            f"  {layout:8s} W={workers:<3d} n={per_worker:<6d} compile={compiled!s:5s} "
            f"{sps:12,.0f} steps/s",
            flush=True,
        )

    paper_sps = None
    if not args.no_paper:
        make = functools.partial(_make_env, 1, False, "cpu", args.seed)
        penv = ParallelEnv(PAPER_WORKERS, make, mp_start_method="spawn")
        try:
            penv.set_seed(args.seed)
            paper_sps, warm = steps_per_second(penv, args.steps, args.warmup)
        finally:
            penv.close()
        record("paper", PAPER_WORKERS, 1, False, paper_sps, warm)

    for compiled in modes:
        for n in args.envs:
            env = _make_env(n, compiled, args.device, args.seed)
            sps, warm = steps_per_second(env, args.steps, args.warmup)
            record("batched", 1, n, compiled, sps, warm)
        for total in args.parallel_envs:
            per = max(1, total // args.workers)
            make = functools.partial(_make_env, per, compiled, "cpu", args.seed)
            penv = ParallelEnv(args.workers, make, mp_start_method="spawn")
            try:
                penv.set_seed(args.seed)
                sps, warm = steps_per_second(penv, args.steps, args.warmup)
            finally:
                penv.close()
            record("parallel", args.workers, per, compiled, sps, warm)

    if paper_sps:
        for r in rows:
            r["x paper"] = r["steps/s"] / paper_sps
    if args.collector:
        rows += _collector_rows(args, modes[-1])

    table = print_table("TruckEnv env-steps/s (random policy, resets included)", rows)
    best = max(rows, key=lambda r: r["steps/s"])
    summary = {
        "best": best,
        "target_steps_per_s": TARGET_STEPS_PER_S,
        "target_met": best["steps/s"] >= TARGET_STEPS_PER_S,
        "paper_layout_steps_per_s": paper_sps,
        "best_x_paper": best["steps/s"] / paper_sps if paper_sps else None,
        "target_ratio_vs_paper": TARGET_RATIO_VS_PAPER,
    }
    print(
        f"\nbest: {best['layout']} W={best['workers']} n={best['envs/worker']} "
        f"compile={best['compile']}: {best['steps/s']:,.0f} steps/s"
        + (f" = {summary['best_x_paper']:.1f}x the paper layout" if paper_sps else "")
    )
    summary["wall_s"] = time.perf_counter() - t_start
    print(f"bench env took {summary['wall_s']:.1f} s" + (" (--quick)" if args.quick else ""))
    args_json = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    write_json(
        "env", {"rows": rows, "summary": summary, "table": table, "args": args_json}, args.out
    )
    return summary


def _collector_rows(args: argparse.Namespace, compiled: bool) -> list[dict]:
    """Collector frames/s with the real two-branch policy (random weights)."""
    from torchrl.collectors import Collector

    from truckrl.rl.network import ModelConfig, make_actor_critic

    rows = []
    for n in args.parallel_envs:
        env = _make_env(n, compiled, args.device, args.seed)
        actor = make_actor_critic(ModelConfig(), NUM_FEATURES, env.config.lidar.num_beams).actor
        frames = n * 32
        collector = Collector(env, actor, frames_per_batch=frames, total_frames=frames * 6)
        t0 = time.perf_counter()
        it = iter(collector)
        next(it)  # warm-up batch (compile)
        warm = time.perf_counter() - t0
        t0 = time.perf_counter()
        count = sum(batch.numel() for batch in it)
        fps = count / (time.perf_counter() - t0)
        collector.shutdown()
        rows.append(
            {
                "layout": "collector",
                "workers": 1,
                "envs/worker": n,
                "trucks": n,
                "compile": compiled,
                "steps/s": fps,
                "warmup_s": warm,
            }
        )
        print(f"  collector n={n} {fps:,.0f} frames/s", flush=True)
    return rows


def _modes(args: argparse.Namespace) -> list[bool]:
    return {"both": [True, False], "on": [True], "off": [False]}[args.compile]


def _scaled_steps(args: argparse.Namespace, n: int) -> int:
    """Timed steps at N trucks: about ``--steps`` x 1,024 trucks of work, 3 .. 4 x ``--steps``."""
    return int(min(4 * args.steps, max(3, round(args.steps * 1024 / n))))


def run_scaling(args: argparse.Namespace) -> dict:
    """The ``--scaling`` sweep: rows, table, JSON and PNG; returns the JSON payload."""
    sweep = SCALING_QUICK if args.quick else SCALING
    ref = sweep["ref_envs"]
    rows = []

    def measure(axis: str, value: int, n: int, compiled: bool, overrides: dict | None) -> None:
        env = _make_env(n, compiled, args.device, args.seed, overrides)  # fresh graphs
        steps = _scaled_steps(args, n)
        sps, warm = steps_per_second(env, steps, min(args.warmup, steps))
        mask = env.get_state()["mask"]
        rows.append(
            {
                "axis": axis,
                "value": value,
                "trucks": n,
                "beams": env.config.lidar.num_beams,
                "segment slots": mask.shape[-1],
                "valid segments": float(mask.sum(-1).float().mean()),
                "compile": compiled,
                "steps": steps,
                "steps/s": sps,
                "warmup_s": warm,
            }
        )
        print(
            f"  {axis:9s} {value:<6d} N={n:<6d} compile={compiled!s:5s} {sps:12,.0f} steps/s",
            flush=True,
        )

    for compiled in _modes(args):
        for n in sweep["envs"]:
            if compiled or n <= args.eager_max_envs:
                measure("trucks", n, n, compiled, None)
        for r in sweep["beams"]:
            measure("beams", r, ref, compiled, {"lidar": {"num_beams": r}})
        for k in sweep["obstacles"]:
            scene = {"task": {"name": "intersection", "scene": {"max_obstacles": k}}}
            measure("obstacles", k, ref, compiled, scene)
    table = print_table("TruckEnv env-steps/s scaling (random policy, resets included)", rows)

    def series(axis: str, x_key: str) -> dict[str, list[tuple[float, float]]]:
        out = {}
        for compiled in _modes(args):
            pts = [
                (float(r[x_key]), r["steps/s"])
                for r in rows
                if r["axis"] == axis and r["compile"] == compiled
            ]
            if pts:
                out["compiled" if compiled else "eager"] = pts
        return out

    panels = [
        ("env-steps/s vs trucks N", "trucks N", series("trucks", "trucks")),
        (f"vs LiDAR beams (N = {ref:,})", "beams R", series("beams", "beams")),
        (
            f"vs scene segment slots (N = {ref:,})",
            "segment slots E",
            series("obstacles", "segment slots"),
        ),
    ]
    draw_loglog_panels(panels, args.plot)
    print(f"wrote {args.plot}")
    payload = {"rows": rows, "table": table, "plot": str(args.plot), "sweep": sweep}
    payload["args"] = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    write_json("env-scaling", payload, args.out)
    return payload


def run_peers(args: argparse.Namespace) -> dict:
    """``--peers``: VMAS and TruckEnv (eager, compiled) at the same N in this run."""
    n = 16 if args.quick else args.peer_envs
    steps = _scaled_steps(args, n)
    warmup = min(args.warmup, steps)
    rows = []
    vm = peers.vmas_steps_per_second(n, steps, warmup, args.seed)
    rows.append({"simulator": "VMAS 1.5 (kinematic bicycle)", "compile": False, "trucks": n, **vm})
    print(f"  VMAS      N={n:<6d} {vm['steps/s']:12,.0f} steps/s", flush=True)
    for compiled in sorted(_modes(args)):
        env = _make_env(n, compiled, args.device, args.seed)  # fresh graphs
        sps, warm = steps_per_second(env, steps, warmup)
        rows.append(
            {"simulator": "TruckEnv", "compile": compiled, "trucks": n, "steps/s": sps,
             "warmup_s": warm}
        )  # fmt: skip
        print(f"  TruckEnv  N={n:<6d} compile={compiled!s:5s} {sps:12,.0f} steps/s", flush=True)
    for r in rows:
        r["x VMAS"] = r["steps/s"] / vm["steps/s"]
    table = print_table(
        f"TruckEnv vs VMAS at N = {n:,} (random actions, resets included, same run)",
        rows,
        ["simulator", "compile", "trucks", "steps/s", "x VMAS", "warmup_s"],
    )
    payload = {"rows": rows, "table": table, "vmas_scene": peers.__doc__}
    payload["args"] = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    write_json("env-peers", payload, args.out)
    return payload
