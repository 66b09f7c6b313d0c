"""EpisodePool: fresh episodes drawn ahead of the resets that use them, handed out in draw order.

Generating scenes in one batch is far cheaper per episode than one at a time, and a training
batch restarts a few trucks on most steps, so episodes are drawn ``size`` at a time and handed
out in order. The pool also holds them prepared for the current difficulty (a task's start
curriculum applied, their first observation computed) for the whole pool in one batch, because
preparing a few rows at every restart costs the same fixed overhead as preparing hundreds. The
pool keeps plain tensors, one per state leaf, because taking rows is then one slice per leaf
instead of an index into a nested TensorDict.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

import torch

#: State leaves ``{leaf key: [m, ...]}``; nested keys are tuples (``("params", "L_t")``).
Leaves = dict[str | tuple[str, ...], torch.Tensor]
#: Observation leaves ``{key: [m, ...]}``.
Observation = dict[str, torch.Tensor]
#: ``prepare(leaves, key)`` -> the episodes as they start under ``key`` and their first
#: observation, row ``i`` of both from row ``i`` of ``leaves`` alone.
Prepare = Callable[[Leaves, Hashable], tuple[Leaves, Observation]]


def _cat(a: dict, b: dict) -> dict:
    return {key: torch.cat((a[key], b[key])) for key in b}


def _rows(leaves: dict, lo: int, hi: int | None = None) -> dict:
    return {k: v[lo:hi] for k, v in leaves.items()}


class EpisodePool:
    """Episodes not yet handed out, oldest first.

    Invariant: every drawn episode is handed out exactly once, in the order drawn, so the
    sequence of episodes is fixed by the generator behind ``draw`` and the sizes taken;
    :meth:`clear` (on a new seed) drops the rest. Where ``prepare`` is given, the pool also holds
    ``prepare(episodes, key)`` for the ``key`` of the last :meth:`take`, row for row: a row's
    preparation must not depend on the other rows of its batch (nor draw random numbers), so
    it is the one a restart of that truck alone would compute. A take with another ``key``
    prepares every held episode again.

    Args:
        draw: ``draw(k)`` -> ``k`` fresh episodes as state leaves ``[k, ...]``.
        size: episodes drawn per refill (more when one take asks for more).
        prepare: :data:`Prepare`, or ``None`` to hand out the drawn episodes as they are.
    """

    def __init__(self, draw: Callable[[int], Leaves], size: int, prepare: Prepare | None = None):
        self._draw = draw
        self._size = size
        self._prepare = prepare
        #: the held episodes are rows ``_pos:`` of ``_episodes`` (a take moves the cursor
        #: instead of slicing every leaf twice)
        self._episodes: Leaves | None = None
        self._pos = 0
        #: ``(key, prepared episodes, their first observation)``, row for row with _episodes
        self._ready: tuple[Hashable, Leaves, Observation] | None = None

    def clear(self) -> None:
        """Drop every held episode; the next take draws afresh."""
        self._episodes = self._ready = None
        self._pos = 0

    def __len__(self) -> int:
        if self._episodes is None:
            return 0
        return next(iter(self._episodes.values())).shape[0] - self._pos

    def take(self, m: int, key: Hashable = None) -> tuple[Leaves, Observation | None]:
        """The next ``m`` episodes ``({state leaf key: [m, ...]}, first observation)``, prepared
        for ``key`` (as drawn, and no observation, without ``prepare``).

        Where fewer than ``m`` are held, the held ones go first and a refill the rest; only
        those ``m`` rows are joined, not the refill's whole batch (a network episode holds
        tens of kilobytes of scene)."""
        rest = len(self)
        if rest >= m:
            return self._held(m, key)
        head = self._held(rest, key) if rest else None
        self._episodes, self._ready, self._pos = self._draw(max(m, self._size)), None, 0
        tail = self._held(m - rest, key)
        if head is None:
            return tail
        obs = None if tail[1] is None else _cat(head[1], tail[1])
        return _cat(head[0], tail[0]), obs

    def _held(self, m: int, key: Hashable) -> tuple[Leaves, Observation | None]:
        """The next ``m`` held episodes (``m <= len(self)``), prepared for ``key``."""
        lo, hi = self._pos, self._pos + m
        self._pos = hi
        if self._prepare is None:
            return _rows(self._episodes, lo, hi), None
        if self._ready is None or self._ready[0] != key:
            # fresh storage from row lo on: a compiled observation guards on storage offsets
            held = self._episodes
            if lo > 0:
                held = {k: v[lo:].clone() for k, v in held.items()}
            self._episodes, self._pos, lo, hi = held, m, 0, m
            self._ready = (key, *self._prepare(held, key))
        _, leaves, obs = self._ready
        return _rows(leaves, lo, hi), _rows(obs, lo, hi)
