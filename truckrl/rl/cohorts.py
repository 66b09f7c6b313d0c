"""Curriculum evidence in start order: every episode counted once, none favoured by its length.

A run (new or resumed) starts every environment at the same step, so the first episodes to end
are the short ones: successes and early crashes end within tens of steps, timeouts only after
``env.max_steps``. Fed in the order they finish, the curriculum's EMA right after a (re)start
sees mostly short episodes, whose success rate can be several times the steady state's, and
promotes on that alone.

:class:`StartOrderFeed` hands the curriculum the finished episodes ordered by the step they
*started* at, and only once every episode that started earlier has finished: the frontier is the
start of the oldest episode still running. Which episodes are handed over, and in which order,
then depends on start times alone, never on an episode's own length or outcome, so the success
rate the EMA sees is unbiased from the first episode on, after a start, a resume or a promotion
alike. The cost is a delay of at most ``env.max_steps`` steps (the longest episode; about three
iterations of the fast preset). Every episode is still counted exactly once.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor


class StartOrderFeed:
    """Turn collected batches ``[*E, T]`` (time last) into start-ordered curriculum evidence.

    Args:
        keys: the ``("next", key)`` entries returned for each released episode, read at its last
            step (default: success and the difficulty it was judged at).
    """

    def __init__(self, keys: tuple[str, ...] = ("success", "difficulty")) -> None:
        self.keys = keys
        self.step = 0  # steps since the (re)start
        self.start: Tensor | None = None  # [E] start step of each env's running episode
        self.pending: list[Tensor] = []  # [K, 2 + len(keys)]: start, env, values

    def update(self, batch: TensorDictBase) -> tuple[Tensor, ...]:
        """Add the episodes that ended in ``batch``; return ``[K]`` tensors (one per key) of the
        episodes released now, oldest start first (ties: env index)."""
        nxt = batch["next"]
        done = nxt["done"].squeeze(-1)
        t = done.shape[-1]
        done = done.reshape(-1, t)
        e = done.shape[0]
        if self.start is None or self.start.shape[0] != e:
            self.start = torch.zeros(e, dtype=torch.long, device=done.device)
        steps = torch.arange(t, device=done.device).expand(e, t)
        last_done = torch.where(done, steps, torch.full_like(steps, -1)).cummax(-1).values
        prev = torch.cat((torch.full_like(last_done[:, :1], -1), last_done[:, :-1]), dim=-1)
        starts = torch.where(prev >= 0, self.step + prev + 1, self.start[:, None])
        env_idx, t_idx = done.nonzero(as_tuple=True)
        values = [nxt[k].reshape(e, t)[env_idx, t_idx].to(torch.float64) for k in self.keys]
        rows = torch.stack([starts[env_idx, t_idx].to(torch.float64), env_idx.double(), *values])
        self.pending.append(rows.T)
        end = last_done[:, -1]
        self.start = torch.where(end >= 0, self.step + end + 1, self.start)
        self.step += t

        pending = torch.cat(self.pending)
        ready = pending[:, 0] < self.start.min()
        out, rest = pending[ready], pending[~ready]
        self.pending = [rest]
        order = torch.argsort(out[:, 0] * e + out[:, 1], stable=True)
        out = out[order]
        return tuple(out[:, 2 + i] for i in range(len(self.keys)))

    @property
    def waiting(self) -> int:
        """Finished episodes held back until the older running ones finish."""
        return int(sum(p.shape[0] for p in self.pending))
