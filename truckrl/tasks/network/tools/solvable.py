"""``python -m truckrl.tasks.network.tools.solvable``: how many network scenes the scripted route driver
solves (a lower bound on how many are solvable; docs/networks.md, "A scripted driver").

    python -m truckrl.tasks.network.tools.solvable                       # defaults below
    python -m truckrl.tasks.network.tools.solvable episodes=200 difficulties=[1] out=null

Drives ``episodes`` held-out scenes of ``seed`` (``truckrl eval``'s) with
:class:`~truckrl.tasks.network.expert.RouteDriver` at each of ``difficulties`` (its curriculum
level: route and traffic; its tolerances), once with the level's traffic and once with none
(``traffic`` shares of the spawned vehicles: the same seed draws the same chains, trucks and
vehicles, the share only decides which drive), on ``experiment=network``'s 1,000-step
episodes. Prints, per run, the outcome rates, where the failed episodes ended along the route,
and the network task's bins; writes them with their provenance to ``out``, headed by the run at
the last difficulty with the first traffic share in ``truckrl eval``'s layout (what
docs/render.py tables).
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

from truckrl.config.fields import param, validate
from truckrl.tasks import MAX_DIFFICULTY

PROG = "python -m truckrl.tasks.network.tools.solvable"
ABOUT = "How many network scenes the scripted route driver solves."


@dataclass
class SolvableConfig:
    """Which scenes, at which levels, with how much traffic."""

    episodes: int = param(1000, lo=1, hi=100_000, unit="episodes", doc="held-out scenes per run")
    seed: int = param(12345, lo=0, hi=2**62, doc="scene seed (evaluate's, no training uses it)")
    difficulties: tuple[float, ...] = param(
        (1.0, 4.0), lo=0.0, hi=MAX_DIFFICULTY, min_len=1, unit="-",
        doc="curriculum levels and tolerances, one run each",
    )  # fmt: skip
    traffic: tuple[float, ...] = param(
        (1.0, 0.0), lo=0.0, hi=1.0, min_len=1, unit="-",
        doc="factors on every level's share of the spawned vehicles, one run each",
    )  # fmt: skip
    road_width: tuple[float, float] | None = param(
        None, lo=2.0, hi=40.0, unit="m", doc="env.task.network.road_width; null: the task's"
    )
    max_steps: int = param(
        1000, lo=1, hi=1_000_000, unit="steps", doc="episode limit (experiment=network's)"
    )
    threads: int = param(1, lo=1, hi=1024, doc="torch CPU threads")
    out: str | None = param("docs/data/results/network-driver.json", doc="JSON file; null: none")

    def __post_init__(self) -> None:
        validate(self)


def env_config(cfg: SolvableConfig, share: float):
    """The network task's env config with ``share`` times every level's traffic."""
    from truckrl.tasks import EnvConfig
    from truckrl.tasks.network.scene import CurriculumConfig

    levels = CurriculumConfig().traffic
    task: dict = {"name": "network", "curriculum": {"traffic": [share * t for t in levels]}}
    if cfg.road_width is not None:
        task["network"] = {"road_width": list(cfg.road_width)}
    return EnvConfig(task=task, max_steps=cfg.max_steps)


def one_run(cfg: SolvableConfig, difficulty: float, share: float) -> dict:
    """Drive the scenes at ``difficulty`` with ``share`` of the traffic: the run's record."""
    import time

    from truckrl.evaluation.categories import summarize_by_category, task_bins
    from truckrl.planning import held_out_states
    from truckrl.tasks.network.expert import drive

    env_cfg = env_config(cfg, share)
    t0 = time.perf_counter()
    states = held_out_states(env_cfg, cfg.episodes, cfg.seed, "cpu", difficulty=difficulty)
    r, _ = drive(env_cfg, states, difficulty, record=False)
    info = {k: states["route", k] for k in states["route"].keys()}
    results = {**r, **info}
    failed = ~r["success"]
    near = r["to_go"].abs() <= 5.0
    rate = lambda k: r[k].double().mean().item()  # noqa: E731
    return {
        "difficulty": difficulty,
        "traffic_share": share,
        "episodes": cfg.episodes,
        "success_rate": rate("success"),
        "collision_rate": rate("collision"),
        "jackknife_rate": rate("jackknife"),
        "timeout_rate": rate("truncated"),
        # where the failures ended: before the goal, within 5 m of it, past it
        "failed_before_goal": int((failed & ~near & (r["to_go"] > 0)).sum()),
        "failed_at_goal": int((failed & near).sum()),
        "failed_past_goal": int((failed & ~near & (r["to_go"] < 0)).sum()),
        "mean_steps_success": r["steps"][r["success"]].double().mean().item()
        if r["success"].any()
        else None,
        "wall_s": round(time.perf_counter() - t0, 1),
        "categories": summarize_by_category(results, task_bins("network", info) or {}),
    }


def run(cfg: SolvableConfig) -> dict:
    import math

    import torch

    from truckrl.cli import check_writable, provenance
    from truckrl.evaluation.categories import format_category_table

    torch.set_num_threads(cfg.threads)
    out = Path(cfg.out) if cfg.out else None
    if out is not None:
        check_writable(out, "out")
    runs = []
    for d in cfg.difficulties:
        for share in cfg.traffic:
            r = one_run(cfg, d, share)
            runs.append(r)
            print(
                f"difficulty {d:g}, traffic x{share:g}: success {100 * r['success_rate']:.1f} %, "
                f"collision {100 * r['collision_rate']:.1f} %, jack-knife "
                f"{100 * r['jackknife_rate']:.1f} %, timeout {100 * r['timeout_rate']:.1f} % of "
                f"{r['episodes']} ({r['wall_s']} s); failures before / at / past the goal "
                f"{r['failed_before_goal']} / {r['failed_at_goal']} / {r['failed_past_goal']}"
            )
            print(format_category_table(r["categories"]), flush=True)
    env_cfg = env_config(cfg, 1.0)
    tol = env_cfg.tolerance
    prov = provenance("cpu")
    if Path(sys.argv[0]).parts[-2:] == ("tools", "solvable.py"):
        prov["command"] = shlex.join(["python", "-m", __spec__.name, *sys.argv[1:]])
    # the headline (what docs/render.py tables as an evaluation): the hardest level, first share
    head = runs[(len(cfg.difficulties) - 1) * len(cfg.traffic)]
    d = head["difficulty"]
    data = {
        "provenance": prov,
        "driver": "truckrl.tasks.network.expert.RouteDriver (defaults)",
        "difficulty": d,
        "traffic_share": head["traffic_share"],
        "episodes": head["episodes"],
        "tolerance_position_m": tol.position * 2.0**-d,
        "tolerance_heading_deg": math.degrees(tol.heading) * 2.0**-d,
        **{
            k: head[k] for k in ("success_rate", "collision_rate", "jackknife_rate", "timeout_rate")
        },
        "categories": head["categories"],
        "seed": cfg.seed,
        "max_steps": cfg.max_steps,
        "road_width_m": list(env_cfg.task.network.road_width),
        "tolerances": {
            f"{d:g}": [tol.position * 2.0**-d, math.degrees(tol.heading) * 2.0**-d]
            for d in cfg.difficulties
        },
        "runs": runs,
    }
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(data, indent=1) + "\n")
        print(f"wrote {out}")
    return data


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(SolvableConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)


if __name__ == "__main__":
    sys.exit(main())
