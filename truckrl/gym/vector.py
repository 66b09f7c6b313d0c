"""``TruckVectorEnv``: N trucks of one :class:`~truckrl.env.TruckEnv` as a ``gymnasium.vector.VectorEnv``.

One batched TruckEnv steps all N trucks as tensor ops; this class only converts its tensordicts
to Gymnasium's arrays, with no per-env Python loop (the one loop builds ``final_obs`` for the
trucks whose episode ended this step, the object array Gymnasium's convention asks for).

Spaces (``F`` numeric features, 26 for the shipped tasks; ``R`` LiDAR beams;
:mod:`truckrl.env.spec` has the feature table)::

    single_observation_space  Dict(observation: Box(-inf, inf, (F,), float32),
                                   lidar: Box(0, 1, (R,), float32))
    single_action_space       Box(-1, 1, (2,), float32): (longitudinal, lateral) command
    observation_space, action_space: the same batched, leading dimension N

Autoreset (``metadata["autoreset_mode"]``): ``AutoresetMode.SAME_STEP``, TruckEnv's own in-place
restart (:mod:`truckrl.env.autoreset`). A step that ends an episode returns the first
observation of the next one; the transition's last observation is ``info["final_obs"][i]``
and its info ``info["final_info"][key][i]``, masked by ``info["_final_obs"]`` and
``info["_final_info"]``. The other ``info`` entries (the outcome flags ``success``,
``collision``, ``jackknife``, ``action_nonfinite``; the reward terms ``r_*``; the errors to the
goal; ``difficulty``; ``step_count``) are ``[N]`` arrays of the rows as returned: for a truck
that just restarted, its fresh episode (flags False, reward terms 0), as Gymnasium's
``SyncVectorEnv`` in the same mode. Every ``info[key]`` has its ``info["_" + key]`` mask.

Actions: an ``[N, 2]`` array or tensor (any real dtype, converted to float32); another shape is a
``ValueError``. Components outside ``[-1, 1]`` are clamped to it by the control step;
NaN or inf rows are replaced by 0 before they touch the state and flagged in
``info["action_nonfinite"]`` (``nonfinite_action="error"`` raises instead): TruckEnv's rules,
:mod:`truckrl.env.spec`.

``tensors=True`` returns torch tensors on the env's device (observations, rewards, flags, info)
instead of numpy arrays, with no copy to the host; ``final_obs`` is then the batched ``{key:
[N, ...]}`` transition observation (valid where ``_final_obs``), so nothing syncs with the device
beyond TruckEnv's own autoreset.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from tensordict import TensorDictBase

from truckrl.env.make import make_env
from truckrl.env.spec import LIDAR_KEY, OBS_KEY
from truckrl.env.truck_env import TruckEnv
from truckrl.tasks.config import DEFAULT_TASK

#: The observation keys of the Dict space (the rest of TruckEnv's observation spec is info).
OBS_KEYS = (OBS_KEY, LIDAR_KEY)
#: ``render_mode`` values the envs accept (``None``: no rendering).
RENDER_MODES = ["rgb_array"]


def single_spaces(env: TruckEnv) -> tuple[spaces.Dict, spaces.Box]:
    """One truck's ``(observation space, action space)`` of ``env`` (module docstring)."""
    features = env.observation_spec[OBS_KEY].shape[-1]
    beams = env.observation_spec[LIDAR_KEY].shape[-1]
    obs = spaces.Dict(
        {
            OBS_KEY: spaces.Box(-np.inf, np.inf, (features,), np.float32),
            LIDAR_KEY: spaces.Box(0.0, 1.0, (beams,), np.float32),
        }
    )
    return obs, spaces.Box(-1.0, 1.0, (2,), np.float32)


def info_keys(env: TruckEnv) -> tuple[str, ...]:
    """The info entries: TruckEnv's observation leaves other than the Dict space's."""
    return tuple(k for k in env.observation_spec.keys() if k not in OBS_KEYS)


def as_action(action: Any, shape: tuple[int, ...], device: torch.device) -> torch.Tensor:
    """``action`` (array, tensor or nested sequence of reals) as a float32 tensor of ``shape`` on
    ``device``; raises ``ValueError`` naming both shapes when it has another shape."""
    a = torch.as_tensor(action, dtype=torch.float32, device=device)
    if tuple(a.shape) != shape:
        raise ValueError(
            f"action has shape {tuple(a.shape)}; expected {shape} "
            "(rows of (longitudinal, lateral) commands in [-1, 1])"
        )
    return a


def env_kwargs(
    task: str, num_envs: int, device: Any, seed: int | None, difficulty: float | None
) -> dict[str, Any]:
    """Keyword arguments of :func:`~truckrl.env.make.make_env` (besides overrides)."""
    return {
        "task": task,
        "num_envs": num_envs,
        "device": device,
        "seed": seed,
        "difficulty": difficulty,
    }


def draw_trucks(env: TruckEnv, lidar: torch.Tensor, count: int) -> tuple[np.ndarray, ...]:
    """Bird's-eye-view frames ``[H, W, 3]`` uint8 RGB of the first ``count`` trucks of ``env``,
    each centred on its tractor with its goal, tolerance and last LiDAR scan (``lidar`` ``[N,
    R]`` in ``[0, 1]``, the observation's)."""
    from truckrl.viz.config import ViewConfig
    from truckrl.viz.draw import draw_state

    view = ViewConfig()
    state = env.get_state()
    tol_pos, tol_ang = env.tolerances()
    frames = []
    for i in range(min(count, env.num_envs)):
        s = state[i]
        caption = f"step {int(s['step_count'])}  difficulty {env.get_difficulty():g}"
        frames.append(
            draw_state(
                s,
                lidar[i] * env.config.lidar.max_range,
                env.task.rel_angles,
                (float(tol_pos[i]), float(tol_ang[i])),
                hud_lines=[caption],
                size_px=view.size_px,
                view_half_extent=view.half_extent,
            )
        )
    return tuple(frames)


class TruckVectorEnv(VectorEnv):
    """N trucks of a task as one Gymnasium ``VectorEnv``; see the module docstring.

    Args:
        num_envs: trucks N, one batch.
        task: task folder (``truckrl tools configs env`` lists them) or a task package's path.
        device: torch device of the simulation.
        seed: scene generator seed until ``reset(seed=...)`` gives another; ``None`` draws one.
        difficulty: starting curriculum difficulty (``None``: the config's).
        render_mode: ``None`` or ``"rgb_array"`` (``render()`` returns BEV frames).
        render_envs: trucks drawn by ``render()``: the first ``render_envs``.
        tensors: return torch tensors on ``device`` instead of numpy arrays.
        **overrides: :class:`~truckrl.tasks.EnvConfig` fields, dotted (``**{"lidar.num_beams":
            32}``) or as mappings; a bad one raises :class:`~truckrl.config.fields.ConfigError`.
    """

    metadata = {"render_modes": RENDER_MODES, "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        task: str = DEFAULT_TASK,
        *,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        difficulty: float | None = None,
        render_mode: str | None = None,
        render_envs: int = 1,
        tensors: bool = False,
        **overrides: Any,
    ) -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode = {render_mode!r}: one of {RENDER_MODES} or None")
        kwargs = env_kwargs(task, num_envs, device, seed, difficulty)
        self.env = make_env(**kwargs, **overrides)
        self.num_envs = self.env.num_envs
        self.render_mode = render_mode
        self.render_envs = int(render_envs)
        self.tensors = bool(tensors)
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env.config.dt}
        self.single_observation_space, self.single_action_space = single_spaces(self.env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._info_keys = info_keys(self.env)
        self._td: TensorDictBase | None = None
        self._all = self._out(torch.ones(self.num_envs, dtype=torch.bool, device=self.env.device))

    # ------------------------------------------------------------------ curriculum
    def set_difficulty(self, difficulty: float) -> None:
        """Set the curriculum difficulty (>= 0) of every truck, used from the next step on
        (tolerances scale by ``2**-difficulty``); out of range raises ``ConfigError``."""
        self.env.set_difficulty(difficulty)

    @property
    def difficulty(self) -> float:
        """The current difficulty."""
        return self.env.get_difficulty()

    # ------------------------------------------------------------------ conversions
    def _out(self, t: torch.Tensor) -> Any:
        """A tensor as returned: itself (``tensors``) or a numpy array (a view on CPU)."""
        return t if self.tensors else t.detach().cpu().numpy()

    def _obs(self, td: TensorDictBase) -> dict[str, Any]:
        return {k: self._out(td.get(k)) for k in OBS_KEYS}

    def _info(self, td: TensorDictBase) -> dict[str, Any]:
        """``{key: [N]}`` of the info leaves of ``td``, each with its all-True ``_key`` mask."""
        info: dict[str, Any] = {}
        for k in self._info_keys:
            info[k] = self._out(td.get(k).squeeze(-1))
            info[f"_{k}"] = self._all
        return info

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start N fresh episodes. ``seed`` (one int: the batch has one scene generator)
        reseeds the generator; ``options={"difficulty": d}`` sets the difficulty first."""
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed = {seed!r}: one int seeds the whole batch (one generator)")
        super().reset(seed=None if seed is None else int(seed))
        if seed is not None:
            self.env.set_seed(int(seed))
        if options and "difficulty" in options:
            self.set_difficulty(options["difficulty"])
        self._td = self.env.reset()
        return self._obs(self._td), self._info(self._td)

    def step(self, actions: Any) -> tuple[dict[str, Any], Any, Any, Any, dict[str, Any]]:
        """One step of every truck, then fresh episodes for those that ended (SAME_STEP)."""
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        action = as_action(actions, (self.num_envs, 2), self.env.device)
        out, self._td = self.env.step_and_maybe_reset(self._td.set("action", action))
        nxt = out.get("next")
        info = self._info(self._td)
        done = nxt.get("done").squeeze(-1)
        if self.tensors:
            info["final_obs"] = self._obs(nxt)
            info["_final_obs"] = done
            info["final_info"] = self._final_info(nxt, done)
            info["_final_info"] = done
        else:
            done = done.cpu().numpy()
            if done.any():
                last = self._obs(nxt)
                final = np.full(self.num_envs, None, dtype=object)
                for i in np.flatnonzero(done):  # the ended trucks only
                    final[i] = {k: v[i] for k, v in last.items()}
                info["final_obs"], info["_final_obs"] = final, done
                info["final_info"], info["_final_info"] = self._final_info(nxt, done), done
        return (
            self._obs(self._td),
            self._out(nxt.get("reward").squeeze(-1)),
            self._out(nxt.get("terminated").squeeze(-1)),
            self._out(nxt.get("truncated").squeeze(-1)),
            info,
        )

    def _final_info(self, nxt: TensorDictBase, done: Any) -> dict[str, Any]:
        """The transition's info ``{key: [N], "_key": done}`` (valid where ``done``)."""
        info: dict[str, Any] = {}
        for k in self._info_keys:
            info[k] = self._out(nxt.get(k).squeeze(-1))
            info[f"_{k}"] = done
        return info

    def render(self) -> tuple[np.ndarray, ...] | None:
        """BEV frames of the first ``render_envs`` trucks (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() without render_mode: pass render_mode='rgb_array'")
            return None
        if self._td is None:
            raise RuntimeError("call reset() before render()")
        return draw_trucks(self.env, self._td.get(LIDAR_KEY), self.render_envs)

    def close_extras(self, **kwargs: Any) -> None:
        self._td = None

    def __repr__(self) -> str:
        return f"TruckVectorEnv({self.env.config.task.name}, num_envs={self.num_envs})"
