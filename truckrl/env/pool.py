"""EpisodePool: fresh episodes drawn ahead of the resets that use them, handed out in draw order.

Generating scenes in one batch is far cheaper per episode than one at a time, and a training
batch restarts a few trucks on most steps, so episodes are drawn ``size`` at a time and handed
out in order. The pool also holds them prepared for the current difficulty (a task's start
curriculum applied, their first observation computed) for the whole pool in one batch, because
preparing a few rows at every restart costs the same fixed overhead as preparing hundreds. The
pool keeps plain tensors, one per state leaf, because taking rows is then one slice per leaf
instead of an index into a nested TensorDict.

A refill may hand back fewer episodes than it was asked for (a task whose generator keeps the
scenes that pass its rule and redraws the others in a later refill), and it may depend on a
*draw key* (what a task's draw needs to know of the difficulty): a take under another draw key
drops the held episodes and draws afresh.
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
#: ``draw(k, draw_key)`` -> at most ``k`` fresh episodes (at least one) as state leaves.
Draw = Callable[[int, Hashable], Leaves]


def _cat(parts: list[dict]) -> dict:
    if len(parts) == 1:
        return parts[0]
    return {key: torch.cat([p[key] for p in parts]) for key in parts[-1]}


def _rows(leaves: dict, lo: int, hi: int | None = None) -> dict:
    return {k: v[lo:hi] for k, v in leaves.items()}


class EpisodePool:
    """Episodes not yet handed out, oldest first.

    Invariant: every drawn episode is handed out exactly once, in the order drawn, until a take
    under another draw key (or :meth:`clear`, on a new seed) drops the rest; so the sequence of
    episodes is fixed by the generator behind ``draw`` and the draw keys of the takes, whatever
    their sizes up to ``size`` (a refill asks for ``size``, or for the whole take where that is
    more). Where ``prepare`` is given, the pool also holds ``prepare(episodes, key)`` for the
    ``key`` of the last :meth:`take`, row for row: a row's preparation must not depend on the
    other rows of its batch (nor draw random numbers), so it is the one a restart of that truck
    alone would compute. A take with another ``key`` prepares every held episode again.

    Args:
        draw: :data:`Draw`.
        size: episodes a refill asks for (more for a take of more).
        prepare: :data:`Prepare`, or ``None`` to hand out the drawn episodes as they are.
        draw_key: ``draw_key(key)`` -> what the draws depend on under the take key ``key``
            (``None``: nothing, the default).
    """

    def __init__(
        self,
        draw: Draw,
        size: int,
        prepare: Prepare | None = None,
        draw_key: Callable[[Hashable], Hashable] | None = None,
    ):
        self._draw = draw
        self._size = size
        self._prepare = prepare
        self._draw_key = draw_key
        #: the held episodes are rows ``_pos:`` of ``_episodes`` (a take moves the cursor
        #: instead of slicing every leaf twice), drawn under ``_held_key``
        self._episodes: Leaves | None = None
        self._held_key: Hashable = None
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

        Where fewer than ``m`` are held, the held ones go first and refills (each asked for
        ``max(m, size)``) the rest; only those ``m`` rows are joined, not a refill's whole batch
        (a network episode holds tens of kilobytes of scene)."""
        draw_key = None if self._draw_key is None else self._draw_key(key)
        ask = max(m, self._size)
        if draw_key != self._held_key:
            self.clear()
            self._held_key = draw_key
        parts: list[tuple[Leaves, Observation | None]] = []
        while m > len(self) or self._episodes is None:
            rest = len(self)
            if rest:
                parts.append(self._held(rest, key))
                m -= rest
            fresh = self._draw(ask, draw_key)
            if not next(iter(fresh.values())).shape[0]:
                raise RuntimeError("an episode pool's draw returned no episode")
            self._episodes, self._ready, self._pos = fresh, None, 0
        parts.append(self._held(m, key))
        obs = None if parts[-1][1] is None else _cat([p[1] for p in parts])
        return _cat([p[0] for p in parts]), obs

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
