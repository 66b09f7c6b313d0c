"""``python -m truckrl.plan``: the sampling-based planner baseline on held-out scenes.

    python -m truckrl.plan --episodes 200 --seed 12345 --difficulty 6

Plans each of the ``--episodes`` scenes that ``python -m truckrl.evaluate episodes=N seed=S``
scores (same seed and count, same scenes) with the CEM planner of
:mod:`truckrl.planning.planner`, confirms every plan by replaying it through a fresh ``TruckEnv``,
and prints the outcome rates, the final errors and the per-category table
(:mod:`truckrl.evaluation.categories`). The JSON (default ``outputs/plan/<date>/<time>/plan.json``)
holds the summary, the category rows, the timing and, per episode, its route, vehicle, outcome,
errors and the action sequence (replay it with ``TruckEnv.set_state`` and ``step``).

``--policy CHECKPOINT`` (a run dir, a ``.pt`` file or ``pretrained``) also drives each scene
with that policy's mean action and replays its action sequence beside the planner's candidates:
a scene counts as solvable when either replay succeeds. The env config is then the
checkpoint's (``--env`` overrides on top; the task and beam count stay), so the scenes are those
of ``python -m truckrl.evaluate checkpoint=CHECKPOINT``; the report gives the planner alone, the
policy alone and either, overall and per category.

``--env KEY=VALUE`` overrides an env config field (``max_steps=300``,
``task.scene.road_width=[14,18]``, ``control.lateral=angle``; values in YAML), ``--planner
KEY=VALUE`` a :class:`~truckrl.planning.planner.PlannerConfig` field. Bad options print one line and
exit with code 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import torch
import yaml

from truckrl.cli import OneLineArgParser, git_revision, run_or_fail
from truckrl.config.fields import ConfigError, build, check_range
from truckrl.evaluation.categories import format_category_table, summarize_by_category, task_bins
from truckrl.evaluation.rollout import summarize
from truckrl.planning.planner import PlannerConfig, category_info, plan_episodes
from truckrl.tasks import MAX_DIFFICULTY, OUTCOMES, EnvConfig
from truckrl.tasks.intersection.scene import ROUTE_KEYS, ROUTE_NAMES

#: ``--route`` names (spaces as underscores) -> route value.
ROUTES = {name.replace(" ", "_"): i for i, name in enumerate(ROUTE_NAMES)}


def _overrides(items: list[str], where: str) -> dict[str, Any]:
    """``["a.b=1", ...]`` -> nested ``{"a": {"b": 1}}`` (values parsed as YAML)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{where} override {item!r} must look like KEY=VALUE")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"{where}.{key}: cannot parse value {raw!r}") from None
        node = out
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{where} override {item!r} conflicts with another")
        node[leaf] = value
    return out


def parser() -> argparse.ArgumentParser:
    p = OneLineArgParser(prog="python -m truckrl.plan", description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=200, help="held-out scenes (default 200)")
    p.add_argument("--seed", type=int, default=12345, help="scene seed (default 12345)")
    p.add_argument("--difficulty", type=float, default=6.0, help="goal tolerance level (default 6)")
    p.add_argument(
        "--route",
        action="append",
        default=[],
        choices=sorted(ROUTES),
        help="plan only scenes of this route (repeatable; default all)",
    )
    p.add_argument("--samples", type=int, help="candidates per scene per iteration")
    p.add_argument("--iterations", type=int, help="CEM iterations per scene (max)")
    p.add_argument("--scenes-per-batch", type=int, help="scenes rolled out together")
    p.add_argument(
        "--planner",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="PlannerConfig field (repeatable)",
    )
    p.add_argument(
        "--env",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="env config field, e.g. max_steps=300 (repeatable)",
    )
    p.add_argument(
        "--policy",
        metavar="CHECKPOINT",
        help="also replay this checkpoint's mean actions: solvable = planner or policy solves it",
    )
    p.add_argument("--no-compile", action="store_true", help="eager rollouts (no ~15 s compile)")
    p.add_argument("--device", default="cpu", help="cpu | cuda[:i]")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--output", help="JSON file (default outputs/plan/<date>/<time>/plan.json)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def configure(args: argparse.Namespace) -> tuple[EnvConfig, PlannerConfig, Any]:
    """Validate the options; raise :class:`ConfigError` naming the bad one (a bad ``--policy``:
    :class:`~truckrl.rl.checkpoint.CheckpointError`).

    Returns:
        ``(env config, planner config, the loaded --policy or None)``.
    """
    if args.episodes < 1 or args.episodes > 1_000_000:
        raise ConfigError(f"--episodes = {args.episodes} must be in [1, 1000000]")
    if args.seed < 0:
        raise ConfigError(f"--seed = {args.seed} must be >= 0")
    check_range("--difficulty", args.difficulty, 0.0, MAX_DIFFICULTY)
    if args.threads < 1:
        raise ConfigError(f"--threads = {args.threads} must be >= 1")
    if args.device != "cpu" and not (args.device.startswith("cuda") and torch.cuda.is_available()):
        raise ConfigError(f"--device = {args.device!r}: not available (cpu, or cuda with a GPU)")
    policy = None
    if args.policy:
        from truckrl.rl.policy import load_policy
        from truckrl.tasks.config import with_env_overrides

        policy = load_policy(args.policy, args.device)
        env_cfg = with_env_overrides(policy.env_config, _overrides(args.env, "env"), fixed=True)
    else:
        env_cfg = build(EnvConfig, _overrides(args.env, "env"), "env")
    planner = _overrides(args.planner, "planner")
    for name in ("samples", "iterations", "scenes_per_batch"):
        if getattr(args, name) is not None:
            planner[name] = getattr(args, name)
    if args.no_compile:
        planner["compile"] = False
    return env_cfg, build(PlannerConfig, planner, "planner"), policy


def _jsonable(x: Any) -> Any:
    if isinstance(x, torch.Tensor):
        return x.tolist()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def run(args: argparse.Namespace) -> dict:
    env_cfg, pc, loaded = configure(args)
    torch.set_num_threads(args.threads)
    indices = None
    if args.route:
        from truckrl.planning.planner import held_out_states

        route = held_out_states(env_cfg, args.episodes, args.seed, args.device, args.difficulty)
        route = route["route", "route"]
        wanted = torch.tensor([ROUTES[r] for r in args.route])
        indices = torch.isin(route.cpu().long(), wanted).nonzero().squeeze(-1)
        if indices.numel() == 0:
            raise ConfigError(f"no scene of route {args.route} among the {args.episodes}")
    t0 = time.perf_counter()
    last = [0.0]

    def progress(done: int, total: int) -> None:
        now = time.perf_counter() - t0
        if not args.quiet and (now - last[0] > 10.0 or done == total):
            last[0] = now
            print(f"  {now:7.1f} s  {done}/{total} scenes planned", file=sys.stderr, flush=True)

    results, (tol_pos, tol_deg), errors = plan_episodes(
        env_cfg,
        args.difficulty,
        args.episodes,
        args.seed,
        pc,
        args.device,
        indices,
        progress,
        loaded.actor if loaded else None,
    )
    seconds = time.perf_counter() - t0
    n = int(results["success"].numel())
    summary = summarize(results, errors)
    # the task's bins (intersection: route, turn, ...; others: their category_dims), if any
    bins = task_bins(env_cfg.task.name, category_info(results))
    rows = summarize_by_category(results, bins, errors) if bins else []
    sources = {}
    if loaded:
        for name, key in (("planner", "planner"), ("policy", "extra")):
            alone = {**results, **results["by_source"][key]}
            sources[name] = {
                "success_rate": alone["success"].float().mean().item(),
                "categories": summarize_by_category(alone, bins, errors) if bins else [],
            }
    steps = results["rollouts"] * env_cfg.max_steps
    out = {
        "difficulty": args.difficulty,
        "tolerance_position_m": tol_pos,
        "tolerance_heading_deg": tol_deg,
        "seed": args.seed,
        "episodes": args.episodes,
        "routes": args.route or "all",
        "planned": n,
        **{k: v for k, v in summary.items() if k != "episodes"},
        "planned_success_rate": results["planned_success"].float().mean().item(),
        "replay_mismatches": int(results["replay_mismatch"].sum()),
        "seconds": seconds,
        "plan_seconds": results["plan_seconds"],
        "rollouts": results["rollouts"],
        "max_truck_steps_per_s": steps / max(results["plan_seconds"], 1e-9),
        "threads": args.threads,
        "device": args.device,
        "planner": dataclasses.asdict(pc),
        "env": dataclasses.asdict(env_cfg),
        "source": git_revision(),
        "categories": rows,
        "per_episode": _per_episode(results, errors),
    }
    if loaded:
        out["policy"] = {
            "checkpoint": str(loaded.path),
            "frames": int(loaded.counters["frames"]),
            **sources["policy"],
        }
        out["planner_alone"] = sources["planner"]
        for e, ok in zip(out["per_episode"], results["solved_by_extra"].tolist(), strict=True):
            e["solved_by"] = "policy" if ok else ("planner" if e["success"] else None)
    output = Path(args.output) if args.output else default_output()
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(out, default=_jsonable) + "\n")
    out["output"] = str(output)
    print_report(out, errors, rows)
    return out


def _per_episode(results: dict, errors) -> list[dict]:
    flags = [o.flag for o in OUTCOMES]
    keys = [
        *flags,
        "length",
        *(q.key for q in errors),
        "planned_success",
        "replay_mismatch",
        "best_ratio",
        "iterations",
        "attempts",
    ]
    eps = []
    for j in range(int(results["success"].numel())):
        e = {"scene_index": int(results["scene_index"][j])}
        for k in keys:
            v = results[k][j].item()
            e[k] = v if not isinstance(v, float) or math.isfinite(v) else None
        e["route"] = {k: results[k][j].item() for k in ROUTE_KEYS if k in results}
        others = [k for k in results["scene_info_keys"] if k not in ROUTE_KEYS]
        if others:
            e["scene_info"] = {k: results[k][j].item() for k in others}
        e["params"] = {k: v[j].item() for k, v in results["params"].items()}
        e["actions"] = results["actions"][j, : int(results["length"][j])].tolist()
        eps.append(e)
    return eps


def default_output() -> Path:
    now = datetime.now()
    return Path("outputs/plan") / now.strftime("%Y-%m-%d") / now.strftime("%H-%M-%S") / "plan.json"


def print_report(s: dict, errors, rows: list[dict]) -> None:
    print(
        f"{s['planned']} scenes (of {s['episodes']}, seed {s['seed']}, routes {s['routes']}) at "
        f"difficulty {s['difficulty']:g} (tolerance {s['tolerance_position_m']:.3g} m, "
        f"{s['tolerance_heading_deg']:.3g} deg)"
    )
    print(
        "  ".join(f"{o.name} {s[f'{o.name}_rate']:.3f}" for o in OUTCOMES)
        + f"  replay mismatches {s['replay_mismatches']}"
    )
    print(f"{'final error':<30}{'mean':>10}{'p95':>10}")
    for q in errors:
        key = f"{q.key}_{q.shown_unit}"
        print(f"{f'{q.key} [{q.shown_unit}]':<30}{s[f'{key}_mean']:>10.3f}{s[f'{key}_p95']:>10.3f}")
    if rows:
        print(format_category_table(rows))
    if "policy" in s:
        print(format_sources(s))
    print(
        f"{s['seconds']:.1f} s in all ({s['plan_seconds']:.1f} s planning, {s['rollouts']} "
        f"rollouts, up to {s['max_truck_steps_per_s']:.0f} truck-steps/s, {s['threads']} "
        f"thread(s), {s['device']}) -> {s['output']}"
    )


def format_sources(s: dict) -> str:
    """Success per category of the planner alone, the policy alone and either (``--policy``)."""
    planner, policy = s["planner_alone"], s["policy"]
    lines = [
        f"solvable = planner or policy ({policy['checkpoint']}, {policy['frames']:,} frames), "
        "each replayed open loop:",
        f"{'category':<34}{'scenes':>7}{'planner':>9}{'policy':>9}{'either':>9}",
        f"{'all':<34}{s['planned']:>7}{planner['success_rate']:>9.1%}"
        f"{policy['success_rate']:>9.1%}{s['success_rate']:>9.1%}",
    ]
    for both, a, b in zip(
        s["categories"], planner["categories"], policy["categories"], strict=True
    ):
        name = f"{both['dimension']} {both['bin']}"
        lines.append(
            f"{name:<34}{both['count']:>7}{a['success_rate']:>9.1%}{b['success_rate']:>9.1%}"
            f"{both['success_rate']:>9.1%}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return run_or_fail(run, parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
