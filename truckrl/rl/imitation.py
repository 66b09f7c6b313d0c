"""Behaviour cloning from demonstrations: a start for PPO that already drives every route.

PPO from scratch can settle on standing still where its first attempts crash (docs/ablations.md, "Right
turns from scratch"): with the paper's rewards and discount a timeout later costs less than a crash now.
Demonstrations of successful episodes give it a start that drives. This module turns them into a
policy start:

* :func:`demonstrations` replays action sequences (the planner's, :mod:`truckrl.planning`)
  through an eager :class:`~truckrl.env.TruckEnv` started from the same scene states and records
  what the policy would have seen before each action: ``observation [M, F]``, ``lidar [M, R]``
  and the demonstrated ``action [M, 2]``, for every step up to the end of each episode (``M``
  samples in all). A replay that does not end in success is dropped (the count is returned).
* :func:`behaviour_clone` fits the actor's mean ("loc") to those actions by mean squared error
  with Adam, shuffled minibatches, a fixed seed; the critic and the log-std are left alone (the
  log-std is then set by the caller).

Who demonstrates (``demos.source``): ``planner``, the CEM planner on any task; ``driver``, the
task's own scripted demonstrator, the ``demonstrations`` function of its folder's ``expert.py``
(looked up by task name, :func:`truckrl.planning.experts.scripted_demonstrations`; closed loop,
successful episodes only).

``truckrl tools imitate`` wraps both and writes a training checkpoint that
``truckrl train resume=<dir>`` continues; :func:`bootstrap` does the whole chain (plan,
replay, clone) inside ``truckrl train demos.episodes=N``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from torch import Tensor

from truckrl.env import TruckEnv
from truckrl.rl.checkpoint import save_checkpoint
from truckrl.rl.network import LIDAR_KEY, OBS_KEY, ActorCritic
from truckrl.tasks import EnvConfig


def demonstrations(
    env_cfg: EnvConfig,
    states: TensorDict,
    actions: Sequence[Sequence[Sequence[float]]],
    difficulty: float,
) -> tuple[TensorDict, int]:
    """Replay action sequences from start states; keep the successful episodes' samples.

    Args:
        env_cfg: the env config the plans were made with.
        states: ``[E]`` start states (:meth:`TruckEnv.get_state` layout).
        actions: ``E`` sequences of ``[2]`` actions in ``[-1, 1]`` (lengths may differ).
        difficulty: the difficulty the plans were made at (it decides when an episode ends).

    Returns:
        ``(samples, kept)``: ``samples`` ``[M]`` with "observation", "lidar" and "action";
        ``kept`` = the number of episodes whose replay succeeded.
    """
    e = int(states.batch_size[0])
    if len(actions) != e:
        raise ValueError(f"{len(actions)} action sequences for {e} start states")
    lengths = torch.tensor([len(a) for a in actions])
    horizon = int(lengths.max()) if e else 0
    acts = torch.zeros(e, horizon, 2)
    for j, seq in enumerate(actions):
        if len(seq):
            acts[j, : len(seq)] = torch.as_tensor(seq, dtype=torch.float32)
    env = TruckEnv(num_envs=e, config=dataclasses.replace(env_cfg, compile=False), seed=0)
    env.set_difficulty(difficulty)
    td = env.set_state(states.clone())
    alive = torch.ones(e, dtype=torch.bool)
    succeeded = torch.zeros(e, dtype=torch.bool)
    rows: list[tuple[Tensor, Tensor, Tensor, Tensor]] = []
    for t in range(horizon):
        take = alive & (t < lengths)
        rows.append((take, td[OBS_KEY], td[LIDAR_KEY], acts[:, t]))
        nxt = env.step(td.set("action", acts[:, t]))["next"]
        done = nxt["done"].squeeze(-1)
        succeeded |= take & done & nxt["success"].squeeze(-1)
        alive &= ~done & (t + 1 < lengths)
        td = nxt
    env.close()
    keep = [(m & succeeded, o, li, a) for m, o, li, a in rows]
    samples = TensorDict(
        {
            OBS_KEY: torch.cat([o[m] for m, o, _, _ in keep]),
            LIDAR_KEY: torch.cat([li[m] for m, _, li, _ in keep]),
            "action": torch.cat([a[m] for m, _, _, a in keep]),
        }
        if keep
        else {
            OBS_KEY: torch.zeros(0, env.task.num_features),
            LIDAR_KEY: torch.zeros(0, env_cfg.lidar.num_beams),
            "action": torch.zeros(0, 2),
        },
        batch_size=[sum(int((m & succeeded).sum()) for m, *_ in keep)],
    )
    return samples, int(succeeded.sum())


def action_mse(ac: ActorCritic, batch: TensorDict, executed: bool = False) -> Tensor:
    """Mean squared error ``[]`` between the actor's mean ("loc") and ``batch["action"]``.

    ``batch`` is ``[B]`` with "observation", "lidar" and "action" (a :func:`demonstrations`
    slice); differentiable in the trunk and the mean head. ``executed``: the mean as the env
    executes it, clamped to ``[-1, 1]`` (``demos.bc_loss = executed``), with the gradient passed
    straight through the clamp: a mean beyond the bound on the demonstrated side costs nothing,
    one that should come back inside is pulled in. A trained policy's mean often lies far past
    the bound (full throttle), where the plain error would pull it in although the truck already
    does what the demonstration does.
    """
    # the trunk and the mean head only: no action is sampled (no random numbers spent)
    loc = ac.actor.get_dist_params(batch.select(OBS_KEY, LIDAR_KEY))["loc"]
    if executed:
        loc = loc + (loc.clamp(-1.0, 1.0) - loc).detach()
    return (loc - batch["action"]).square().mean()


#: Where a run keeps its demonstration samples when PPO goes on cloning (``demos.bc_coeff``).
SAMPLES_NAME = "demos.pt"
_SAMPLE_KEYS = (OBS_KEY, LIDAR_KEY, "action")


def save_samples(path: str | Path, samples: TensorDict) -> Path:
    """Write demonstration samples atomically (tensors only: loads with ``weights_only=True``)."""
    return save_checkpoint(path, {k: samples[k].detach().cpu() for k in _SAMPLE_KEYS})


def load_samples(path: str | Path) -> TensorDict:
    """Read :func:`save_samples`' file back as ``[M]`` samples.

    Raises:
        ValueError: missing, unreadable or not a samples file (one line naming the file).
    """
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
        return TensorDict({k: data[k] for k in _SAMPLE_KEYS}, batch_size=[len(data["action"])])
    except FileNotFoundError:
        raise ValueError(f"{path} does not exist") from None
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same one-line error
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise ValueError(f"{path} is not a demonstrations file ({first})") from None


def behaviour_clone(
    ac: ActorCritic,
    samples: TensorDict,
    epochs: int,
    lr: float,
    batch_size: int,
    seed: int = 0,
    executed: bool = False,
) -> list[float]:
    """Fit the actor's mean to ``samples["action"]`` (MSE, :func:`action_mse` with
    ``executed``); return the mean loss of each epoch.

    Only the trunk and the mean head move (the log-std has no gradient in this loss; the value
    head is not in the actor).
    """
    n = int(samples.batch_size[0])
    if n == 0:
        raise ValueError("no demonstration samples to clone")
    gen = torch.Generator().manual_seed(seed)
    params = [p for name, p in ac.actor.named_parameters() if not name.endswith("log_std")]
    opt = torch.optim.Adam(params, lr=lr)
    losses = []
    for _ in range(epochs):
        order = torch.randperm(n, generator=gen)
        total = 0.0
        for start in range(0, n, batch_size):
            b = samples[order[start : start + batch_size]]
            loss = action_mse(ac, b, executed)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * int(b.batch_size[0])
        losses.append(total / n)
    return losses


def set_action_std(ac: ActorCritic, std: float) -> None:
    """Set the policy's state-independent std [action units] for every action dimension."""
    with torch.no_grad():
        ac.gaussian.log_std.fill_(math.log(std))
    ac.gaussian.project_()  # within model.max_std


def plan_demos(plan: dict[str, Any]) -> tuple[list[int], list[list[list[float]]]]:
    """Scene indices and action sequences of the successful episodes of a ``plan.json`` that
    holds one (``truckrl plan skip_solved=true`` writes none for the scenes the policy solved)."""
    episodes = [e for e in plan["per_episode"] if e["success"] and "actions" in e]
    return [int(e["scene_index"]) for e in episodes], [e["actions"] for e in episodes]


def _driven(env_cfg: EnvConfig, dc: Any) -> tuple[Tensor, TensorDict]:
    """``dc.episodes`` scenes of seed ``dc.seed`` driven by the task's scripted demonstrator
    (``expert.demonstrations`` of its folder): ``(solved [E], samples [M])``.

    Raises:
        ConfigError: the task's folder has no such demonstrator.
    """
    from truckrl.planning import scripted_demonstrations

    drive = scripted_demonstrations(env_cfg.task.name)
    return drive(env_cfg, dc.episodes, dc.seed, dc.difficulty)


def bootstrap(
    ac: ActorCritic,
    env_cfg: EnvConfig,
    dc: Any,
    device: torch.device | str = "cpu",
    seed: int = 0,
    progress: Any = None,
    on_round: Any = None,
) -> tuple[dict[str, Any], TensorDict]:
    """Plan ``dc.episodes`` scenes of seed ``dc.seed`` (``dc.source`` "planner"; "driver":
    drive them with the task's scripted demonstrator, its folder's ``expert.demonstrations``),
    clone the successful episodes into ``ac``'s actor and set its std: a training run's start
    (``train demos.episodes=N``).

    Args:
        ac: the fresh actor-critic (changed in place: trunk and mean head, log-std).
        env_cfg: the training's env config (the plans use it).
        dc: :class:`~truckrl.config.schemas.DemosConfig`; the planner runs on ``dc.device`` when set,
            else on ``device``.
        device: where ``ac`` is and the cloning runs.
        seed: behaviour-cloning shuffle seed.
        progress: ``progress(done, total)`` after every planner iteration, or None.
        on_round: ``on_round(r, record)`` after every DAgger round (:func:`dagger`), or None.

    With ``dc.dagger_rounds > 0`` (source "driver") :func:`dagger` follows the first clone.

    Returns:
        ``(summary, samples)``: a JSON-ready summary (scenes, source, the demonstrator's success
        rate, episodes kept, their samples, losses, the DAgger rounds, seconds) and the ``[M]``
        samples it cloned (the rounds' included).

    Raises:
        ValueError: no episode succeeded (nothing to clone), or ``source`` "driver" with a task
            whose expert has no ``demonstrations`` (a ConfigError).
    """
    import time

    from truckrl.planning import PlannerConfig, held_out_states, plan_states

    t0 = time.perf_counter()
    if dc.source == "driver":
        success, samples = _driven(env_cfg, dc)
    else:
        overrides = {"compile": dc.compile}
        overrides |= {k: getattr(dc, k) for k in ("samples", "iterations") if getattr(dc, k)}
        where = dc.device or device
        states = held_out_states(env_cfg, dc.episodes, dc.seed, where)
        results, _, _ = plan_states(
            env_cfg, states, dc.difficulty, PlannerConfig(**overrides), where, progress
        )
        success = results["success"]
    t_plan = time.perf_counter() - t0
    ok = success.nonzero().squeeze(-1)
    if ok.numel() == 0:
        raise ValueError(
            f"the {dc.source} solved none of {dc.episodes} scenes at difficulty "
            f"{dc.difficulty:g}: nothing to clone (lower demos.difficulty or raise demos.episodes)"
        )
    if dc.source == "driver":
        kept = int(ok.numel())
    else:
        lengths = results["length"].long()
        actions = [results["actions"][j, : int(lengths[j])].tolist() for j in ok.tolist()]
        samples, kept = demonstrations(
            env_cfg, states[ok.to(states.device)].cpu(), actions, dc.difficulty
        )
    losses = behaviour_clone(
        ac, samples.to(device), dc.epochs, dc.lr, dc.batch_size, seed, dc.bc_loss == "executed"
    )
    shown = int(samples.batch_size[0])  # the demonstrations' own samples
    rounds = []
    if dc.dagger_rounds > 0:
        samples, rounds = dagger(ac, env_cfg, dc, samples, device, seed, on_round)
    set_action_std(ac, dc.std)
    summary = {
        "scenes": dc.episodes,
        "seed": dc.seed,
        "difficulty": dc.difficulty,
        "source": dc.source,
        "planner_success_rate": success.float().mean().item(),
        "plans_kept": kept,
        "samples": shown,
        "epochs": dc.epochs,
        "losses": losses,
        "plan_seconds": t_plan,
        "dagger": rounds,
        "seconds": time.perf_counter() - t0,
    }
    return summary, samples


def dagger(
    ac: ActorCritic,
    env_cfg: EnvConfig,
    dc: Any,
    samples: TensorDict,
    device: torch.device | str = "cpu",
    seed: int = 0,
    on_round: Any = None,
) -> tuple[TensorDict, list[dict[str, Any]]]:
    """``dc.dagger_rounds`` rounds of DAgger (Ross, Gordon and Bagnell 2011) on the cloned ``ac``.

    Each round ``r`` (1, 2, ...) lets ``ac``'s mean action drive the ``dc.dagger_episodes``
    scenes of seed ``dc.seed + r`` at ``dc.difficulty`` (on the CPU), labels every state it
    visits with the task's demonstrator's action (its expert's ``labelled``), adds those samples
    to ``samples`` and fits the actor to all of them for ``dc.dagger_epochs`` passes, from where
    it stands. A clone's mistakes take it to states the demonstrations never show; the labels
    teach it the way back.

    ``on_round(r, record)``, where given, is called with each round's record as it ends.

    Returns:
        ``(samples, rounds)``: all samples (``[M]``, the demonstrations first) and per round a
        JSON-ready record (scene seed, the clone's success rate on its scenes before the fit,
        samples added, losses, seconds).
    """
    import time

    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from truckrl.planning import scripted_labels

    labelled = scripted_labels(env_cfg.task.name)
    actor = ac.actor

    def act(td: TensorDict) -> Tensor:
        obs = td.select(OBS_KEY, LIDAR_KEY).to(device)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            return actor(obs)["action"].cpu()

    rounds = []
    for r in range(1, dc.dagger_rounds + 1):
        t0 = time.perf_counter()
        solved, fresh = labelled(env_cfg, dc.dagger_episodes, dc.seed + r, dc.difficulty, act)
        samples = torch.cat([samples.cpu(), fresh.cpu()])
        losses = behaviour_clone(
            ac, samples.to(device), dc.dagger_epochs, dc.lr, dc.batch_size, seed + r,
            dc.bc_loss == "executed",
        )  # fmt: skip
        rounds.append(
            {
                "seed": dc.seed + r,
                "scenes": dc.dagger_episodes,
                "clone_success_rate": solved.float().mean().item(),
                "samples_added": int(fresh.batch_size[0]),
                "losses": losses,
                "seconds": time.perf_counter() - t0,
            }
        )
        if on_round is not None:
            on_round(r, rounds[-1])
    return samples, rounds
