"""The cross-entropy method (CEM) over the planner's candidates, scene by scene (:func:`cem`).

An *attempt* at a scene samples a diagonal Gaussian over the parameters (its initial mean and std
from the planner's ``initial(attempt, arc)``: for the knot planner mean 0, speeds at
``speed_mean``, std ``init_std``), clamped to ``[-1, 1]``; the best ``elite_frac`` of its
population (which always holds its best candidate so far) give the next mean and std, blended
with the old ones by ``smoothing`` and floored at ``min_std``. An attempt ends after
``iterations`` iterations; a scene gets up to ``attempts`` independent attempts (restarts escape
local minima) and stops as soon as a candidate succeeds with every error within ``stop_margin``
of its tolerance. Attempts are queued through the batch's ``scenes_per_batch`` slots: first
attempts, then restarts; when the queue runs dry, idle slots start the remaining attempts of the
scenes still running, then join their populations.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import torch
from tensordict import TensorDictBase
from torch import Tensor

from truckrl.config.fields import check_range
from truckrl.planning.config import PlannerConfig
from truckrl.tasks import MAX_DIFFICULTY

if TYPE_CHECKING:
    from truckrl.planning.rollout import Planner

#: Cost subtracted from a successful candidate: every success ranks before every failure.
SUCCESS_BONUS = 1.0e6

#: A kept candidate: ``(cost, score, applied actions [T, 2])``.
Candidate = tuple[float, float, Tensor]


class _Job:
    """One CEM attempt at one scene: its Gaussian over the parameters and its best candidate."""

    def __init__(
        self, scene: int, pc: PlannerConfig, mean: Tensor, std: Tensor, arc: bool = False
    ) -> None:
        self.scene, self.pc, self.iters, self.arc = scene, pc, 0, arc
        self.mean, self.std = mean, std
        self.best_x = self.mean.clone()
        self.best_cost = math.inf

    def update(self, elites: Tensor) -> None:
        a = self.pc.smoothing
        self.mean = a * self.mean + (1.0 - a) * elites.mean(0)
        self.std = (a * self.std + (1.0 - a) * elites.std(0)).clamp_min(self.pc.min_std)
        self.iters += 1


class _Search:
    """The bookkeeping of one :func:`cem` call over ``e`` scenes (per-scene tensors ``[e]``)."""

    def __init__(self, planner: Planner, e: int) -> None:
        self.planner, self.pc, self.dev = planner, planner.config, planner.device
        self.best_cost = torch.full((e,), math.inf)
        self.best_ratio = torch.full((e,), math.inf)
        self.iters = torch.zeros(e, dtype=torch.int64)
        self.started = torch.zeros(e, dtype=torch.int64)
        self.done = torch.zeros(e, dtype=torch.bool)
        self.cands: list[list[Candidate]] = [[] for _ in range(e)]
        self.queue = list(range(e))  # scenes waiting for their first attempt
        self.jobs: list[_Job] = []
        self.rollouts = 0

    def fill(self) -> None:
        """Fill the slots: first attempts, then restarts of unsolved scenes, then share."""
        pc, started = self.pc, self.started
        while len(self.jobs) < pc.scenes_per_batch:
            if self.queue:
                scene = self.queue.pop(0)
                if self.done[scene]:
                    continue
            else:
                running = dict.fromkeys(j.scene for j in self.jobs)
                spare = [i for i in running if started[i] < pc.attempts]
                if not spare:
                    break
                scene = min(spare, key=lambda i: int(started[i]))
            started[scene] += 1
            arc = pc.steer_prior == "arc" or (
                pc.steer_prior == "alternate" and int(started[scene]) % 2 == 1
            )
            mean, std = self.planner.initial(int(started[scene]) - 1, arc)
            self.jobs.append(_Job(scene, pc, mean, std, arc))

    def sample(self, owner: list[_Job], g: torch.Generator) -> Tensor:
        """``[slots * samples, P]`` candidates of the slots' attempts ``owner``."""
        slots, k, p = len(owner), self.pc.samples, self.planner.num_params
        mean = torch.stack([j.mean for j in owner])
        std = torch.stack([j.std for j in owner])
        xs = mean[:, None] + std[:, None] * torch.randn(slots, k, p, generator=g, device=self.dev)
        xs = xs.clamp(-1.0, 1.0)
        for j, job in enumerate(owner):
            if job.iters > 0 and owner.index(job) == j:
                xs[j, 0] = job.best_x  # elitism: the best candidate so far rides along
        return xs.reshape(slots * k, p)

    def learn(self, job: _Job, sel: Tensor, x: Tensor, acc: dict[str, Tensor], actions: Tensor):
        """Update attempt ``job`` and its scene from its rows ``sel`` of the batch's candidates
        ``x``, their rollout ``acc`` (costs on the host) and ``actions [T, N, 2]``."""
        pc, i = self.pc, job.scene
        cost, score, worst, length = acc["cost"], acc["best"], acc["worst"], acc["length"]
        c, xi = cost[sel], x[sel.to(self.dev)]
        order = torch.argsort(c)
        job.update(xi[order.to(self.dev)[: max(2, math.ceil(pc.elite_frac * sel.numel()))]])
        top = int(sel[order[0]])
        if cost[top] < job.best_cost:
            job.best_cost, job.best_x = float(cost[top]), x[top].clone()
        if cost[top] < self.best_cost[i]:
            self.best_cost[i], self.best_ratio[i] = cost[top], worst[top]
        new = [
            (float(cost[r]), float(score[r]), actions[: int(length[r]), r].cpu())
            for r in sel[order[: pc.replay_candidates]].tolist()
        ]
        merged = sorted(
            {(z[0], z[1]): z for z in self.cands[i] + new}.values(), key=lambda z: z[0]
        )  # a rollout is deterministic: the elite carried over repeats its cost exactly
        succeeded = [z for z in merged if z[0] < 0]
        self.cands[i] = succeeded[: pc.replay_candidates] if succeeded else merged[:1]
        self.iters[i] += 1
        if self.best_cost[i] < 0 and self.best_ratio[i] <= pc.stop_margin:
            self.done[i] = True  # solved with room to spare: stop every attempt

    def retire(self) -> None:
        """Drop the attempts of solved scenes and those that used up their iterations; queue a
        restart of an unsolved scene, or give it up after ``attempts``."""
        pc, done = self.pc, self.done
        ended = [j for j in self.jobs if j.iters >= pc.iterations]
        self.jobs = [j for j in self.jobs if not done[j.scene] and j.iters < pc.iterations]
        for job in ended:
            i = job.scene
            if done[i] or any(j.scene == i for j in self.jobs) or i in self.queue:
                continue
            if self.started[i] < pc.attempts:
                self.queue.append(i)
            else:
                done[i] = True


@torch.no_grad()
def cem(
    planner: Planner,
    states: TensorDictBase,
    difficulty: float,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Plan every scene of ``states [E]`` (start states as from ``TruckEnv.get_state()``) with
    ``planner``'s rollouts.

    Returns:
        ``{"candidates": list per scene of (cost, score, actions [T, 2]) best first (the
        successful ones, up to ``replay_candidates``, or the lowest-cost one),
        "planned_success" [E] bool, "best_ratio" [E] (largest error / tolerance at the
        closest approach of the best candidate), "iterations" [E] int (all attempts),
        "attempts" [E] int, "rollouts" int, "seconds" float}``.
    """
    check_range("difficulty", difficulty, 0.0, MAX_DIFFICULTY)
    pc, dev = planner.config, planner.device
    e, k, slots = states.batch_size[0], pc.samples, pc.scenes_per_batch
    states = states.to(dev)
    g = torch.Generator(device=dev)
    g.manual_seed(pc.seed)
    run, t0 = _Search(planner, e), time.perf_counter()
    while run.queue or run.jobs:
        run.fill()
        owner = [run.jobs[j % len(run.jobs)] for j in range(slots)]
        x = run.sample(owner, g)
        rows = torch.tensor([job.scene for job in owner], device=dev).repeat_interleave(k)
        arc_on = torch.tensor([job.arc for job in owner], device=dev).repeat_interleave(k)
        acc, actions = planner.rollout(states[rows], x, difficulty, arc_on)
        run.rollouts += slots * k
        host = {key: acc[key].cpu() for key in ("best", "worst", "length")}
        host["cost"] = (acc["best"] - SUCCESS_BONUS * acc["success"].float()).cpu()
        slot_of_row = torch.arange(slots).repeat_interleave(k)
        for job in dict.fromkeys(owner):
            mine = torch.tensor([o is job for o in owner])
            run.learn(job, mine[slot_of_row].nonzero().squeeze(-1), x, host, actions)
        run.retire()
        if progress is not None:
            progress(int(run.done.sum()), e)
    return {
        "candidates": run.cands,
        "planned_success": run.best_cost < 0,
        "best_ratio": run.best_ratio,
        "iterations": run.iters,
        "attempts": run.started,
        "rollouts": run.rollouts,
        "seconds": time.perf_counter() - t0,
    }
