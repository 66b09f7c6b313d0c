"""``truckrl plan``: the sampling-based planner baseline on held-out scenes.

    truckrl plan episodes=200 seed=12345 difficulty=6

Plans each of the ``episodes`` scenes that ``truckrl eval episodes=N seed=S`` scores (same seed
and count, same scenes) with the CEM planner of :mod:`truckrl.planning`, confirms every
plan by replaying it through a fresh ``TruckEnv``, and prints the outcome rates, the final errors
and the per-category table (:mod:`truckrl.evaluation.categories`). The JSON (``out``; default
``outputs/plan/<date>/<time>/plan.json``) holds the summary, the category rows, the timing and,
per episode, its scene info, vehicle, outcome, errors and the action sequence (replay it with
``TruckEnv.set_state`` and ``step``).

``checkpoint=CHECKPOINT`` (a run dir, a ``.pt`` file or ``pretrained``) also drives each scene
with that policy's mean action and replays its action sequence beside the planner's candidates:
a scene counts as solvable when either replay succeeds. The env config is then the
checkpoint's (``env.FIELD=VALUE`` on top; the task and beam count stay), so the scenes are those
of ``truckrl eval checkpoint=CHECKPOINT``; the report gives the planner alone, the policy alone
and either, overall and per category.

``env.FIELD=VALUE`` changes an env config field (``env.max_steps=300``,
``env.task.scene.road_width=[14,18]``, ``env.control.lateral=angle``), ``planner.FIELD=VALUE`` a
:class:`~truckrl.planning.PlannerConfig` field (``planner.samples=64``,
``planner.compile=false``), ``category`` plans only the scenes in every named bin of the task
(``category="[route right]"``, as the category table prints them). ``skip_solved=true`` (with
``checkpoint``) plans only the scenes the policy fails: the solvable share of many scenes at the
cost of searching the policy's misses alone. Bad input prints one line and exits with code 2.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from truckrl.config.fields import ConfigError, param, validate
from truckrl.planning.config import PlannerConfig
from truckrl.tasks import MAX_DIFFICULTY, OUTCOMES

PROG = "truckrl plan"
ABOUT = "The CEM planner baseline on the held-out scenes of truckrl eval (same seed, same scenes)."


@dataclass
class PlanConfig:
    """Which scenes, which planner, and where the JSON goes."""

    episodes: int = param(200, lo=1, hi=1_000_000, doc="held-out scenes")
    seed: int = param(12345, lo=0, hi=2**62, doc="scene seed (evaluate's by default)")
    difficulty: float = param(6.0, lo=0.0, hi=MAX_DIFFICULTY, doc="goal tolerance level")
    category: tuple[str, ...] = param(
        (), min_len=0, doc="plan only scenes in every bin 'DIMENSION BIN' (category table); all"
    )
    checkpoint: str | None = param(
        None, doc="also replay this policy's mean actions: solvable = planner or policy"
    )
    skip_solved: bool = param(
        False,
        doc="with checkpoint: plan only the scenes the policy fails (each scene it solves is "
        "already a witness; the planner-alone figures then cover the planned scenes, and only "
        "their action sequences are written)",
    )
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    env: dict[str, Any] = param({}, doc="env config fields (env.max_steps=300)")
    device: str = param("cpu", doc="cpu | cuda[:i]")
    threads: int = param(1, lo=1, hi=1024, doc="torch CPU threads")
    out: str | None = param(None, doc="JSON file; null: outputs/plan/<date>/<time>/plan.json")
    quiet: bool = param(False, doc="no progress lines")

    def __post_init__(self) -> None:
        if isinstance(self.category, str):  # one value for a list of one
            self.category = (self.category,)
        validate(self)
        if self.skip_solved and not self.checkpoint:
            raise ConfigError(
                "skip_solved = true needs checkpoint= (the policy whose failures are planned)"
            )


def configure(args: PlanConfig) -> tuple[Any, Any]:
    """The env config and the loaded ``checkpoint`` (or None).

    Raises:
        ConfigError: a bad env field or device; CheckpointError: an unusable checkpoint.
    """
    from truckrl.config.fields import build
    from truckrl.config.schemas import check_device
    from truckrl.tasks import EnvConfig

    check_device("device", args.device)
    if args.checkpoint:
        from truckrl.rl.policy import load_policy
        from truckrl.tasks.config import with_env_overrides

        policy = load_policy(args.checkpoint, args.device)
        return with_env_overrides(policy.env_config, args.env, fixed=True), policy
    return build(EnvConfig, args.env, "env"), None


def _jsonable(x: Any) -> Any:
    import torch

    if isinstance(x, torch.Tensor):
        return x.tolist()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def scene_indices(env_cfg: Any, args: PlanConfig):
    """The held-out scenes in every ``args.category`` (LongTensor), or None for all of them.

    Raises:
        ConfigError: a category the task does not have, or no scene in them.
    """
    if not args.category:
        return None
    from truckrl.evaluation.categories import category_mask, task_bins
    from truckrl.evaluation.rollout import SCENE_INFO_ENTRIES
    from truckrl.planning import held_out_states
    from truckrl.sim.vehicle import trailer_length

    states = held_out_states(env_cfg, args.episodes, args.seed, args.device, args.difficulty)
    info = {"trailer_length": trailer_length(states["params"])}
    for entry in SCENE_INFO_ENTRIES:
        if entry in states.keys():
            info |= {k: states[entry, k] for k in states[entry].keys()}
    task = env_cfg.task.name
    keep = category_mask(task_bins(task, info), args.category, task, info["trailer_length"] > -1)
    indices = keep.cpu().nonzero().squeeze(-1)
    if indices.numel() == 0:
        raise ConfigError(f"category = {list(args.category)}: no scene of the {args.episodes}")
    return indices


def run(args: PlanConfig) -> dict:
    import torch

    from truckrl.planning import plan_episodes

    env_cfg, loaded = configure(args)
    torch.set_num_threads(args.threads)
    indices = scene_indices(env_cfg, args)
    t0 = time.perf_counter()
    last = [0.0]

    def progress(done: int, total: int) -> None:
        now = time.perf_counter() - t0
        if not args.quiet and (now - last[0] > 10.0 or done == total):
            last[0] = now
            print(f"  {now:7.1f} s  {done}/{total} scenes planned", file=sys.stderr, flush=True)

    results, tolerance, errors = plan_episodes(
        env_cfg,
        args.difficulty,
        args.episodes,
        args.seed,
        args.planner,
        args.device,
        indices,
        progress,
        loaded.actor if loaded else None,
        args.skip_solved,
    )
    seconds = time.perf_counter() - t0
    out, rows = report(args, env_cfg, loaded, results, tolerance, errors)
    out["seconds"] = seconds
    from truckrl.cli import provenance

    out["provenance"] = provenance(args.device)  # the docs' tables print it under the figures
    output = Path(args.out) if args.out else default_output()
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(out, default=_jsonable) + "\n")
    out["output"] = str(output)
    print_report(out, errors, rows)
    return out


def report(args: PlanConfig, env_cfg, loaded, results: dict, tolerance, errors):
    """The JSON record of a plan run and its category rows."""
    import torch

    from truckrl.cli import git_revision
    from truckrl.evaluation.categories import summarize_by_category, task_bins
    from truckrl.evaluation.rollout import summarize
    from truckrl.planning import category_info

    n = int(results["success"].numel())
    summary = summarize(results, errors)
    bins = task_bins(env_cfg.task.name, category_info(results))  # None: the task has none
    rows = summarize_by_category(results, bins, errors) if bins else []
    sources = {}
    if loaded:
        # skip_solved: the planner searched only the scenes results["searched"] marks; its
        # figures alone cover those, the policy's every scene
        planned = results.get("searched", torch.ones(n, dtype=torch.bool))
        everyone = torch.ones(n, dtype=torch.bool)
        for name, key, keep in (("planner", "planner", planned), ("policy", "extra", everyone)):
            own = results["by_source"][key]
            if name == "policy":
                own = {k: v[keep] for k, v in own.items()}
            alone = {**_scene_rows(results, keep, n), **own}
            alone["scene_info_keys"] = results.get("scene_info_keys", ())
            cells = task_bins(env_cfg.task.name, category_info(alone)) if bins else None
            sources[name] = {
                "scenes": int(keep.sum()),
                "success_rate": alone["success"].float().mean().item() if keep.any() else None,
                "categories": summarize_by_category(alone, cells, errors) if cells else [],
            }
    steps = results["rollouts"] * env_cfg.max_steps
    out = {
        "difficulty": args.difficulty,
        "tolerance_position_m": tolerance[0],
        "tolerance_heading_deg": tolerance[1],
        "seed": args.seed,
        "episodes": args.episodes,
        "categories_planned": list(args.category) or "all",
        "planned": n,
        "searched": int(results["searched"].sum()) if "searched" in results else n,
        **{k: v for k, v in summary.items() if k != "episodes"},
        "planned_success_rate": results["planned_success"].float().mean().item(),
        "replay_mismatches": int(results["replay_mismatch"].sum()),
        "plan_seconds": results["plan_seconds"],
        "rollouts": results["rollouts"],
        "max_truck_steps_per_s": steps / max(results["plan_seconds"], 1e-9),
        "threads": args.threads,
        "device": args.device,
        "planner": dataclasses.asdict(args.planner),
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
        searched = results.get("searched", torch.ones(n, dtype=torch.bool)).tolist()
        for e, ok, s in zip(
            out["per_episode"], results["solved_by_extra"].tolist(), searched, strict=True
        ):
            e["solved_by"] = "policy" if ok else ("planner" if e["success"] else None)
            e["searched"] = s
    return out, rows


def _scene_rows(results: dict, keep, n: int) -> dict:
    """The per-scene tensors ``[n, ...]`` of ``results``, rows ``keep`` (bool ``[n]``) only."""
    import torch

    return {
        k: v[keep]
        for k, v in results.items()
        if isinstance(v, torch.Tensor) and v.shape[:1] == (n,)
    }


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
        if results["scene_info_keys"]:  # the task's scene metadata (route, angles, ...)
            e["scene_info"] = {k: results[k][j].item() for k in results["scene_info_keys"]}
        e["params"] = {k: v[j].item() for k, v in results["params"].items()}
        # skip_solved: a scene the planner did not search has the checkpoint's mean actions,
        # which the checkpoint reproduces (policy_actions), so its sequence is not written
        if "searched" not in results or bool(results["searched"][j]):
            e["actions"] = results["actions"][j, : int(results["length"][j])].tolist()
        eps.append(e)
    return eps


def default_output() -> Path:
    now = datetime.now()
    return Path("outputs/plan") / now.strftime("%Y-%m-%d") / now.strftime("%H-%M-%S") / "plan.json"


def print_report(s: dict, errors, rows: list[dict]) -> None:
    print(
        f"{s['planned']} scenes (of {s['episodes']}, seed {s['seed']}, categories "
        f"{s['categories_planned']}) at "
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
        from truckrl.evaluation.categories import format_category_table

        print(format_category_table(rows))
    if "policy" in s:
        print(format_sources(s))
    print(
        f"{s['seconds']:.1f} s in all ({s['plan_seconds']:.1f} s planning, {s['rollouts']} "
        f"rollouts, up to {s['max_truck_steps_per_s']:.0f} truck-steps/s, {s['threads']} "
        f"thread(s), {s['device']}) -> {s['output']}"
    )


def format_sources(s: dict) -> str:
    """Success per category of the planner alone, the policy alone and either (``checkpoint``).
    With ``skip_solved`` the planner's column covers only the scenes it searched (those the
    policy fails), as ``rate of count``."""
    planner, policy = s["planner_alone"], s["policy"]
    subset = planner["scenes"] != s["planned"]

    def rate(row: dict | None, count: int) -> str:
        if row is None or row["success_rate"] is None:
            return "-"
        return f"{row['success_rate']:.1%}" + (f" of {count}" if subset else "")

    w = 16 if subset else 9
    title = "each replayed open loop"
    if subset:
        title += f"; the planner searched only the {planner['scenes']} scenes the policy fails"
    lines = [
        f"solvable = planner or policy ({policy['checkpoint']}, {policy['frames']:,} frames), "
        f"{title}:",
        f"{'category':<34}{'scenes':>7}{'planner':>{w}}{'policy':>9}{'either':>9}",
        f"{'all':<34}{s['planned']:>7}{rate(planner, planner['scenes']):>{w}}"
        f"{policy['success_rate']:>9.1%}{s['success_rate']:>9.1%}",
    ]
    by_bin = {(r["dimension"], r["bin"]): r for r in planner["categories"]}
    for both, b in zip(s["categories"], policy["categories"], strict=True):
        a = by_bin.get((both["dimension"], both["bin"]))
        lines.append(
            f"{both['dimension'] + ' ' + both['bin']:<34}{both['count']:>7}"
            f"{rate(a, a['count'] if a else 0):>{w}}{b['success_rate']:>9.1%}"
            f"{both['success_rate']:>9.1%}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(PlanConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)


if __name__ == "__main__":
    sys.exit(main())
