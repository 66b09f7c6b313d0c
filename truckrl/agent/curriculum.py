"""Success-driven difficulty curriculum (the paper's section "Curriculum learning").

The runner keeps an exponential moving average (EMA) of episode success over all environments.
Every finished episode updates it once, in time order: ``ema <- a * ema + (1 - a) * success``
(paper: ``a = 0.995``). As soon as the EMA exceeds the threshold (paper: 0.70) the difficulty rises
by a fixed step (paper: 0.5). The environment turns difficulty into tolerances,
``30 m * 2**-difficulty`` and ``60 deg * 2**-difficulty`` (``conf/env/default.yaml: tolerance``).

After a promotion the EMA restarts from ``ema_init`` (default 0) and the remaining outcomes of the
same batch are dropped: each promotion must then be earned with evidence gathered entirely at the
new tolerances. With ``a = 0.995`` that takes at least 241 successful episodes in a row
(``1 - 0.995**241 > 0.7``), so one lucky batch can never climb two levels. Episodes whose success
was judged at another difficulty (the env reports ``"difficulty"`` per step; an episode that was
running during a promotion finishes under the new tolerances only if it ends after it) are also
ignored.

Mode ``fixed`` (``conf/curriculum/none.yaml``) never changes the difficulty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from truckrl.sim.validation import ConfigError, check_choice, check_range


@dataclass(frozen=True)
class CurriculumConfig:
    """Curriculum settings (``conf/curriculum/*.yaml``).

    Attributes:
        mode: "ema" (the paper's promotion rule) or "fixed".
        start_difficulty: difficulty at the start of training (resumed runs use the checkpoint's).
        ema_decay: EMA factor per finished episode (paper: 0.995).
        threshold: promote when the EMA exceeds this (paper: 0.70).
        step: difficulty increment per promotion (paper: 0.5).
        ema_init: EMA value at the start and after each promotion.
        max_difficulty: no promotion beyond this (``None``: unbounded).
    """

    mode: str = "ema"
    start_difficulty: float = 0.0
    ema_decay: float = 0.995  # paper
    threshold: float = 0.70  # paper
    step: float = 0.5  # paper
    ema_init: float = 0.0
    max_difficulty: float | None = None

    def __post_init__(self) -> None:
        check_choice("curriculum.mode", self.mode, ("ema", "fixed"))
        check_range("curriculum.start_difficulty", self.start_difficulty, 0.0, 30.0)
        check_range("curriculum.ema_decay", self.ema_decay, 0.0, 1.0, lo_open=True, hi_open=True)
        check_range("curriculum.threshold", self.threshold, 0.0, 1.0, lo_open=True, hi_open=True)
        check_range("curriculum.step", self.step, 0.0, 30.0, lo_open=True)
        check_range("curriculum.ema_init", self.ema_init, 0.0, 1.0)
        if self.ema_init > self.threshold:
            raise ConfigError(
                f"curriculum.ema_init = {self.ema_init} must not exceed "
                f"curriculum.threshold = {self.threshold} (it would promote at every episode)"
            )
        if self.max_difficulty is not None:
            check_range(
                "curriculum.max_difficulty", self.max_difficulty, self.start_difficulty, 30.0
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
