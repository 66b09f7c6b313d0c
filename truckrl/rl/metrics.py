"""Episode statistics from collected batches, kept on device until logging.

The collector hands over ``[..., T]`` batches (time last) of a set of environments that keep
running across batches, so an episode may span two batches. :class:`EpisodeTracker` carries the
running per-env sums of the reward terms over batch boundaries and reports, for the episodes that
ended in a batch: the outcome rates, the episode length, the final errors and each reward term
**summed over the episode** (averaged over the episodes that ended). :func:`iteration_scalars`
names everything one training iteration logs to TensorBoard.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torch import Tensor

from truckrl.tasks import OUTCOMES, Quantity, shown


def episode_sums(x: Tensor, done: Tensor, carry: Tensor) -> tuple[Tensor, Tensor]:
    """Per-episode sums of a per-step signal along the last (time) dim, with carry-over.

    Args:
        x: ``[*E, T, K]`` per-step values (K signals).
        done: ``[*E, T]`` bool, True at the last step of an episode.
        carry: ``[*E, K]`` sums of the episodes still running when the previous batch ended.

    Returns:
        ``(sums [*E, T, K], carry [*E, K])``: ``sums[..., t, :]`` is the full episode sum where
        ``done[..., t]`` (meaningless elsewhere); the new carry holds the unfinished episodes.
    """
    t = x.shape[-2]
    cs = x.cumsum(-2)
    steps = torch.arange(t, device=x.device).expand_as(done)
    last_done = torch.where(done, steps, torch.full_like(steps, -1)).cummax(-1).values
    prev = torch.cat((torch.full_like(last_done[..., :1], -1), last_done[..., :-1]), dim=-1)
    gathered = cs.gather(-2, prev.clamp(min=0)[..., None].expand_as(cs))
    base = torch.where((prev >= 0)[..., None], gathered, -carry[..., None, :])
    sums = cs - base
    # the running episode after the last done: what the step after the batch would see as base
    end = last_done[..., -1]
    end_cs = cs.gather(-2, end.clamp(min=0)[..., None, None].expand(*end.shape, 1, cs.shape[-1]))
    tail_base = torch.where((end >= 0)[..., None], end_cs[..., 0, :], -carry)
    return sums, cs[..., -1, :] - tail_base


class EpisodeTracker:
    """Turn each batch into episode statistics; carries reward-term sums across batches.

    Args:
        reward_keys: the task's reward-term keys (``Task.reward_keys``).
        errors: the task's error quantities (``Task.error_quantities``).
    """

    def __init__(self, reward_keys: tuple[str, ...], errors: tuple[Quantity, ...]) -> None:
        self.return_keys = ("reward", *reward_keys)
        self.errors = errors
        self.carry: Tensor | None = None

    def reset(self) -> None:
        self.carry = None

    def update(self, batch: TensorDictBase) -> dict[str, Tensor]:
        """Statistics of the episodes that ended in ``batch`` (``[*E, T]``), as 0-dim tensors.

        Keys: "episodes", "<outcome>_rate" for each outcome of the schema, "length" [steps],
        "final_<error>" in its shown unit (m or deg), "return/<term>" (summed per episode), and
        "step/<term>" (mean per step over the batch). Rates and means are NaN without episodes.
        """
        nxt = batch["next"]
        done = nxt["done"].squeeze(-1)
        x = torch.cat([nxt[k] for k in self.return_keys], dim=-1).to(torch.float32)
        if self.carry is None or self.carry.shape != x.shape[:-2] + x.shape[-1:]:
            self.carry = torch.zeros(*x.shape[:-2], x.shape[-1], device=x.device)
        sums, self.carry = episode_sums(x, done, self.carry)

        n = done.sum()
        denom = n.clamp(min=1).to(torch.float32)
        nan = torch.tensor(math.nan, device=done.device)

        def mean_at_done(v: Tensor) -> Tensor:
            return torch.where(n > 0, (v.squeeze(-1).to(torch.float32) * done).sum() / denom, nan)

        out = {"episodes": n.to(torch.float32)}
        for o in OUTCOMES:
            out[f"{o.name}_rate"] = mean_at_done(nxt[o.flag])
        out["length"] = mean_at_done(nxt["step_count"])
        for q in self.errors:
            out[f"final_{q.key}"] = shown(q, mean_at_done(nxt[q.key]))
        ep = (sums * done[..., None]).sum(dim=tuple(range(done.dim()))) / denom
        step_mean = x.mean(dim=tuple(range(done.dim())))
        for i, k in enumerate(self.return_keys):
            out[f"return/{k}"] = torch.where(n > 0, ep[i], nan)
            out[f"step/{k}"] = step_mean[i]
        return out


def finished_in_time_order(batch: TensorDictBase, key: str) -> Tensor:
    """Values of ``("next", key)`` at the episodes' last steps, oldest first: ``[K]``."""
    nxt = batch["next"]
    done = nxt["done"].squeeze(-1)
    value = nxt[key].squeeze(-1)
    # time-major flattening: all envs' step 0, then step 1, ...
    done_t = done.movedim(-1, 0).reshape(-1)
    value_t = value.movedim(-1, 0).reshape(-1)
    return value_t[done_t]


def iteration_scalars(
    stats: dict[str, Tensor],
    learn: dict[str, float],
    curriculum: dict[str, float],
    timing: dict[str, float],
    errors: tuple[Quantity, ...],
) -> dict[str, float]:
    """Every TensorBoard scalar of one training iteration, by its logged name.

    Args:
        stats: :meth:`EpisodeTracker.update` output.
        learn: the PPO update's metrics (losses, KL, lr, ...).
        curriculum: difficulty, EMA, promotions and the current tolerances (position [m],
            heading [deg]).
        timing: ``perf/*`` figures.
        errors: the task's error quantities (for the units in the names).

    Returns:
        ``{name: value}``; NaN values (no episode ended this iteration) are dropped.
    """
    keys = list(stats)
    values = torch.stack([stats[k] for k in keys]).tolist()  # one device sync
    v = dict(zip(keys, values, strict=True))
    out = {"episode/count": v["episodes"], "episode/length": v["length"]}
    out.update({f"episode/{o.name}_rate": v[f"{o.name}_rate"] for o in OUTCOMES})
    for q in errors:
        out[f"episode/final_{q.key}_{q.shown_unit}"] = v[f"final_{q.key}"]
    for k in keys:
        if k.startswith("return/"):
            out[f"reward_episode/{k.removeprefix('return/')}"] = v[k]
        elif k.startswith("step/"):
            out[f"reward_step/{k.removeprefix('step/')}"] = v[k]
    out["episode/success_ema"] = curriculum["ema"]
    for k in ("loss_objective", "loss_critic", "loss_entropy"):
        out[f"loss/{k.removeprefix('loss_')}"] = learn[k]
    for k in ("entropy", "kl", "kl_approx", "clip_fraction", "grad_norm", "lr", "action_std"):
        out[f"train/{k}"] = learn[k]
    if "loss_bc" in learn:  # the cloning term is on (demos.bc_coeff)
        out["loss/bc"] = learn["loss_bc"]
        out["train/bc_coeff"] = learn["bc_coeff"]
    for axis in ("longitudinal", "lateral"):  # absent for a one-axis action
        if f"action_std_{axis}" in learn:
            out[f"train/action_std_{axis}"] = learn[f"action_std_{axis}"]
    out["curriculum/difficulty"] = curriculum["difficulty"]
    out["curriculum/promotions"] = curriculum["promotions"]
    out["curriculum/tolerance_position_m"] = curriculum["tolerance_position_m"]
    out["curriculum/tolerance_heading_deg"] = curriculum["tolerance_heading_deg"]
    out.update(hparam_metrics(curriculum["difficulty"], curriculum["ema"]))
    out.update(timing)
    return {k: x for k, x in out.items() if math.isfinite(x)}


def hparam_metrics(difficulty: float, ema: float) -> dict[str, float]:
    """The metrics shown beside the hyper-parameters in TensorBoard's HPARAMS table."""
    return {"hparam/difficulty": difficulty, "hparam/success_ema": ema}
