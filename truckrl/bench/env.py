"""Environment throughput: env-steps/s of TruckEnv, batched vs. the paper's process layout.

Measured with a uniformly random policy (``action_spec.rand()``), resets included
(``step_and_maybe_reset``), after a warm-up that also absorbs ``torch.compile``:

* one batched ``TruckEnv`` (no extra processes) at N trucks, eager and compiled;
* ``ParallelEnv`` with W worker processes, each a batched ``TruckEnv`` of N / W trucks;
* the paper's layout: 24 worker processes each stepping one truck (``ParallelEnv(24, n=1)``),
  measured in the same run so the ratio is side by side;
* optionally (``collector=true``) ``Collector`` frames/s with the real two-branch policy;
* optionally (``gym=true``) the Gymnasium door beside each batched row:
  ``gymnasium.make_vec(<default task's id>, num_envs=N)`` (:mod:`truckrl.gym`, numpy arrays out,
  random numpy actions in) and the TorchRL row measured ``repeats`` times each, alternating,
  in the same run; the rows carry the medians and ``x torchrl``, the median over the pairs of
  the Gymnasium run's env-steps/s over the TorchRL run's just before it.

Two other sections replace those rows when asked for (both may be given):

* ``scaling=true``: env-steps/s against the number of trucks N (1 ... 65,536), LiDAR beams
  (16 ... 256 at N = 1,024) and obstacle slots of the scene (``env.task.scene.max_obstacles``:
  0, 4, 16, 64, i.e. 8 ... 264 segment slots, at N = 1,024), compiled and (up to
  ``eager_max_envs``) eager; a table, the JSON record and a PNG of three log-log panels
  (``plot``, default ``docs/env_scaling.png``).
* ``peers=true``: VMAS (optional ``bench`` extra) with the closest scenario it can express
  (:mod:`truckrl.bench.peers`) beside TruckEnv eager and compiled at the same N, measured in
  the same run, with the ratios.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import statistics
import time
from dataclasses import dataclass

import numpy as np
import torch
from torchrl.envs import EnvBase, ParallelEnv

from truckrl.bench import peers
from truckrl.bench.report import (
    DEFAULT_OUT_DIR,
    draw_loglog_panels,
    fill_unset,
    print_table,
    write_json,
)
from truckrl.config.fields import param, validate
from truckrl.env import TruckEnv
from truckrl.tasks import MAX_DIFFICULTY

TARGET_STEPS_PER_S = 100_000  # the target, 16 beams, on a CPU
TARGET_RATIO_VS_PAPER = 30.0  # best config >= 30x the paper layout in the same run
PAPER_WORKERS = 24  # paper: 24 single-truck worker processes


#: What ``quick=true`` sets, unless given.
QUICK = {"envs": (1, 256), "parallel_envs": (), "steps": 10, "warmup": 2, "compile": "off"}
QUICK |= {"paper": False}

#: Sweeps of ``scaling=true`` (full, ``quick=true``): trucks N, beams R at N_ref, obstacle slots at N_ref.
SCALING = {
    "envs": [1, 16, 256, 1024, 4096, 16384, 65536],
    "beams": [16, 32, 64, 128, 256],
    "obstacles": [0, 4, 16, 64],
    "ref_envs": 1024,
}
SCALING_QUICK = {"envs": [1, 16, 64], "beams": [16, 32], "obstacles": [0, 4], "ref_envs": 16}


@dataclass
class EnvBenchConfig:
    """``truckrl bench env``'s keys."""

    quick: bool = param(
        False, doc="a short run: eager only, N = 1 and 256, no ParallelEnv or paper rows "
        "(keys given still apply)",
    )  # fmt: skip
    envs: tuple[int, ...] = param(
        (1, 24, 256, 1024, 4096), lo=1, hi=1e8, unit="trucks", doc="N of the batched TruckEnv rows"
    )
    workers: int = param(2, lo=1, hi=1024, unit="processes", doc="W of the ParallelEnv rows")
    parallel_envs: tuple[int, ...] = param(
        (1024, 4096), lo=1, hi=1e8, min_len=0, unit="trucks",
        doc="total trucks of the ParallelEnv rows, split over workers ([]: no such rows)",
    )  # fmt: skip
    steps: int = param(50, lo=1, hi=1e7, unit="steps", doc="timed steps per measurement")
    warmup: int = param(5, lo=0, hi=1e7, unit="steps", doc="untimed steps first (absorb compile)")
    compile: str = param(
        "both", choices=("both", "on", "off"), doc="eager (off), torch.compile'd (on) or both rows"
    )
    paper: bool = param(True, doc="the 24-process paper layout row")
    collector: bool = param(False, doc="also Collector frames/s with the real policy")
    gym: bool = param(
        False, doc="also gymnasium.make_vec's VectorEnv at each batched N (needs the gym extra)"
    )
    repeats: int = param(
        3, lo=1, hi=1000,
        doc="gym, tasks: measurements of each row, alternating (medians)",
    )  # fmt: skip
    scaling: bool = param(
        False, doc="instead of the rows above: steps/s against N, beams and obstacles; PNG too"
    )
    eager_max_envs: int = param(
        4096, lo=1, hi=1e8, unit="trucks", doc="scaling: largest N also measured eager"
    )
    plot: str = param("docs/env_scaling.png", doc="scaling: PNG path (three log-log panels)")
    peers: bool = param(
        False, doc="instead of the rows above: VMAS beside TruckEnv (needs the bench extra)"
    )
    peer_envs: int = param(1024, lo=1, hi=1e8, unit="trucks", doc="peers: N of the rows")
    device: str = param("cpu", doc="torch device of the batched rows (cpu, cuda)")
    threads: int | None = param(
        None, lo=1, hi=4096, doc="torch threads in the main process (null: torch's choice)"
    )
    seed: int = param(0, lo=0, hi=2**31 - 1, doc="scene seed")
    task: str | None = param(
        None, doc="task folder of the throughput rows (env.task.name; null: the default task)"
    )
    tasks: tuple[str, ...] = param(
        (), min_len=0,
        doc="task folders timed back to back at each batched N, alternating (instead of task)",
    )  # fmt: skip
    parts: bool = param(
        False, doc="batched rows: also the ms per step of each part of the step (episode draws, "
        "their preparation, restarts, the transition, the rest; truckrl.env.timing)",
    )  # fmt: skip
    difficulty: float = param(
        0.0, lo=0.0, hi=MAX_DIFFICULTY,
        doc="curriculum difficulty the envs step at (where a task's scenes grow with it: "
        "network has traffic from 1 on)",
    )  # fmt: skip
    out: str = param(str(DEFAULT_OUT_DIR), doc="JSON record: a folder, or a .json path")

    def __post_init__(self) -> None:
        validate(self)


def parse(argv: list[str]) -> EnvBenchConfig:
    """``KEY=VALUE`` arguments into :class:`EnvBenchConfig`, ``quick`` applied; a bad value is
    one line, exit 2, before any work."""
    from truckrl.cli import fail, key_value_config

    args = key_value_config(EnvBenchConfig, argv, "truckrl bench env", __doc__)
    if args.quick:
        fill_unset(args, argv, QUICK)
    if any(n < args.workers for n in args.parallel_envs):
        fail(
            f"parallel_envs = {list(args.parallel_envs)}: each must be >= workers ({args.workers})"
        )
    try:
        torch.device(args.device)
    except (RuntimeError, TypeError):
        fail(f"device = {args.device!r}: not a torch device (cpu, cuda, cuda:1)")
    if args.peers and not peers.vmas_available():
        fail(f"peers=true needs VMAS: {peers.INSTALL_HINT}")
    if args.gym and importlib.util.find_spec("gymnasium") is None:
        fail("gym=true needs Gymnasium: pip install 'truckrl[gym]'")
    if args.task is not None:
        from truckrl.config.fields import ConfigError
        from truckrl.tasks import task_class

        try:
            task_class(args.task)
        except ConfigError as e:
            fail(str(e).replace("env.task.name", "task", 1))
        if args.scaling or args.peers or args.gym:
            fail(f"task = {args.task!r}: scaling, peers and gym measure the default task only")
    if args.parts and (args.scaling or args.peers or args.gym):
        fail("parts=true times the batched rows: not with scaling, peers or gym")
    if args.difficulty and (args.scaling or args.peers or args.gym):
        fail(f"difficulty = {args.difficulty:g}: scaling, peers and gym step at difficulty 0")
    if args.tasks:
        from truckrl.config.fields import ConfigError
        from truckrl.tasks import task_class

        for i, name in enumerate(args.tasks):
            try:
                task_class(name)
            except ConfigError as e:
                fail(str(e).replace("env.task.name", f"tasks[{i}]", 1))
        if args.task is not None or args.scaling or args.peers or args.gym:
            fail(
                f"tasks = {list(args.tasks)}: not with task, scaling, peers or gym "
                "(each measures one task)"
            )
    return args


def _make_env(
    n: int,
    compile: bool,
    device: str,
    seed: int,
    overrides: dict | None = None,
    task: str | None = None,
    fresh_graphs: bool = True,
    difficulty: float = 0.0,
) -> TruckEnv:
    if compile and fresh_graphs:
        # Every env of a new size or config compiles new graphs of the same functions (step,
        # observation): without a reset, dynamo stops compiling them after
        # torch._dynamo.config.recompile_limit (8) graphs and runs the later rows eagerly.
        torch._dynamo.reset()
    config = {"compile": compile, **(overrides or {})}
    if task is not None:
        config["task"] = {"name": task}
    env = TruckEnv(num_envs=n, device=device, config=config, seed=seed)
    env.set_difficulty(difficulty)  # before the first reset, which draws the episodes
    return env


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


def steps_per_second_parts(
    env: TruckEnv, steps: int, warmup: int
) -> tuple[float, float, dict[str, float]]:
    """:func:`steps_per_second` of a batched ``TruckEnv`` with the timed loop's wall time split
    into the parts of :mod:`truckrl.env.timing`: env-steps/s, the warm-up seconds and
    ``{part: ms per step}`` (``other``: the rest; ``total``: all of it)."""
    from truckrl.env.timing import timed_parts

    t0 = time.perf_counter()
    td = env.reset()
    for _ in range(warmup):
        td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
    warm = time.perf_counter() - t0
    with timed_parts(env) as parts:
        t0 = time.perf_counter()
        for _ in range(steps):
            td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
        if env.device.type == "cuda":
            torch.cuda.synchronize(env.device)
        wall = time.perf_counter() - t0
    ms = {k: 1e3 * v / steps for k, v in parts.as_dict().items()}
    ms["other"] = 1e3 * wall / steps - sum(ms.values())
    ms["total"] = 1e3 * wall / steps
    return env.batch_size.numel() * steps / wall, warm, ms


def _measure(env: TruckEnv, args: EnvBenchConfig) -> tuple[float, float, dict[str, float] | None]:
    """One measurement of a batched row: :func:`steps_per_second`, or with ``parts=true``
    :func:`steps_per_second_parts`."""
    if args.parts:
        return steps_per_second_parts(env, args.steps, args.warmup)
    return (*steps_per_second(env, args.steps, args.warmup), None)


def _median_parts(runs: list[dict[str, float] | None]) -> dict[str, float] | None:
    """Each part's median over the runs (ms per step), or ``None`` without parts."""
    if runs[0] is None:
        return None
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}  # type: ignore[index]


def _print_parts(label: str, ms: dict[str, float]) -> None:
    cells = "  ".join(f"{k} {v:.2f}" for k, v in ms.items())
    print(f"  {label}: ms per step: {cells}", flush=True)


def gym_steps_per_second(venv, steps: int, warmup: int, seed: int) -> tuple[float, float]:
    """:func:`steps_per_second` of a Gymnasium ``VectorEnv``: uniformly random numpy actions
    (drawn before the clock starts; a table the size of the warm-up plus timed steps),
    autoreset included; env-steps/s and the warm-up seconds."""
    n = venv.num_envs
    shape = (warmup + steps, *venv.action_space.shape)
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, shape).astype(np.float32)
    t0 = time.perf_counter()
    venv.reset(seed=seed)
    for a in actions[:warmup]:
        venv.step(a)
    warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    for a in actions[warmup:]:
        venv.step(a)
    if venv.unwrapped.env.device.type == "cuda":
        torch.cuda.synchronize(venv.unwrapped.env.device)
    return n * steps / (time.perf_counter() - t0), warm


def _make_gym(n: int, compile: bool, device: str, seed: int):
    """``gymnasium.make_vec`` of the default task's id: ``n`` trucks, numpy arrays on CPU
    (torch tensors on another device), the same config as :func:`_make_env`."""
    import gymnasium

    import truckrl.gym
    from truckrl.tasks.config import DEFAULT_TASK

    if compile:
        torch._dynamo.reset()  # as _make_env
    tensors = torch.device(device).type != "cpu"
    return gymnasium.make_vec(
        truckrl.gym.env_id(DEFAULT_TASK),
        num_envs=n,
        seed=seed,
        device=device,
        tensors=tensors,
        compile=compile,
    )


def run(args: EnvBenchConfig) -> dict:
    """``truckrl bench env``: the throughput rows (or the scaling / peers sections), printed,
    written as JSON; returns the summary."""
    t_start = time.perf_counter()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.scaling or args.peers:
        return _run_sections(args, t_start)
    modes = {"both": [False, True], "on": [True], "off": [False]}[args.compile]
    rows: list[dict] = []
    paper_sps = _paper_row(args, rows) if args.paper else None
    for compiled in modes:
        _throughput_rows(args, compiled, rows)
    if paper_sps:
        for r in rows:
            r["x paper"] = r["steps/s"] / paper_sps
    if args.collector:
        rows += _collector_rows(args, modes[-1])
    return _summarize(args, rows, paper_sps, t_start)


def _print_wall(args: EnvBenchConfig, summary: dict, t_start: float) -> None:
    """Store the run's wall time (s) in ``summary["wall_s"]`` and print it."""
    summary["wall_s"] = time.perf_counter() - t_start
    print(f"bench env took {summary['wall_s']:.1f} s" + (" (quick)" if args.quick else ""))


def _run_sections(args: EnvBenchConfig, t_start: float) -> dict:
    """``scaling=true`` and/or ``peers=true``: those sections instead of the throughput rows;
    returns ``{"scaling"?, "peers"?, "wall_s"}``."""
    summary = {}
    if args.scaling:
        summary["scaling"] = run_scaling(args)
    if args.peers:
        summary["peers"] = run_peers(args)
    _print_wall(args, summary, t_start)
    return summary


def _record(
    rows: list[dict], layout: str, workers: int, per_worker: int, compiled: bool, sps, warm
) -> None:
    """Append one throughput row (``sps`` env-steps/s, ``warm`` warm-up s) and print it."""
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


def _parallel_steps_per_second(
    args: EnvBenchConfig, workers: int, per_worker: int, compiled: bool
) -> tuple[float, float]:
    """Env-steps/s and warm-up s of a ``ParallelEnv`` of ``workers`` spawned processes, each a
    CPU ``TruckEnv`` of ``per_worker`` trucks; the processes are closed after."""
    make = functools.partial(
        _make_env, per_worker, compiled, "cpu", args.seed, task=args.task,
        difficulty=args.difficulty,
    )  # fmt: skip
    penv = ParallelEnv(workers, make, mp_start_method="spawn")
    try:
        penv.set_seed(args.seed)
        return steps_per_second(penv, args.steps, args.warmup)
    finally:
        penv.close()


def _paper_row(args: EnvBenchConfig, rows: list[dict]) -> float:
    """The paper's layout (24 single-truck eager processes): record its row, return its
    env-steps/s, the reference of the ``x paper`` column."""
    paper_sps, warm = _parallel_steps_per_second(args, PAPER_WORKERS, 1, False)
    _record(rows, "paper", PAPER_WORKERS, 1, False, paper_sps, warm)
    return paper_sps


def _throughput_rows(args: EnvBenchConfig, compiled: bool, rows: list[dict]) -> None:
    """One compile mode's rows: batched ``TruckEnv`` at each N of ``envs``, then
    ``ParallelEnv`` at each total of ``parallel_envs`` (split over ``workers``)."""
    for n in args.envs:
        if args.tasks:
            _task_rows(args, compiled, n, rows)
            continue
        env = _make_env(
            n, compiled, args.device, args.seed, task=args.task, difficulty=args.difficulty
        )
        if not args.gym:
            sps, warm, ms = _measure(env, args)
            _record(rows, "batched", 1, n, compiled, sps, warm)
            if ms is not None:
                rows[-1]["parts_ms"] = ms
                _print_parts(f"N={n}", ms)
            continue
        venv = _make_gym(n, compiled, args.device, args.seed)
        torchrl_runs, gym_runs = [], []
        for _ in range(args.repeats):  # alternating: both rows see the same machine load
            torchrl_runs.append(steps_per_second(env, args.steps, args.warmup))
            gym_runs.append(gym_steps_per_second(venv, args.steps, args.warmup, args.seed))
        venv.close()
        for layout, runs in (("batched", torchrl_runs), ("gym", gym_runs)):
            sps = statistics.median(r[0] for r in runs)
            _record(rows, layout, 1, n, compiled, sps, runs[0][1])
            rows[-1]["runs"] = [r[0] for r in runs]
        # each gym run over the TorchRL run just before it, then the median: robust to the
        # load drifting during the measurement, where a ratio of the two medians is not
        pairs = [g[0] / t[0] for t, g in zip(torchrl_runs, gym_runs, strict=True)]
        rows[-1]["x torchrl"] = statistics.median(pairs)
        print(f"  gym / torchrl at N={n}: {rows[-1]['x torchrl']:.3f}", flush=True)
    for total in args.parallel_envs:
        per = max(1, total // args.workers)
        sps, warm = _parallel_steps_per_second(args, args.workers, per, compiled)
        _record(rows, "parallel", args.workers, per, compiled, sps, warm)


def _task_rows(args: EnvBenchConfig, compiled: bool, n: int, rows: list[dict]) -> None:
    """``tasks=[...]``: one batched ``TruckEnv`` of ``n`` trucks per task, measured ``repeats``
    times each, alternating (every task sees the same machine load); a row per task with its
    median, its runs and ``x <first task>``, the median over the rounds of its run over the
    first task's run of that round."""
    # one graph reset for the whole set: a reset between them would drop the graphs of the
    # envs made before it, and each would compile again inside the timed loop of a later round
    envs = [
        _make_env(
            n,
            compiled,
            args.device,
            args.seed,
            task=t,
            fresh_graphs=i == 0,
            difficulty=args.difficulty,
        )
        for i, t in enumerate(args.tasks)
    ]
    runs: list[list[tuple[float, float, dict[str, float] | None]]] = [[] for _ in envs]
    for _ in range(args.repeats):
        for env, task_runs in zip(envs, runs, strict=True):
            task_runs.append(_measure(env, args))
    ref = f"x {args.tasks[0]}"
    for task, task_runs in zip(args.tasks, runs, strict=True):
        sps = statistics.median(r[0] for r in task_runs)
        _record(rows, "batched", 1, n, compiled, sps, task_runs[0][1])
        rows[-1]["task"] = task
        rows[-1]["runs"] = [r[0] for r in task_runs]
        pairs = [r[0] / f[0] for f, r in zip(runs[0], task_runs, strict=True)]
        rows[-1][ref] = statistics.median(pairs)
        print(f"  {task} / {args.tasks[0]} at N={n}: {rows[-1][ref]:.4f}", flush=True)
        ms = _median_parts([r[2] for r in task_runs])
        if ms is not None:
            rows[-1]["parts_ms"] = ms
            _print_parts(task, ms)
            # the same ratio with each run's episode draws left out of both tasks' step time:
            # what the task's step costs beside the first task's, its scene generator aside
            bare = [
                (f[2]["total"] - f[2]["draw"]) / (r[2]["total"] - r[2]["draw"])  # type: ignore[index]
                for f, r in zip(runs[0], task_runs, strict=True)
            ]
            rows[-1][f"{ref} without draws"] = statistics.median(bare)
            print(
                f"  {task} / {args.tasks[0]} at N={n}, draws left out: "
                f"{rows[-1][f'{ref} without draws']:.4f}",
                flush=True,
            )


def _summarize(
    args: EnvBenchConfig, rows: list[dict], paper_sps: float | None, t_start: float
) -> dict:
    """Table, best row against the targets, printed lines and the JSON record; returns the
    summary."""
    columns = None
    if args.gym:
        for r in rows:
            r.setdefault("x torchrl", None)
        columns = [c for c in rows[0] if c != "runs"]
    if args.tasks:
        for r in rows:
            r.setdefault("task", None)
            r.setdefault(f"x {args.tasks[0]}", None)
        columns = [c for c in rows[-1] if c not in ("runs", "parts_ms")]
    elif args.parts:
        columns = [c for c in rows[0] if c != "parts_ms"]
    table = print_table("TruckEnv env-steps/s (random policy, resets included)", rows, columns)
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
    _print_wall(args, summary, t_start)
    args_json = dataclasses.asdict(args)
    write_json(
        "env", {"rows": rows, "summary": summary, "table": table, "args": args_json}, args.out
    )
    return summary


def _collector_rows(args: EnvBenchConfig, compiled: bool) -> list[dict]:
    """Collector frames/s with the real two-branch policy (random weights)."""
    from torchrl.collectors import Collector

    from truckrl.rl.network import ModelConfig, make_actor_critic

    rows = []
    for n in args.parallel_envs:
        env = _make_env(
            n, compiled, args.device, args.seed, task=args.task, difficulty=args.difficulty
        )
        features = env.task.num_features
        actor = make_actor_critic(ModelConfig(), features, env.config.lidar.num_beams).actor
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


def _modes(args: EnvBenchConfig) -> list[bool]:
    return {"both": [True, False], "on": [True], "off": [False]}[args.compile]


def _scaled_steps(args: EnvBenchConfig, n: int) -> int:
    """Timed steps at N trucks: about ``steps`` x 1,024 trucks of work, 3 .. 4 x ``steps``."""
    return int(min(4 * args.steps, max(3, round(args.steps * 1024 / n))))


def run_scaling(args: EnvBenchConfig) -> dict:
    """The ``scaling=true`` sweep: rows, table, JSON and PNG; returns the JSON payload."""
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
            scene = {"task": {"scene": {"max_obstacles": k}}}  # the default task's scene
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


def run_peers(args: EnvBenchConfig) -> dict:
    """``peers=true``: VMAS and TruckEnv (eager, compiled) at the same N in this run."""
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
