"""``TruckGymEnv``: one truck of a task as a ``gymnasium.Env`` (what ``gymnasium.make`` returns).

Spaces, info and action rules are :mod:`truckrl.gym.vector`'s for one truck: observation
``Dict(observation: (F,), lidar: (R,))`` float32, action ``Box(-1, 1, (2,))``; ``info`` holds the
outcome flags, the reward terms, the errors to the goal, ``difficulty`` and ``step_count`` of the
step as Python scalars. No autoreset: after ``terminated`` or ``truncated`` call ``reset()``.
``render()`` (``render_mode="rgb_array"``) is the bird's-eye view ``[H, W, 3]`` uint8 RGB.
For many trucks use ``gymnasium.make_vec`` (:class:`~truckrl.gym.vector.TruckVectorEnv`), which
batches them in one simulation instead of one env per truck.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import torch
from tensordict import TensorDictBase

from truckrl.env.make import make_env
from truckrl.env.spec import LIDAR_KEY
from truckrl.gym.vector import (
    OBS_KEYS,
    RENDER_MODES,
    as_action,
    draw_trucks,
    env_kwargs,
    info_keys,
    single_spaces,
)
from truckrl.tasks.config import DEFAULT_TASK


class TruckGymEnv(gymnasium.Env):
    """One truck of ``task``; arguments as :class:`~truckrl.gym.vector.TruckVectorEnv`'s
    (without ``num_envs``, ``render_envs`` and ``tensors``)."""

    metadata = {"render_modes": RENDER_MODES}

    def __init__(
        self,
        task: str = DEFAULT_TASK,
        *,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        difficulty: float | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode = {render_mode!r}: one of {RENDER_MODES} or None")
        self.env = make_env(**env_kwargs(task, 1, device, seed, difficulty), **overrides)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env.config.dt}
        self.observation_space, self.action_space = single_spaces(self.env)
        self._info_keys = info_keys(self.env)
        self._td: TensorDictBase | None = None

    def set_difficulty(self, difficulty: float) -> None:
        """Set the curriculum difficulty (>= 0), used from the next step on; out of range
        raises ``ConfigError``."""
        self.env.set_difficulty(difficulty)

    @property
    def difficulty(self) -> float:
        """The current difficulty."""
        return self.env.get_difficulty()

    def _obs(self, td: TensorDictBase) -> dict[str, np.ndarray]:
        return {k: td.get(k)[0].detach().cpu().numpy() for k in OBS_KEYS}

    def _info(self, td: TensorDictBase) -> dict[str, Any]:
        return {k: td.get(k)[0, 0].item() for k in self._info_keys}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """A fresh episode; ``seed`` reseeds the scene generator, ``options={"difficulty": d}``
        sets the difficulty first."""
        super().reset(seed=seed)
        if seed is not None:
            self.env.set_seed(int(seed))
        if options and "difficulty" in options:
            self.set_difficulty(options["difficulty"])
        self._td = self.env.reset()
        return self._obs(self._td), self._info(self._td)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        a = as_action(action, (2,), self.env.device)[None]
        self._td = self.env.step(self._td.set("action", a)).get("next")
        td = self._td
        return (
            self._obs(td),
            float(td.get("reward")[0, 0]),
            bool(td.get("terminated")[0, 0]),
            bool(td.get("truncated")[0, 0]),
            self._info(td),
        )

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gymnasium.logger.warn("render() without render_mode: pass render_mode='rgb_array'")
            return None
        if self._td is None:
            raise RuntimeError("call reset() before render()")
        return draw_trucks(self.env, self._td.get(LIDAR_KEY), 1)[0]
