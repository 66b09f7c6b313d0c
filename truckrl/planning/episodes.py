"""Planned episodes scored like a policy's: plan, confirm by replay, report per scene.

Replay
    The best ``replay_candidates`` successful sequences of each scene (or its lowest-cost one when
    none succeeded) are replayed open loop through a fresh eager :class:`~truckrl.env.TruckEnv`
    started with ``set_state`` from the scene's start state. A scene is solved when a replay
    succeeds; the reported outcome, length and errors are those of that replay (else of the
    replay of the lowest-cost sequence), recorded at its first ``done`` as in
    :func:`~truckrl.evaluation.rollout.evaluate_policy`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor

from truckrl.config.fields import ConfigError, build
from truckrl.env import TruckEnv
from truckrl.evaluation.rollout import SCENE_INFO_ENTRIES, policy_actions
from truckrl.planning.config import PlannerConfig
from truckrl.planning.gears import GearPlanner
from truckrl.planning.rollout import Planner, param_keys
from truckrl.planning.scenes import held_out_states
from truckrl.sim.vehicle import trailer_length
from truckrl.tasks import OUTCOMES, EnvConfig, Quantity, shown


@torch.no_grad()
def replay(
    env_cfg: EnvConfig | dict | None,
    states: TensorDictBase,
    actions: Tensor,
    difficulty: float,
    device: torch.device | str = "cpu",
) -> dict[str, Tensor]:
    """Replay open-loop ``actions [N, T, 2]`` from ``states [N]`` through a fresh eager
    :class:`TruckEnv`; record every episode at its first ``done`` (as ``evaluate_policy``).

    Returns:
        ``{flag: [N] bool for "success", "collision", "jackknife", "truncated"; "length" [N];
        the task's errors [N] in their shown units}``.
    """
    cfg = dataclasses.replace(build(EnvConfig, env_cfg, "env"), compile=False)
    n = states.batch_size[0]
    env = TruckEnv(num_envs=n, device=device, config=cfg, seed=0)
    env.set_difficulty(difficulty)
    env.set_state(states)
    errors = env.task.error_quantities
    flags = tuple(o.flag for o in OUTCOMES)
    keys = (*flags, *(q.key for q in errors), "step_count")
    rec = {k: torch.zeros(n, device=device) for k in keys}
    ended = torch.zeros(n, dtype=torch.bool, device=device)
    actions = actions.to(device)
    for t in range(cfg.max_steps):
        a = actions[:, t] if t < actions.shape[1] else torch.zeros(n, 2, device=device)
        nxt = env.step(TensorDict({"action": a}, batch_size=[n], device=device))["next"]
        new = nxt["done"].squeeze(-1) & ~ended
        for k in keys:
            rec[k] = torch.where(new, nxt[k].squeeze(-1).to(torch.float32), rec[k])
        ended |= new
        if bool(ended.all()):
            break
    env.close()
    out = {k: rec[k].bool().cpu() for k in flags}
    out["length"] = rec["step_count"].cpu()
    for q in errors:
        out[q.key] = shown(q, rec[q.key]).cpu()
    return out


def make_planner(
    env_cfg: EnvConfig | dict | None,
    config: PlannerConfig | dict | None = None,
    device: torch.device | str = "cpu",
) -> Planner | GearPlanner:
    """The planner ``config.search`` names: :class:`Planner` (``knots``) or
    :class:`~truckrl.planning.gears.GearPlanner` (``gears``)."""
    pc = build(PlannerConfig, config, "planner")
    kind = GearPlanner if pc.search == "gears" else Planner
    return kind(env_cfg, pc, device)


def _replay_sequences(
    candidates: list[list[tuple[float, float, Tensor]]], horizon: int, extra: Tensor | None
) -> tuple[Tensor, Tensor, int]:
    """Every kept candidate (and each scene's ``extra`` sequence after them) as one batch:
    ``(owner scene [R], actions [R, horizon, 2] zero-padded, number of planner rows)``."""
    owner, seqs = [], []
    for i, cs in enumerate(candidates):
        for _, _, a in cs:
            owner.append(i)
            pad = torch.zeros(horizon, 2)
            pad[: a.shape[0]] = a
            seqs.append(pad)
    n_planned = len(owner)
    if extra is not None:
        e = extra.shape[0]
        owner.extend(range(e))
        pad = torch.zeros(e, horizon, 2)
        t = min(horizon, extra.shape[1])
        pad[:, :t] = extra[:, :t].cpu()
        seqs.extend(pad)
    return torch.tensor(owner), torch.stack(seqs), n_planned


def _pick(
    rep: dict[str, Tensor], owner: Tensor, n_planned: int, e: int, extra: bool
) -> tuple[Tensor, dict[str, dict[str, Tensor]], Tensor | None]:
    """Which replay row reports each scene: ``(row [E], by_source, solved_by_extra [E] | None)``;
    the planner's first successful row, else its first; the extra row where only it succeeds."""
    pick = torch.zeros(e, dtype=torch.long)
    for i in range(e):
        rows = (owner[:n_planned] == i).nonzero().squeeze(-1)
        ok = rep["success"][rows]
        pick[i] = rows[ok.nonzero()[0, 0]] if bool(ok.any()) else rows[0]
    by_source: dict[str, dict[str, Tensor]] = {"planner": {k: v[pick] for k, v in rep.items()}}
    if not extra:
        return pick, by_source, None
    extra_rows = torch.arange(n_planned, n_planned + e)
    by_source["extra"] = {k: v[extra_rows] for k, v in rep.items()}
    use_extra = by_source["extra"]["success"] & ~by_source["planner"]["success"]
    return torch.where(use_extra, extra_rows, pick), by_source, use_extra


def _scene_keys(results: dict[str, Any], states: TensorDictBase, reverse: bool) -> None:
    """Add the scene keys of ``evaluate_policy``'s results, flat and in its dtypes: the vehicle
    parameters, the trailer length and the task's scene metadata (evaluation bins by it)."""
    results["params"] = {k: states["params", k].cpu() for k in param_keys(reverse)}
    results["trailer_length"] = trailer_length(results["params"])
    keys: list[str] = []
    for entry in SCENE_INFO_ENTRIES:
        if entry in states.keys():
            for k in states[entry].keys():
                v = states[entry, k].cpu()
                results[k] = v.long() if k == "route" else v
                keys.append(k)
    results["scene_info_keys"] = tuple(keys)


def plan_states(
    env_cfg: EnvConfig | dict | None,
    states: TensorDictBase,
    difficulty: float,
    config: PlannerConfig | dict | None = None,
    device: torch.device | str = "cpu",
    progress: Callable[[int, int], None] | None = None,
    extra: Tensor | None = None,
) -> tuple[dict[str, Any], tuple[float, float], tuple[Quantity, ...]]:
    """Plan every start state of ``states [E]`` and confirm each plan by replay.

    With ``extra`` (``[E, T', 2]`` action sequences from another controller, e.g. a policy's
    mean actions from :func:`~truckrl.evaluation.rollout.policy_actions`), each scene's extra
    sequence is replayed in the same batch as the planner's candidates, and a scene counts as
    solved when either replay succeeds: the planner's result is reported where it succeeded, else
    the extra sequence's where that did, else the planner's. ``results["by_source"]`` then holds
    both replays (``{"planner": ..., "extra": ...}``, each with the outcome flags, "length" and
    the errors ``[E]``), so each controller can be scored alone on the same scenes.

    Returns:
        ``(results, (position tolerance [m], heading tolerance [deg]), errors)`` as
        :func:`~truckrl.evaluation.rollout.evaluate_policy`; ``results`` holds its per-episode keys
        (from the replay) plus "planned_success" (the planner's own rollout succeeded),
        "replay_mismatch" (it did, but no replay did), "best_ratio" (the largest error /
        tolerance ratio at the closest approach of the best candidate: <= 1 within the
        tolerances), "iterations" and "attempts" (CEM), "actions" ``[E, T, 2]`` (the reported
        sequence, zeros after its end), "params" (the vehicle parameters, ``{key: [E]}``) and
        the totals "rollouts", "plan_seconds"; with ``extra``, also "by_source" (above) and
        "solved_by_extra" ``[E]`` (the reported replay is the extra sequence's).
    """
    planner = make_planner(env_cfg, config, device)
    e, horizon = states.batch_size[0], planner.horizon
    if extra is not None and (extra.dim() != 3 or extra.shape[0] != e or extra.shape[2] != 2):
        raise ValueError(f"extra must be [{e}, T, 2] action sequences, got {list(extra.shape)}")
    plan = planner.plan(states, difficulty, progress)
    owner, acts, n_planned = _replay_sequences(plan["candidates"], horizon, extra)
    rep = replay(planner.env_cfg, states[owner.to(states.device)], acts, difficulty, device)
    pick, by_source, use_extra = _pick(rep, owner, n_planned, e, extra is not None)
    results: dict[str, Any] = {k: v[pick] for k, v in rep.items()}
    if extra is not None:
        results["by_source"] = by_source
        results["solved_by_extra"] = use_extra
    length = results["length"].long()
    steps = torch.arange(horizon)
    results["actions"] = acts[pick] * (steps[None, :, None] < length[:, None, None])
    results["planned_success"] = plan["planned_success"]
    results["replay_mismatch"] = plan["planned_success"] & ~results["success"]
    for key in ("best_ratio", "iterations", "attempts", "rollouts"):
        results[key] = plan[key]
    results["plan_seconds"] = plan["seconds"]
    _scene_keys(results, states, planner.task.reverse)
    return results, _tolerance(planner, difficulty), planner.task.error_quantities


def plan_episodes(
    env_cfg: EnvConfig | dict | None,
    difficulty: float,
    episodes: int,
    seed: int,
    config: PlannerConfig | dict | None = None,
    device: torch.device | str = "cpu",
    indices: Sequence[int] | Tensor | None = None,
    progress: Callable[[int, int], None] | None = None,
    policy: Callable[[TensorDictBase], TensorDictBase] | None = None,
    skip_solved: bool = False,
) -> tuple[dict[str, Any], tuple[float, float], tuple[Quantity, ...]]:
    """Plan the ``episodes`` seeded scenes that ``evaluate_policy(…, episodes, seed)`` scores.

    Args:
        env_cfg: env config (task, vehicle and scene ranges, ``max_steps``, control mode).
        difficulty: curriculum difficulty of the goal test.
        episodes, seed: which scenes (the same as ``evaluate_policy`` with these values).
        config: :class:`PlannerConfig` or a mapping of its fields.
        device: where the rollouts and replays run.
        indices: plan only these of the ``episodes`` scenes (``results["scene_index"]`` says
            which); default all.
        progress: called as ``progress(done, total)`` after every CEM iteration.
        policy: a policy (as ``evaluate_policy`` takes) whose mean actions on the same scenes
            are replayed beside the planner's candidates (``plan_states``'s ``extra``): a scene
            is then solved when the planner or the policy solves it.
        skip_solved: with ``policy``, plan only the scenes whose policy replay fails: a scene
            the policy solves is a witness that it is solvable, and searching it again costs
            the most planning time for no new answer (:func:`_merge_skipped`).

    Returns:
        As :func:`plan_states`, plus ``results["scene_index"] [E]``; with ``skip_solved``,
        also ``results["searched"] [E]`` (bool: the planner searched the scene).
    """
    if skip_solved and policy is None:
        raise ConfigError("skip_solved needs a policy (truckrl plan: checkpoint=)")
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError(f"episodes = {episodes!r} must be a whole number >= 1")
    states = held_out_states(env_cfg, episodes, seed, device, difficulty)
    index = torch.arange(episodes) if indices is None else torch.as_tensor(indices).long()
    if index.numel() and (index.min() < 0 or index.max() >= episodes):
        raise ConfigError(f"indices must lie in [0, {episodes - 1}]")
    states = states[index.to(states.device)]
    extra = None
    if policy is not None:
        extra = policy_actions(policy, build(EnvConfig, env_cfg, "env"), states, difficulty, device)
    if skip_solved:
        first = replay(env_cfg, states, extra, difficulty, device)
        todo = (~first["success"]).nonzero().squeeze(-1)
        part = None
        if todo.numel():
            part = plan_states(
                env_cfg, states[todo.to(states.device)], difficulty, config, device, progress,
                extra[todo.to(extra.device)],
            )  # fmt: skip
        results, tolerance, errors = _merge_skipped(
            env_cfg, states, difficulty, config, first, extra, todo, part
        )
    else:
        results, tolerance, errors = plan_states(
            env_cfg, states, difficulty, config, device, progress, extra
        )
    results["scene_index"] = index
    return results, tolerance, errors


def _tolerance(planner: Planner | GearPlanner, difficulty: float) -> tuple[float, float]:
    """The goal tolerances at ``difficulty``: (position [m], heading [deg])."""
    tol_pos, tol_ang = planner.task.tolerances(torch.tensor([float(difficulty)]))
    return float(tol_pos[0]), math.degrees(float(tol_ang[0]))


def _merge_skipped(
    env_cfg: EnvConfig | dict | None,
    states: TensorDictBase,
    difficulty: float,
    config: PlannerConfig | dict | None,
    first: dict[str, Tensor],
    extra: Tensor,
    todo: Tensor,
    part: tuple[dict[str, Any], tuple[float, float], tuple[Quantity, ...]] | None,
) -> tuple[dict[str, Any], tuple[float, float], tuple[Quantity, ...]]:
    """:func:`plan_states`'s results for all ``E`` scenes where only the ``todo`` ones were
    planned (``part``, None when there were none): the other rows are the policy's replay
    ``first`` (solved by it, ``solved_by_extra``), never planned (``planned_success`` False,
    ``best_ratio`` NaN, no iterations). ``by_source["planner"]`` holds the planned rows only
    (``results["searched"]`` says which), ``by_source["extra"]`` every row."""
    planner = make_planner(env_cfg, config, "cpu")  # its task's tolerances and keys only
    e, horizon = states.batch_size[0], planner.horizon
    searched = torch.zeros(e, dtype=torch.bool)
    searched[todo.cpu()] = True
    acts = torch.zeros(e, horizon, 2)
    t = min(horizon, extra.shape[1])
    acts[:, :t] = extra[:, :t].cpu()
    length = first["length"].long()
    results: dict[str, Any] = {k: v.clone() for k, v in first.items()}
    results["actions"] = acts * (torch.arange(horizon)[None, :, None] < length[:, None, None])
    results["planned_success"] = torch.zeros(e, dtype=torch.bool)
    results["replay_mismatch"] = torch.zeros(e, dtype=torch.bool)
    results["best_ratio"] = torch.full((e,), math.nan)
    results["iterations"] = torch.zeros(e, dtype=torch.long)
    results["attempts"] = torch.zeros(e, dtype=torch.long)
    results["solved_by_extra"] = first["success"].clone()
    results["rollouts"], results["plan_seconds"] = 0, 0.0
    by_planner: dict[str, Tensor] = {k: v[:0] for k, v in first.items()}
    if part is not None:
        got = part[0]
        rows = todo.cpu()
        for k, v in results.items():
            if isinstance(v, Tensor) and k in got:
                v[rows] = got[k].to(v.dtype)
        results["rollouts"], results["plan_seconds"] = got["rollouts"], got["plan_seconds"]
        by_planner = got["by_source"]["planner"]
    results["by_source"] = {"planner": by_planner, "extra": first}
    results["searched"] = searched
    _scene_keys(results, states, planner.task.reverse)
    return results, _tolerance(planner, difficulty), planner.task.error_quantities


def category_info(results: dict[str, Any]) -> dict[str, Tensor]:
    """Per-episode inputs of :func:`truckrl.evaluation.categories.task_bins` from plan results:
    the trailer length and the task's scene metadata keys."""
    keys = ("trailer_length", *results.get("scene_info_keys", ()))
    return {k: results[k] for k in keys if k in results}
