"""``python -m truckrl.tasks.network.tools``: a policy trained on one intersection, driven through road
networks by the route's junction exits as sub-goals (issue 42, item 4; docs/chaining.md).

    python -m truckrl.tasks.network.tools                      # pretrained:intersection, defaults below
    python -m truckrl.tasks.network.tools episodes=20 junctions=[2] traffic=[1.0] out=null

Loads ``checkpoint`` (a policy whose task observes the shared 26 features and no extras, as the
intersection task does), builds the sub-goal view of the network task
(:mod:`truckrl.tasks.network.cells`) with the policy's vehicle, LiDAR (its beam count), control,
``dt`` and tolerances, and runs :func:`~truckrl.evaluation.rollout.evaluate_policy` (mean
action, one episode per scene) on ``episodes`` held-out scenes of ``seed`` at ``difficulty``,
once per route length in ``junctions`` and traffic share in ``traffic``. The route length is
the network task's curriculum fixed to one level (``env.task.curriculum.junctions=[j]``); a
traffic share of 0 keeps the spawned vehicles out of the same scenes (the same seed draws the
same chains, trucks and vehicles; the share only decides which drive), so the traffic's part in
the failures is the difference. ``control=true`` adds, per route length with the first traffic
share, the same scenes with the final goal shown from the start (no sub-goals).

Prints, per run, the outcome rates, the sub-goals the failed episodes had passed, the network
task's bins and route length [m] bins, and writes everything with its provenance to ``out``.
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass, replace
from pathlib import Path

from truckrl.config.fields import ConfigError, param, validate
from truckrl.tasks import MAX_DIFFICULTY

PROG = "python -m truckrl.tasks.network.tools"
ABOUT = "An intersection policy driven through networks by junction-exit sub-goals."

#: Route length bin edges [m] (the network task's routes are about 80-350 m per its preset).
ROUTE_LENGTH_EDGES: tuple[float, ...] = (0.0, 150.0, 250.0, 350.0, 1000.0)
#: Dimension name of the route length bins.
ROUTE_LENGTH_DIM = "route length [m]"
#: Dimension name of the runs' bins in the record's category rows.
RUN_DIM = "run"


@dataclass
class ChainConfig:
    """Which policy, on which scenes, with which sub-goals."""

    checkpoint: str = param(
        "pretrained:intersection", doc="checkpoint file, run dir or pretrained[:task]"
    )
    episodes: int = param(200, lo=1, hi=100_000, unit="episodes", doc="held-out scenes per run")
    seed: int = param(12345, lo=0, hi=2**62, doc="scene seed (evaluate's, no training uses it)")
    difficulty: float = param(
        4.0, lo=0.0, hi=MAX_DIFFICULTY, doc="tolerances 30 m and 60 deg times 2**-difficulty"
    )
    junctions: tuple[int, ...] = param(
        (1, 2, 3), lo=1, hi=16, min_len=1, unit="-", doc="route lengths, one run each"
    )
    traffic: tuple[float, ...] = param(
        (1.0, 0.0), lo=0.0, hi=1.0, min_len=1, unit="-",
        doc="shares of the spawned vehicles that drive, one run each",
    )  # fmt: skip
    past_exit: float = param(
        20.0, lo=0.0, hi=1000.0, unit="m", doc="env.task.subgoal.past_exit of every run"
    )
    switch: float = param(
        5.0, lo=0.0, hi=1000.0, unit="m", doc="env.task.subgoal.switch of every run"
    )
    horizon: float = param(
        0.0, lo=0.0, hi=1000.0, unit="m", doc="env.task.subgoal.horizon of every run (0: off)"
    )
    road_width: tuple[float, float] | None = param(
        None, lo=2.0, hi=40.0, unit="m",
        doc="env.task.network.road_width of every run; null: the network task's",
    )  # fmt: skip
    block_types: tuple[str, ...] | None = param(
        None, doc="env.task.network.block_types of every run; null: the network task's"
    )
    control: bool = param(False, doc="also run each route length without sub-goals")
    max_steps: int = param(
        1000, lo=1, hi=1_000_000, unit="steps", doc="episode limit (experiment=network's)"
    )
    failures: int = param(
        8, lo=0, hi=10_000, unit="episodes", doc="failed episodes per run described in the JSON"
    )
    threads: int = param(1, lo=1, hi=1024, doc="torch CPU threads")
    out: str | None = param(
        "docs/data/results/chain-intersection.json", doc="JSON file; null: none"
    )

    def __post_init__(self) -> None:
        validate(self)


def chain_env(base, cfg: ChainConfig, junctions: int, share: float, subgoals: bool = True):
    """The sub-goal network env of ``base`` (a policy's :class:`~truckrl.tasks.EnvConfig`): its
    vehicle, LiDAR, control, ``dt`` and tolerances, routes through ``junctions`` junctions
    with ``share`` of the spawned vehicles driving."""
    from truckrl.tasks.network.cells.task import CellsTaskConfig, SubgoalConfig
    from truckrl.tasks.network.scene import CurriculumConfig

    task = CellsTaskConfig(
        curriculum=CurriculumConfig(
            difficulty=(0.0,), junctions=(junctions,), traffic=(share,), distance=(0.0,)
        ),
        subgoal=SubgoalConfig(
            past_exit=cfg.past_exit, switch=cfg.switch, junctions=subgoals, horizon=cfg.horizon
        ),
    )
    if cfg.road_width is not None:
        task = replace(task, network=replace(task.network, road_width=cfg.road_width))
    if cfg.block_types is not None:
        task = replace(task, network=replace(task.network, block_types=cfg.block_types))
    return replace(base, max_steps=cfg.max_steps, compile=False, task=task)


def check_policy(policy, checkpoint: str) -> None:
    """Raise ``ConfigError`` unless the policy observes the intersection task's layout."""
    from truckrl.tasks import make_task
    from truckrl.tasks.base import NUM_FEATURES

    extras = make_task(policy.env_config).num_extras
    if extras:
        raise ConfigError(
            f"checkpoint = {checkpoint!r}: its task {policy.env_config.task.name!r} observes "
            f"{NUM_FEATURES} + {extras} features; the sub-goal view gives {NUM_FEATURES} (the "
            f"intersection task's layout)"
        )


def subgoals_passed(states, path, switch: float):
    """Per episode ``[E]`` (long): the junction sub-goals the truck passed (the switching rule
    on its furthest route projection along ``path [E, T + 1, 4]``) beyond those behind its
    start, and the furthest projection [m]."""
    import torch

    from truckrl.tasks.network.cells.task import advance
    from truckrl.tasks.network.task import project

    e, t1 = path.shape[:2]
    pts, cum = states["route_points"], states["route_cum"]
    rep = lambda x: x.repeat_interleave(t1, 0)  # noqa: E731
    s = project(rep(pts), rep(cum), path.reshape(-1, 4))[0].view(e, t1)
    furthest = s.amax(1)
    start = states["subgoal_index"]
    end = advance(start, furthest, states["subgoal_s"], switch)
    return (end - start).to(torch.long), furthest


def collision_sites(states, pose):
    """Where trucks at their final ``pose [E, 4]`` touch the chain's curbs: ``(what [E], body
    [E], block [E])``: ``what`` 1 where a curb is touched (0: none, so a vehicle where the
    episode ended in a collision), ``body`` 0 tractor / 1 trailer / 2 both, ``block`` the
    block index of the first touched curb (-1: none); all long."""
    import torch

    from truckrl.sim.collision import touching

    params = {k: states["params", k] for k in states["params"].keys()}
    tractor, trailer = touching(pose, params, states["segments"], states["mask"])
    hit = tractor | trailer
    first = hit.to(torch.uint8).argmax(-1, keepdim=True)
    block = torch.where(hit.any(-1), states["segment_block"].gather(1, first).squeeze(1), -1)
    front, back = tractor.any(-1), trailer.any(-1)
    body = back.long() + (front & back).long()
    return hit.any(-1).long(), body, block.long()


def route_pose(states, pose):
    """Trucks at ``pose [E, 4]`` against their route: ``(along [E], left [E], heading [E])``,
    the arc length of their projection past the start's [m], their signed distance from the
    route (+ left of it) [m] and their heading less the route's there [deg, (-180, 180]]."""
    import math

    import torch

    from truckrl.tasks.network.scene import point_at
    from truckrl.tasks.network.task import project

    pts, cum = states["route_points"], states["route_cum"]
    s = project(pts, cum, pose)[0]
    xy, heading = point_at(pts, cum, s.unsqueeze(-1))
    d, h = pose[:, :2] - xy[:, 0], heading[:, 0]
    left = -d[:, 0] * torch.sin(h) + d[:, 1] * torch.cos(h)
    error = torch.remainder(pose[:, 2] - h + math.pi, 2 * math.pi) - math.pi
    return s - states["route_s"], left, torch.rad2deg(error)


def curb_collisions(results, states, pose) -> dict[str, dict]:
    """The curb collisions on links and in junctions: ``{role: {count, left_of_route,
    along_m_p10/p50/p90, steps_p50, heading_error_deg_p10/p50/p90}}`` (the truck's final pose
    against the route, :func:`route_pose`)."""
    import torch

    what, _, block = collision_sites(states, pose)
    along, left, error = route_pose(states, pose)
    hit = results["collision"] & (what > 0)
    out = {}
    for role, parity in (("link", 0), ("junction", 1)):
        m = hit & (block % 2 == parity)
        if not bool(m.any()):
            continue
        q = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
        a, e = along[m].double().quantile(q), error[m].double().quantile(q)
        out[role] = {
            "count": int(m.sum()),
            "left_of_route": int((left[m] > 0).sum()),
            **{f"along_m_p{p}": round(float(v), 1) for p, v in zip((10, 50, 90), a, strict=True)},
            "steps_p50": float(results["length"][m].double().median()),
            **{
                f"heading_error_deg_p{p}": round(float(v), 1)
                for p, v in zip((10, 50, 90), e, strict=True)
            },
        }
    return out


def site_counts(results, states, pose) -> dict[str, int]:
    """Collisions ``{site: count}``: ``vehicle``, or ``<body> on <link|junction> <type>``."""
    from truckrl.sim.network.config import BLOCK_NAMES

    what, body, block = collision_sites(states, pose)
    bodies = ("tractor", "trailer", "tractor and trailer")
    out: dict[str, int] = {}
    for i in results["collision"].nonzero().squeeze(-1).tolist():  # a report's rows
        if not what[i]:
            key = "vehicle"
        else:
            k = int(block[i])
            role = "link" if k % 2 == 0 else "junction"
            key = f"{bodies[int(body[i])]} on {role} {BLOCK_NAMES[int(states['block_type'][i, k])]}"
        out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def describe_failures(results, states, passed, furthest, count: int) -> list[dict]:
    """The first ``count`` failed episodes: outcome, steps, sub-goals passed, furthest route
    projection and route length [m], final distance to the goal [m], blocks on the route."""
    import torch

    from truckrl.sim.network.config import BLOCK_NAMES

    failed = (~results["success"]).nonzero().squeeze(-1)[:count]
    what, body, block = collision_sites(states, results["path"][:, -1])
    _, left, error = route_pose(states, results["path"][:, -1])
    rows = []
    for i in failed.tolist():  # a report's rows, after the rollout
        outcome = next(
            (k for k in ("collision", "jackknife", "truncated") if bool(results[k][i])), "none"
        )
        first = states["start_options"].shape[1] - 1 - int(results["junctions"][i])
        types = states["block_type"][i, 2 * first :].tolist()
        rows.append(
            {
                "episode": i,
                "outcome": "timeout" if outcome == "truncated" else outcome,
                "steps": int(results["length"][i]),
                "subgoals_passed": int(passed[i]),
                "furthest_m": round(float(furthest[i] - states["route_s"][i]), 1),
                "route_length_m": round(float(results["route_length"][i]), 1),
                "final_pos_error_m": round(float(results["pos_error"][i]), 1),
                "final_left_of_route_m": round(float(left[i]), 2),
                "final_heading_error_deg": round(float(error[i]), 1),
                "vehicles": int(results["vehicles"][i]),
                "curb_touched_by": (
                    ("tractor", "trailer", "both")[int(body[i])] if what[i] else None
                ),
                "curb_block": int(block[i]) - 2 * first if what[i] else None,
                "blocks": [BLOCK_NAMES[t] for t in types if t >= 0],
                "turns_deg": [
                    round(float(torch.rad2deg(states["junction_turn"][i, k])))
                    for k in range(2 * first + 1, states["junction_turn"].shape[1], 2)
                ],
            }
        )
    return rows


def run_name(junctions: int, share: float, subgoals: bool) -> str:
    """A run's bin name: ``"2 junctions, traffic"``, ``"1 junction, no traffic"``, ..."""
    traffic = {0.0: "no traffic", 1.0: "traffic"}.get(share, f"{share:g} of the traffic")
    plural = "s" if junctions != 1 else ""
    return f"{junctions} junction{plural}, {traffic}" + ("" if subgoals else ", no sub-goals")


def pooled_tables(runs: list[tuple[str, bool, dict]], errors) -> tuple[dict, list[dict]]:
    """The record's headline: ``(summary, category rows)`` of ``runs`` (``(name, headline,
    results)`` each): one bin per run (dimension :data:`RUN_DIM`), then the network task's
    bins and the route length bins over the ``headline`` runs pooled (every route length at
    the first traffic share, with sub-goals); the summary is theirs."""
    import torch

    from truckrl.evaluation.categories import summarize_by_category
    from truckrl.evaluation.rollout import summarize
    from truckrl.tasks.bins import range_bins
    from truckrl.tasks.network.bins import JUNCTION_DIM, network_bins

    keys = [k for k in runs[0][2] if k not in ("path", "motion")]
    pooled = {k: torch.cat([r[k] for _, _, r in runs]) for k in keys}
    counts = [r["success"].shape[0] for _, _, r in runs]
    which = torch.repeat_interleave(torch.arange(len(runs)), torch.tensor(counts))
    head = torch.tensor([h for _, h, _ in runs])[which]
    bins: dict[str, dict] = {RUN_DIM: {name: which == i for i, (name, _, _) in enumerate(runs)}}
    more = network_bins(pooled)
    del more[JUNCTION_DIM]  # the runs are the route lengths
    length = pooled["route_length"].to(torch.float64)
    more[ROUTE_LENGTH_DIM] = range_bins(length, ROUTE_LENGTH_EDGES, head)
    for dim, named in more.items():
        bins[f"{dim}, pooled"] = {b: m & head for b, m in named.items()}
    summary = summarize({k: v[head] for k, v in pooled.items()}, errors)
    return summary, summarize_by_category(pooled, bins, errors)


def one_run(actor, env_cfg, cfg: ChainConfig) -> tuple[dict, dict, tuple]:
    """Evaluate on the held-out scenes of one env: its record (the summary, the failures'
    sub-goals, sites and rows, the category rows), the per-episode results and the task's
    error quantities."""
    import torch

    from truckrl.evaluation.categories import summarize_by_category, task_bins
    from truckrl.evaluation.rollout import evaluate_policy, summarize
    from truckrl.planning.scenes import held_out_states
    from truckrl.tasks.bins import range_bins

    results, _, errors = evaluate_policy(
        actor, env_cfg, cfg.difficulty, cfg.episodes, cfg.seed, record_paths=True
    )
    states = held_out_states(env_cfg, cfg.episodes, cfg.seed, difficulty=cfg.difficulty)
    passed, furthest = subgoals_passed(states, results["path"], cfg.switch)
    j = int(results["junctions"].max())
    failed = ~results["success"]
    passed_hist = {str(k): int((failed & (passed == k)).sum()) for k in range(j + 1)}
    bins = task_bins(env_cfg.task.name, results) or {}
    length = results["route_length"].to(torch.float64)
    bins[ROUTE_LENGTH_DIM] = range_bins(length, ROUTE_LENGTH_EDGES, torch.ones_like(failed))
    row = {
        "junctions": j,
        "traffic_share": env_cfg.task.curriculum.traffic[0],
        "subgoals": env_cfg.task.subgoal.junctions,
        **summarize(results, errors),
        "feasible_rate": results["feasible"].mean().item(),
        "failed_by_subgoals_passed": passed_hist,
        "collisions_by_site": site_counts(results, states, results["path"][:, -1]),
        "curb_collisions": curb_collisions(results, states, results["path"][:, -1]),
        "categories": summarize_by_category(results, bins, errors),
        "failures": describe_failures(results, states, passed, furthest, cfg.failures),
    }
    return row, results, errors


def run(cfg: ChainConfig) -> dict:
    import math
    import time

    import torch

    from truckrl.cli import check_writable, provenance
    from truckrl.evaluation.categories import format_category_table
    from truckrl.rl.policy import load_policy
    from truckrl.tasks.network.cells.task import CELLS_TASK

    torch.set_num_threads(cfg.threads)
    out = Path(cfg.out) if cfg.out else None
    if out is not None:
        check_writable(out, "out")
    policy = load_policy(cfg.checkpoint)
    check_policy(policy, cfg.checkpoint)
    plan = [(j, share, True) for j in cfg.junctions for share in cfg.traffic]
    if cfg.control:
        plan += [(j, cfg.traffic[0], False) for j in cfg.junctions]
    runs, per_episode = [], []
    for j, share, subgoals in plan:
        env_cfg = chain_env(policy.env_config, cfg, j, share, subgoals)
        t0 = time.perf_counter()
        r, results, errors = one_run(policy.actor, env_cfg, cfg)
        r["wall_s"] = round(time.perf_counter() - t0, 1)
        r["name"] = run_name(j, share, subgoals)
        runs.append(r)
        per_episode.append((r["name"], share == cfg.traffic[0] and subgoals, results))
        print(
            f"{r['name']}: success {100 * r['success_rate']:.1f} %, collision "
            f"{100 * r['collision_rate']:.1f} %, jack-knife {100 * r['jackknife_rate']:.1f} %, "
            f"timeout {100 * r['timeout_rate']:.1f} % of {r['episodes']} ({r['wall_s']} s); "
            f"failures by sub-goals passed {r['failed_by_subgoals_passed']}; collisions "
            f"{r['collisions_by_site']}"
        )
        print(format_category_table(r["categories"]), flush=True)
    summary, categories = pooled_tables(per_episode, errors)
    network = chain_env(policy.env_config, cfg, 1, 1.0).task.network
    print(format_category_table(categories))
    tol = policy.env_config.tolerance
    scale = 2.0**-cfg.difficulty
    prov = provenance("cpu")
    if Path(sys.argv[0]).parts[-2:] == ("tools", "__main__.py"):  # python -m ...network.tools
        prov["command"] = shlex.join(["python", "-m", __spec__.name, *sys.argv[1:]])
    data = {
        "provenance": prov,
        "checkpoint": cfg.checkpoint,
        "policy_task": policy.env_config.task.name,
        "task": CELLS_TASK,
        "num_beams": policy.env_config.lidar.num_beams,
        "control": f"{policy.env_config.control.longitudinal}/{policy.env_config.control.lateral}",
        "difficulty": cfg.difficulty,
        "tolerance_position_m": tol.position * scale,
        "tolerance_heading_deg": math.degrees(tol.heading) * scale,
        "seed": cfg.seed,
        "episodes_per_run": cfg.episodes,
        "max_steps": cfg.max_steps,
        "past_exit_m": cfg.past_exit,
        "switch_m": cfg.switch,
        "horizon_m": cfg.horizon,
        "road_width_m": list(network.road_width),
        "block_types": list(network.block_types),
        "headline": f"every route length, {run_name(1, cfg.traffic[0], True).split(', ')[1]}",
        **summary,
        "categories": categories,
        "runs": runs,
    }
    if out is not None:
        out.write_text(json.dumps(data, indent=1) + "\n")
        print(f"wrote {out}")
    return data


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(ChainConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)
