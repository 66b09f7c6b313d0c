"""Success-driven difficulty curriculum (the paper's section "Curriculum learning").

The runner keeps an exponential moving average (EMA) of episode success over all environments.
Every finished episode updates it once, in time order: ``ema <- a * ema + (1 - a) * success``
(paper: ``a = 0.995``). As soon as the EMA exceeds the threshold (paper: 0.70) the difficulty rises
by a fixed step (paper: 0.5). The environment turns difficulty into tolerances,
``30 m * 2**-difficulty`` and ``60 deg * 2**-difficulty`` (``env.tolerance.*``).

After a promotion the EMA restarts from ``ema_init`` (default 0) and the remaining outcomes of the
same batch are dropped: each promotion must then be earned with evidence gathered entirely at the
new tolerances. With ``a = 0.995`` that takes at least 241 successful episodes in a row
(``1 - 0.995**241 > 0.7``), so one lucky batch can never climb two levels. Episodes whose success
was judged at another difficulty (the env reports ``"difficulty"`` per step; an episode that was
running during a promotion finishes under the new tolerances only if it ends after it) are also
ignored.

Mode ``fixed`` (preset ``curriculum=none``) never changes the difficulty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate


@dataclass(frozen=True)
class CurriculumConfig:
    """Curriculum settings (``curriculum.*``; presets ``curriculum=paper|none``)."""

    mode: str = param(
        "ema", choices=("ema", "fixed"), unit="-", doc="ema (the paper's promotion rule) or fixed"
    )
    start_difficulty: float = param(
        0.0,
        lo=0.0,
        hi=30.0,
        unit="-",
        doc="difficulty at the start of training (resumed runs use the checkpoint's)",
    )
    ema_decay: float = param(
        0.995,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        hi_open=True,
        unit="-",
        doc="EMA factor per finished episode",
        source="paper",
    )
    threshold: float = param(
        0.70,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        hi_open=True,
        unit="-",
        doc="promote when the EMA of success exceeds this",
        source="paper",
    )
    step: float = param(
        0.5,
        lo=0.0,
        lo_open=True,
        hi=30.0,
        unit="-",
        doc="difficulty increment per promotion",
        source="paper",
    )
    ema_init: float = param(
        0.0,
        lo=0.0,
        hi=1.0,
        unit="-",
        doc="EMA value at the start and after each promotion; <= threshold",
    )
    max_difficulty: float | None = param(
        None,
        lo=0.0,
        hi=30.0,
        unit="-",
        doc="no promotion beyond this (null: unbounded); >= start_difficulty",
    )

    def __post_init__(self) -> None:
        validate(self, "curriculum")
        if self.ema_init > self.threshold:
            raise ConfigError(
                f"curriculum.ema_init = {self.ema_init} must not exceed "
                f"curriculum.threshold = {self.threshold} (it would promote at every episode)"
            )
        if self.max_difficulty is not None and self.max_difficulty < self.start_difficulty:
            raise ConfigError(
                f"curriculum.max_difficulty = {self.max_difficulty} must be at least "
                f"curriculum.start_difficulty = {self.start_difficulty}"
            )


def ema_trajectory(ema0: float, decay: float, x: Tensor) -> Tensor:
    """EMA after each element of a stream: ``y_j = decay * y_{j-1} + (1 - decay) * x_j``.

    Vectorised with a closed form per chunk, ``y_j = a^(j+1) (y0 + (1-a) sum_{i<=j} a^-(i+1) x_i)``,
    in float64; chunks keep ``a^-C`` below ``e^50``.

    Args:
        ema0: EMA before the stream.
        decay: factor ``a`` in (0, 1).
        x: ``[K]`` stream values (e.g. success in {0, 1}).

    Returns:
        ``[K]`` float64 EMA after each element.
    """
    x = x.detach().reshape(-1).to(torch.float64)
    chunk = int(max(1, min(4096, 50.0 / -math.log(decay))))
    out = []
    y0 = torch.tensor(float(ema0), dtype=torch.float64, device=x.device)
    for part in x.split(chunk):
        k = torch.arange(1, part.numel() + 1, dtype=torch.float64, device=x.device)
        pow_ = decay**k
        y = pow_ * (y0 + (1.0 - decay) * torch.cumsum(part / pow_, 0))
        out.append(y)
        y0 = y[-1]
    return torch.cat(out) if out else x.new_zeros(0)


class Curriculum:
    """Difficulty state and promotion rule; see the module docstring.

    Attributes:
        difficulty: current difficulty (float, multiples of ``step`` above the start).
        ema: EMA of success at the current difficulty.
        promotions: promotions so far.
        episodes: finished episodes counted so far.
    """

    def __init__(self, cfg: CurriculumConfig) -> None:
        self.cfg = cfg
        self.difficulty = float(cfg.start_difficulty)
        self.ema = float(cfg.ema_init)
        self.promotions = 0
        self.episodes = 0

    def update(self, success: Tensor, difficulty: Tensor | None = None) -> bool:
        """Feed finished episodes in time order; return True when the difficulty rose.

        Args:
            success: ``[K]`` bool or {0, 1} outcome of each finished episode, oldest first.
            difficulty: ``[K]`` difficulty under which each success was judged; episodes at
                another difficulty than the current one are ignored.
        """
        success = success.reshape(-1)
        if difficulty is not None:
            same = torch.isclose(
                difficulty.reshape(-1).to(torch.float64),
                torch.tensor(self.difficulty, dtype=torch.float64, device=difficulty.device),
            )
            success = success[same]
        if success.numel() == 0:
            return False
        if self.cfg.mode == "fixed":
            self.episodes += success.numel()
            return False
        traj = ema_trajectory(self.ema, self.cfg.ema_decay, success)
        above = torch.nonzero(traj > self.cfg.threshold)
        at_cap = self.cfg.max_difficulty is not None and (
            self.difficulty + self.cfg.step > self.cfg.max_difficulty + 1e-9
        )
        if above.numel() == 0 or at_cap:
            self.ema = float(traj[-1])
            self.episodes += success.numel()
            return False
        self.episodes += int(above[0, 0]) + 1
        self.difficulty += self.cfg.step
        self.ema = float(self.cfg.ema_init)
        self.promotions += 1
        return True

    def state_dict(self) -> dict[str, float | int]:
        return {
            "difficulty": self.difficulty,
            "ema": self.ema,
            "promotions": self.promotions,
            "episodes": self.episodes,
        }

    def load_state_dict(self, state: dict[str, float | int]) -> None:
        self.difficulty = float(state["difficulty"])
        self.ema = float(state["ema"])
        self.promotions = int(state["promotions"])
        self.episodes = int(state["episodes"])
