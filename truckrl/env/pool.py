"""EpisodePool: fresh episodes drawn ahead of the resets that use them, handed out in draw order.

Generating scenes in one batch is far cheaper per episode than one at a time, and a training
batch restarts a few trucks on most steps, so episodes are drawn ``size`` at a time and handed
out in order. The pool keeps plain tensors, one per state leaf, because taking rows is then one
slice per leaf instead of an index into a nested TensorDict.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

#: State leaves ``{leaf key: [m, ...]}``; nested keys are tuples (``("params", "L_t")``).
Leaves = dict[str | tuple[str, ...], torch.Tensor]
#: Observation leaves ``{key: [m, ...]}``.
Observation = dict[str, torch.Tensor]


class EpisodePool:
    """Episodes not yet handed out, oldest first.

    Invariant: every drawn episode is handed out exactly once, in the order drawn, so the
    sequence of episodes is fixed by the generator behind ``draw`` and the sizes taken;
    :meth:`clear` (on a new seed) drops the rest. Where ``first_observation`` is given, row
    ``i`` of the held observation is the first observation of row ``i`` of the held episodes: a
    row's observation does not depend on the other rows of its batch, so it is the one a reset
    of that truck alone would compute.

    Args:
        draw: ``draw(k)`` -> ``k`` fresh episodes as state leaves ``[k, ...]``.
        size: episodes drawn per refill (more when one take asks for more).
        first_observation: ``first_observation(leaves)`` -> their first observation
            ``[k, ...]``, computed once per refill for the whole batch; ``None`` when the
            observation depends on more than the drawn episode (e.g. a start curriculum).
    """

    def __init__(
        self,
        draw: Callable[[int], Leaves],
        size: int,
        first_observation: Callable[[Leaves], Observation] | None = None,
    ) -> None:
        self._draw = draw
        self._size = size
        self._first_observation = first_observation
        self._episodes: Leaves | None = None
        self._observation: Observation | None = None

    def clear(self) -> None:
        """Drop every held episode; the next take draws afresh."""
        self._episodes = self._observation = None

    def __len__(self) -> int:
        return 0 if self._episodes is None else next(iter(self._episodes.values())).shape[0]

    def take(self, m: int) -> tuple[Leaves, Observation | None]:
        """The next ``m`` episodes ``({state leaf key: [m, ...]}, first observation or None)``."""
        episodes, observation = self._episodes, self._observation
        if len(self) < m:
            k = max(m, self._size)
            fresh = self._draw(k)
            fresh_obs = None if self._first_observation is None else self._first_observation(fresh)
            if episodes is None:
                episodes, observation = fresh, fresh_obs
            else:
                episodes = {key: torch.cat((episodes[key], fresh[key])) for key in fresh}
                if fresh_obs is not None:
                    observation = {
                        key: torch.cat((observation[key], fresh_obs[key])) for key in fresh_obs
                    }
        self._episodes = {key: v[m:] for key, v in episodes.items()}
        if observation is None:
            return {key: v[:m] for key, v in episodes.items()}, None
        self._observation = {key: v[m:] for key, v in observation.items()}
        taken_obs = {key: v[:m] for key, v in observation.items()}
        return {key: v[:m] for key, v in episodes.items()}, taken_obs
