"""``TruckSB3VecEnv``: the batched trucks as a Stable-Baselines3 ``VecEnv`` (``pip install truckrl[sb3]``).

A thin adapter over :class:`~truckrl.gym.vector.TruckVectorEnv` (numpy arrays): one simulation
steps all N trucks, so ``PPO("MultiInputPolicy", TruckSB3VecEnv(num_envs=256))`` trains on them
without one env object or process per truck::

    from stable_baselines3 import PPO
    from truckrl.gym.sb3 import TruckSB3VecEnv

    env = TruckSB3VecEnv(num_envs=256, seed=0)
    PPO("MultiInputPolicy", env).learn(100_000)

SB3's step contract: observations ``{"observation": [N, F], "lidar": [N, R]}``, rewards
``[N]`` float32, dones ``[N]`` bool (terminated or truncated; the truck has already restarted),
and ``infos``, a list of N dicts. SB3 reads them at the ended trucks only, so only those are
filled: ``terminal_observation`` (the transition's last observation, for bootstrapping),
``TimeLimit.truncated`` (truncated and not terminated), ``is_success`` (SB3's success counter),
and the transition's info entries (outcome flags, reward terms, errors, ``difficulty``,
``step_count``); the other trucks' dicts are empty. :attr:`TruckSB3VecEnv.last_info` holds the
whole step's Gymnasium info (``[N]`` arrays).

One simulation is one state: ``get_attr``, ``set_attr`` and ``env_method`` act on it once and
repeat the result per truck, and take no ``indices`` but all of them
(``env_method("set_difficulty", d)`` sets every truck's difficulty). ``seed(s)`` seeds the
batch's one scene generator with ``s`` at the next ``reset()``. ``render()`` and
``get_images()`` draw the first ``render_envs`` trucks.

The PPO recipe that learns on it (``examples/sb3_ppo.py``, ``truckrl bench trainers``):
:data:`PPO_KWARGS` (experiment=quick's numbers in SB3's names; its env overrides:
``truckrl.bench.trainers.quick_env_overrides``) and :class:`CurriculumCallback` (the paper's curriculum from SB3's
step infos), with the steering-angle control (``docs/gymnasium.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from truckrl.gym.vector import TruckVectorEnv


class TruckSB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` over a :class:`TruckVectorEnv`; see the module docstring.

    Args:
        venv: the batched env to adapt (numpy arrays, not ``tensors=True``); ``None`` builds one
            from ``**kwargs`` (:class:`TruckVectorEnv`'s arguments: ``num_envs``, ``task``,
            ``seed``, ``difficulty``, config overrides, ...).
    """

    def __init__(self, venv: TruckVectorEnv | None = None, **kwargs: Any) -> None:
        if venv is None:
            venv = TruckVectorEnv(**kwargs)
        elif kwargs:
            raise TypeError(f"give venv or its arguments, not both: {sorted(kwargs)}")
        if venv.tensors:
            raise ValueError("TruckSB3VecEnv needs numpy arrays: a TruckVectorEnv(tensors=False)")
        self.venv = venv
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self.last_info: dict[str, Any] = {}
        self._actions: np.ndarray | None = None

    # ------------------------------------------------------------------ stepping
    def reset(self) -> dict[str, np.ndarray]:
        seed = self._seeds[0]
        obs, self.last_info = self.venv.reset(seed=seed, options=self._options[0] or None)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, list[dict]]:
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        self.last_info = info
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if "final_obs" in info:
            final, last = info["final_obs"], info["final_info"]
            keys = [k for k in last if not k.startswith("_")]
            for i in np.flatnonzero(dones):  # the ended trucks only
                row = {k: last[k][i].item() for k in keys}
                row["terminal_observation"] = final[i]
                row["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                row["is_success"] = row["success"]
                infos[i] = row
        return obs, reward.astype(np.float32, copy=False), dones, infos

    def close(self) -> None:
        self.venv.close()

    # ------------------------------------------------------------------ one state, N trucks
    def _all(self, indices: VecEnvIndices) -> int:
        """The number of trucks ``indices`` names; raises unless it names all of them."""
        idx = list(self._get_indices(indices))
        if sorted(idx) != list(range(self.num_envs)):
            raise ValueError(
                "the trucks share one simulation: get_attr / set_attr / env_method act on all "
                "of them (indices=None)"
            )
        return len(idx)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * self._all(indices)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._all(indices)
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs
    ) -> list[Any]:
        n = self._all(indices)
        return [getattr(self.venv, method_name)(*method_args, **method_kwargs)] * n

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(list(self._get_indices(indices)))

    def get_images(self) -> Sequence[np.ndarray | None]:
        return list(self.venv.render() or ())


# ------------------------------------------------------------------ the PPO recipe
#: PPO settings of experiment=quick in SB3's names (ppo/fast.yaml, quick.yaml, PPOConfig and
#: ModelConfig defaults for the rest).
PPO_KWARGS: dict[str, Any] = {
    "n_steps": 32,
    "batch_size": 1024,
    "n_epochs": 5,
    "learning_rate": 3e-4,
    "gamma": 0.998,
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.005,
    "vf_coef": 0.5,
    "policy_kwargs": {"net_arch": [128, 64], "log_std_init": math.log(0.5)},
}


class CurriculumCallback(BaseCallback):
    """Feeds each step's finished episodes (success and the difficulty they were judged at,
    from SB3's ``infos``) to a curriculum (:class:`truckrl.rl.curriculum.Curriculum` or any
    object with its ``difficulty`` attribute and ``update(success [K], difficulty [K]) -> bool``
    method); on a promotion it
    sets the env's difficulty (``env_method("set_difficulty", d)``). Stops training once the
    difficulty reaches ``stop_difficulty`` (``None``: never).

    Attributes:
        promotions: ``[(difficulty, frames)]``, one per promotion.
    """

    def __init__(self, curriculum: Any, stop_difficulty: float | None = None) -> None:
        super().__init__()
        self.curriculum = curriculum
        self.stop_difficulty = stop_difficulty
        self.promotions: list[tuple[float, int]] = []

    def _on_training_start(self) -> None:
        self.training_env.env_method("set_difficulty", self.curriculum.difficulty)

    def _on_step(self) -> bool:
        ended = np.flatnonzero(self.locals["dones"])
        if ended.size:
            infos = self.locals["infos"]
            success = torch.tensor([infos[i]["success"] for i in ended])
            judged_at = torch.tensor([infos[i]["difficulty"] for i in ended])
            if self.curriculum.update(success, judged_at):
                d = self.curriculum.difficulty
                self.training_env.env_method("set_difficulty", d)
                self.promotions.append((d, self.num_timesteps))
                self.logger.record("curriculum/difficulty", d)
                print(f"difficulty {d:g} at {self.num_timesteps:,} frames", flush=True)
        stop = self.stop_difficulty
        return stop is None or self.curriculum.difficulty < stop
