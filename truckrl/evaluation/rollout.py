"""Deterministic evaluation: one episode per seeded scene with the policy's mean action."""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.config.fields import ConfigError
from truckrl.env import TruckEnv
from truckrl.evaluation.interval import wilson_interval
from truckrl.sim.vehicle import trailer_length
from truckrl.tasks import OUTCOMES, EnvConfig, Quantity, shown

#: What :func:`evaluate_policy` runs: a TorchRL actor, or any callable of :func:`as_policy`'s two
#: conventions (``td -> td`` setting "action", or ``obs -> action``).
Policy = TensorDictModuleBase | Callable[..., Any]


def as_policy(policy: Policy) -> Callable[[TensorDictBase], TensorDictBase]:
    """Any policy as ``td [N] -> td [N]`` with "action" ``[N, 2]``.

    A TorchRL module is returned as it is. Any other callable is called by its number of
    required positional parameters, and what it returns decides the rest:

    - one: ``policy(td)`` with the env's tensordict ``[N]`` ("observation", "lidar", the flags);
      it returns a tensordict holding "action" (``td -> td``), or the action itself;
    - two: ``policy(observation [N, F], lidar [N, R])``, the exported model's inputs
      (``obs -> action``); it returns the action.

    An action is a tensor or array ``[N, 2]`` (any float dtype), moved to the env's device as
    float32; the env clamps it to ``[-1, 1]``. Two conventions because a TorchRL policy reads
    a tensordict while a controller written outside truckrl, or an exported model, reads arrays.

    Raises:
        ConfigError: (on call) an action that is not ``[N, 2]``.
    """
    if isinstance(policy, TensorDictModuleBase):
        return policy
    arrays = _required_positional(policy) >= 2

    def run(td: TensorDictBase) -> TensorDictBase:
        out = policy(td["observation"], td["lidar"]) if arrays else policy(td)
        if isinstance(out, TensorDictBase):
            return out
        return td.set("action", _action(out, td))

    return run


def _required_positional(f: Callable) -> int:
    """How many positional parameters ``f`` requires (1 when it has no signature)."""
    try:
        params = inspect.signature(f).parameters.values()
    except (TypeError, ValueError):
        return 1
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    return sum(p.kind in kinds and p.default is inspect.Parameter.empty for p in params)


def _action(a: Any, td: TensorDictBase) -> Tensor:
    """A returned action as float32 ``[N, 2]`` on the env's device."""
    a = torch.from_numpy(np.asarray(a)) if not isinstance(a, Tensor) else a
    n = td.batch_size[0]
    if tuple(a.shape) != (n, 2):
        raise ConfigError(f"the policy returned an action of shape {list(a.shape)}, not [{n}, 2]")
    return a.to(td.device, torch.float32)


#: State entries that hold a task's per-episode scene metadata ``{key: [N]}``: ``route`` (the
#: intersection task's, named after its main key) and ``scene_info`` (other tasks).
SCENE_INFO_ENTRIES = ("route", "scene_info")

#: Control-state quantities (:mod:`truckrl.sim.control`'s chains) recorded after every step of an
#: episode for :func:`smoothness`, with their units: the smoothness a control mode buys shows in
#: the realised jerk and steering rate whichever quantity the policy commands.
MOTION = (
    ("accel", "m/s^2"),
    ("jerk", "m/s^3"),
    ("steer_rate", "rad/s"),
    ("steer_accel", "rad/s^2"),
)


@torch.no_grad()
def evaluate_policy(
    actor: Policy,
    env_cfg: EnvConfig,
    difficulty: float,
    episodes: int,
    seed: int,
    device: str | torch.device = "cpu",
    record_paths: bool = False,
) -> tuple[dict[str, Tensor], tuple[float, float], tuple[Quantity, ...]]:
    """Run one episode in each of ``episodes`` seeded scenes with the mean action.

    All episodes run as one batch; each env's first episode is recorded at its first ``done``
    (every episode ends by ``env_cfg.max_steps``). The same ``seed`` gives the same scenes.

    Args:
        actor: the policy. A TorchRL actor (``TensorDictModule``) runs under
            ``ExplorationType.DETERMINISTIC``, i.e. with its mean action. Any other callable
            works too (a scripted controller, an exported model), in either convention of
            :func:`as_policy`: ``td -> td`` (it gets the env's tensordict ``[E]``:
            "observation", "lidar", the flags, and returns a tensordict ``[E]`` with "action"
            ``[E, 2]``) or ``obs -> action`` (``f(observation [E, F], lidar [E, R])`` returns
            the action ``[E, 2]``, a tensor or array). The env clamps actions to ``[-1, 1]``.
            It runs under ``torch.no_grad()``. Example, a controller that holds half throttle
            and steers against the goal's lateral offset::

                def drive(observation, lidar):
                    return torch.stack(
                        [torch.full_like(observation[:, 0], 0.5), -0.3 * observation[:, 1]], -1
                    )

                results, tolerance, errors = evaluate_policy(drive, EnvConfig(), 0.0, 20, 0)

    Returns:
        ``(results, (position tolerance [m], heading tolerance [deg]), errors)``: ``results``
        holds per-episode ``[E]`` tensors on CPU: one bool per outcome flag ("success",
        "collision", "jackknife", "truncated"), "length" [steps] and each of the task's
        ``errors`` at the episode's last step, in its shown unit (m or deg). It also holds each
        episode's scene, read from the env's state at reset, so that row ``i`` of every entry
        is the same episode: "trailer_length" [m] (front overhang + wheelbase + rear overhang)
        and every scene metadata entry the task records (``state["route"]`` or
        ``state["scene_info"]``, :data:`SCENE_INFO_ENTRIES`): for the
        intersection task the :data:`~truckrl.tasks.intersection.scene.ROUTE_KEYS`, "route" (long,
        ``ROUTE_*``), "turn_angle" and "crossing_angle" [rad], "start_road_width",
        "goal_road_width" and "goal_distance" [m]. ``results`` is thus a valid input of
        :func:`truckrl.evaluation.categories.task_bins`. With ``record_paths`` it also holds "path"
        ``[E, T + 1, 4]``: the pose ``(x, y, heading, articulation)`` [m, m, rad, rad] at the
        start and after each step, held at its last value once the episode has ended (``T``:
        the steps the batch ran); the start states themselves (the scenes) are
        ``truckrl.planning.held_out_states`` of the same env config, seed and
        difficulty. "motion" ``[E, T, 4]`` holds the :data:`MOTION` quantities after each step
        of the episode (in their units; NaN after the episode's end), the input of
        :func:`smoothness`.
    """
    # eager: a one-off batch does not repay the compile time
    env_cfg = dataclasses.replace(env_cfg, compile=False)
    actor = as_policy(actor)
    env = TruckEnv(num_envs=episodes, device=device, config=env_cfg, seed=seed)
    env.set_difficulty(difficulty)
    tol_pos, tol_ang = env.tolerances()
    tolerance = (float(tol_pos[0]), math.degrees(float(tol_ang[0])))
    errors = env.task.error_quantities
    flags = tuple(o.flag for o in OUTCOMES)
    keys = (*flags, *(q.key for q in errors), "step_count")
    rec = {k: torch.zeros(episodes, device=device) for k in keys}
    ended = torch.zeros(episodes, dtype=torch.bool, device=device)
    td = env.reset()
    start = env.get_state()
    scene = _scene_of(start)
    path = [start["pose"]] if record_paths else None
    motion = []
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env_cfg.max_steps):
            nxt = env.step(actor(td))["next"]
            new = nxt["done"].squeeze(-1) & ~ended
            for k in keys:
                rec[k] = torch.where(new, nxt[k].squeeze(-1).to(torch.float32), rec[k])
            after = env.get_state()  # the state after the step (an ended truck keeps its pose)
            if path is not None:
                path.append(torch.where(ended[:, None], path[-1], after["pose"]))
            q = torch.stack([after[k].to(torch.float32) for k, _ in MOTION], -1)
            motion.append(torch.where(ended[:, None], torch.nan, q))
            ended |= new
            if bool(ended.all()):
                break
            td = nxt
    env.close()
    results = _results(rec, flags, errors, scene, path)
    results["motion"] = torch.stack(motion, 1).cpu()
    return results, tolerance, errors


def _scene_of(start: TensorDictBase) -> dict[str, Tensor]:
    """Each episode's scene from the state at reset: "trailer_length" [m] and every entry of the
    task's scene metadata (:data:`SCENE_INFO_ENTRIES`), each ``[E]``."""
    scene = {"trailer_length": trailer_length(start["params"])}
    for entry in SCENE_INFO_ENTRIES:
        if entry in start.keys():
            scene |= {k: start[entry, k] for k in start[entry].keys()}
    return scene


def _results(
    rec: dict[str, Tensor],
    flags: tuple[str, ...],
    errors: tuple[Quantity, ...],
    scene: dict[str, Tensor],
    path: list[Tensor] | None,
) -> dict[str, Tensor]:
    """:func:`evaluate_policy`'s ``results`` on CPU from the values recorded at each episode's
    end ``rec`` (flags, errors and "step_count"), the ``scene`` and the poses ``path``."""
    out = {k: rec[k].bool().cpu() for k in flags}
    out["length"] = rec["step_count"].cpu()
    for q in errors:
        out[q.key] = shown(q, rec[q.key]).cpu()
    for k, v in scene.items():
        out[k] = v.long().cpu() if k == "route" else v.cpu()
    if path is not None:
        out["path"] = torch.stack(path, 1).cpu()
    return out


def summarize(results: dict[str, Tensor], errors: tuple[Quantity, ...]) -> dict[str, Any]:
    """Outcome rates, the success rate's 95 % interval (``"success_ci95": [lo, hi]``,
    :func:`~truckrl.evaluation.interval.wilson_interval`), mean length and mean / p95 of the
    final errors over episodes."""
    n = int(results["success"].numel())
    out: dict[str, Any] = {"episodes": n}
    for o in OUTCOMES:
        out[f"{o.name}_rate"] = results[o.flag].float().mean().item()
    out["success_ci95"] = list(wilson_interval(int(results["success"].sum()), n))
    out["mean_length"] = results["length"].mean().item()
    for q in errors:
        v = results[q.key].to(torch.float64)
        out[f"{q.key}_{q.shown_unit}_mean"] = v.mean().item()
        out[f"{q.key}_{q.shown_unit}_p95"] = torch.quantile(v, 0.95).item()
    return out


#: Percentiles of :func:`smoothness` [%].
SMOOTHNESS_PERCENTILES = (50, 95, 99)


def smoothness(results: dict[str, Tensor]) -> dict[str, float] | None:
    """Percentiles of the magnitude of each :data:`MOTION` quantity over every step of the
    successful episodes of ``results`` (:func:`evaluate_policy`'s), keyed
    ``"<quantity>_<unit>_p<q>"`` (e.g. ``jerk_m/s^3_p95``), plus ``"steps"``, the steps pooled.
    None when no episode succeeded. Successful episodes only, so that a policy is not credited
    with the calm of a truck that stopped or crashed early."""
    m = results["motion"][results["success"]].reshape(-1, len(MOTION)).double().numpy()
    m = m[~np.isnan(m).any(-1)]
    if m.shape[0] == 0:
        return None
    pct = np.percentile(np.abs(m), SMOOTHNESS_PERCENTILES, axis=0)  # [P, 4], linear
    out: dict[str, float] = {"steps": int(m.shape[0])}
    for i, (key, unit) in enumerate(MOTION):
        for j, p in enumerate(SMOOTHNESS_PERCENTILES):
            out[f"{key}_{unit}_p{p}"] = float(pct[j, i])
    return out


@torch.no_grad()
def policy_actions(
    actor: Policy,
    env_cfg: EnvConfig,
    states: TensorDictBase,
    difficulty: float,
    device: str | torch.device = "cpu",
) -> Tensor:
    """The actions ``[E, T, 2]`` that ``actor``'s mean action applies from each start state of
    ``states [E]`` (as from :meth:`TruckEnv.get_state`) in one episode of at most ``T =
    env_cfg.max_steps`` steps; zeros after the episode's first ``done``.

    The sequence is open loop: replayed from the same start state through the deterministic
    simulator (``planner.replay``) it drives the same episode, which is how
    ``truckrl plan checkpoint=`` checks a policy's solutions with the planner's replay.
    """
    env_cfg = dataclasses.replace(env_cfg, compile=False)
    actor = as_policy(actor)
    e = states.batch_size[0]
    env = TruckEnv(num_envs=e, device=device, config=env_cfg, seed=0)
    env.set_difficulty(difficulty)
    td = env.set_state(states)
    out = torch.zeros(e, env_cfg.max_steps, 2, device=device)
    ended = torch.zeros(e, dtype=torch.bool, device=device)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for t in range(env_cfg.max_steps):
            td = actor(td)
            out[:, t] = torch.where(ended[:, None], 0.0, td["action"].clamp(-1.0, 1.0))
            nxt = env.step(td)["next"]
            ended |= nxt["done"].squeeze(-1)
            if bool(ended.all()):
                break
            td = nxt
    env.close()
    return out.cpu()
