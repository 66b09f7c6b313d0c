"""TruckEnv: N articulated trucks as one batched TorchRL environment.

One :class:`TruckEnv` holds ``num_envs`` independent episodes as tensors (``batch_size=[N]``);
every physics, collision and LiDAR step is one set of tensor ops over all N, on CPU or CUDA.
Stack several with ``ParallelEnv(W, lambda: TruckEnv(num_envs=n))`` for a ``[W, n]`` batch.

Spec tree (``*B`` = batch dims, ``R`` = LiDAR beams)::

    observation  float32 [*B, 26]  numeric features (table below)
    lidar        float32 [*B, R]   first-hit range / max_range, in [0, 1]
    action       float32 [*B, 2]   [-1, 1]: (longitudinal, lateral) command, scaled to the
                                   control mode's per-truck limit (see truckrl.sim.control)
    reward       float32 [*B, 1]
    done / terminated / truncated  bool [*B, 1]
    info (also in the observation spec, logged by training):
      success, collision, jackknife, action_nonfinite   bool [*B, 1]
      r_progress, r_tractor_heading, r_trailer_heading,
      r_time, r_success, r_collision, r_timeout         float32 [*B, 1]  reward terms (sum = reward)
      pos_error [m], tractor_heading_error [rad],
      trailer_heading_error [rad]                       float32 [*B, 1]  current errors to the goal
      step_count int64 [*B, 1];  difficulty float32 [*B, 1]

Numeric observation (index -> meaning -> normalisation). ``theta`` tractor heading, ``phi``
articulation, ``psi_g`` goal heading; geometry and limits map their configured ``[min, max]``
range onto ``[-1, 1]``:

=====  ==============================================  ==============================
index  meaning                                         normalisation
=====  ==============================================  ==============================
0, 1   goal position in the tractor frame (x fwd, y left)  / 50 m (paper)
2, 3   sin, cos of (psi_g - theta)                     -
4, 5   sin, cos of (psi_g - theta - phi)  (trailer)    -
6, 7   sin, cos of phi                                 -
8      speed                                           / max_speed
9      acceleration                                    / max_accel
10     jerk                                            / max_jerk
11     steering angle                                  / max_steer
12     steering rate                                   / max_steer_rate
13     steering acceleration                           / max_steer_accel
14     wheelbase L_t                                   range -> [-1, 1]
15     kingpin offset a_tk                             range -> [-1, 1]
16     trailer wheelbase L_ka                          range -> [-1, 1]
17     tractor front overhang                          range -> [-1, 1]
18     tractor rear overhang                           range -> [-1, 1]
19     tractor width                                   range -> [-1, 1]
20     trailer rear overhang                           range -> [-1, 1]
21     trailer width                                   range -> [-1, 1]
22     max steering angle                              range -> [-1, 1]
23     max speed                                       range -> [-1, 1]
24     limit of the longitudinal command (mode's)      range -> [-1, 1]
25     limit of the lateral command (mode's)           range -> [-1, 1]
=====  ==============================================  ==============================

Reward (paper, "Rewards"): +0.05 per metre of progress toward the goal, +0.5 per radian of
tractor and of trailer heading-error reduction, time reward 0 per step, +5 on success, -7 on
collision (curb/obstacle) or jack-knife, -8 on timeout (200 steps). Success: position error and
both heading errors within the current tolerances (``30 m * 2**-d`` and ``60 deg * 2**-d`` at
difficulty ``d``, set by :meth:`TruckEnv.set_difficulty`).

Termination: success, collision or jack-knife -> ``terminated``; step limit -> ``truncated``.
Non-finite actions are replaced by 0 before they touch the state (no host sync needed to detect
them) and flagged in ``action_nonfinite``; ``nonfinite_action="error"`` raises instead (that check
syncs with the device every step, so it is a debugging option).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from truckrl.sim.collision import truck_collides
from truckrl.sim.control import CONTROL_KEYS, Control, ControlConfig
from truckrl.sim.geometry import rotate, to_local, wrap_angle
from truckrl.sim.lidar import LidarConfig, beam_angles, lidar_scan
from truckrl.sim.scene import SceneConfig, generate_scenes
from truckrl.sim.validation import ConfigError, check_choice, check_range, from_mapping
from truckrl.sim.vehicle import (
    PARAM_KEYS,
    VehicleConfig,
    jackknifed,
    kinematics_step,
    normalized_params,
    sample_vehicle_params,
    truck_corners,
)

NUM_FEATURES = 26  # paper: "the numeric block consists of 26 scalars"
GOAL_SCALE = 50.0  # [m] paper: goal location scaled by 50 m

#: Geometry/limit parameters observed at indices 14..23 (the two mode-dependent limits follow).
OBSERVED_PARAMS = (
    "wheelbase",
    "kingpin_offset",
    "trailer_wheelbase",
    "front_overhang",
    "rear_overhang",
    "tractor_width",
    "trailer_rear_overhang",
    "trailer_width",
    "max_steer",
    "max_speed",
)
_LONG_LIMIT = {"speed": "max_speed", "accel": "max_accel", "jerk": "max_jerk"}
_LAT_LIMIT = {"angle": "max_steer", "rate": "max_steer_rate", "accel": "max_steer_accel"}

REWARD_TERMS = (
    "r_progress",
    "r_tractor_heading",
    "r_trailer_heading",
    "r_time",
    "r_success",
    "r_collision",
    "r_timeout",
)
FLAG_KEYS = ("success", "collision", "jackknife", "action_nonfinite")
ERROR_KEYS = ("pos_error", "tractor_heading_error", "trailer_heading_error")
_STATE_KEYS = ("pose", "goal", "segments", "mask", "step_count", *CONTROL_KEYS, *ERROR_KEYS)


@dataclass
class RewardConfig:
    """Reward weights (paper, "Rewards")."""

    progress: float = 0.05  # paper: +0.05 per metre of progress toward the goal
    tractor_heading: float = 0.5  # paper: +0.5 per radian of tractor heading correction
    trailer_heading: float = 0.5  # paper: +0.5 per radian of trailer heading correction
    time: float = 0.0  # paper: time reward 0 per step
    success: float = 5.0  # paper: +5 on success
    collision: float = -7.0  # paper: -7 on collision or jack-knife
    timeout: float = -8.0  # paper: -8 on timeout

    def __post_init__(self) -> None:
        for f in fields(self):
            setattr(self, f.name, check_range(f"env.reward.{f.name}", getattr(self, f.name)))


@dataclass
class ToleranceConfig:
    """Goal tolerances at difficulty 0 and the starting difficulty (paper, "Curriculum")."""

    position: float = 30.0  # [m] paper: 30 m at difficulty 0
    heading_deg: float = 60.0  # [deg] paper: 60 degrees at difficulty 0
    difficulty: float = 0.0  # starting difficulty; tolerances scale by 2**-difficulty

    def __post_init__(self) -> None:
        self.position = check_range("env.tolerance.position", self.position, 0.0, 1e4, lo_open=True)
        self.heading_deg = check_range(
            "env.tolerance.heading_deg", self.heading_deg, 0.0, 180.0, lo_open=True
        )
        self.difficulty = check_range("env.tolerance.difficulty", self.difficulty, 0.0, 30.0)


@dataclass
class EnvConfig:
    """Everything that defines a TruckEnv except the batch size and device."""

    dt: float = 0.1  # [s] paper: dt = 0.1 s
    max_steps: int = 200  # paper: 200 steps per episode
    substeps: int = 1  # Euler sub-steps per dt (1 = the paper's scheme)
    nonfinite_action: str = "zero"
    compile: bool = False  # torch.compile the step and observation (fuses the pair tests)
    episode_pool: int = 256  # episodes generated per refill of the reset pool
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    tolerance: ToleranceConfig = field(default_factory=ToleranceConfig)

    def __post_init__(self) -> None:
        self.dt = check_range("env.dt", self.dt, 0.0, 1.0, lo_open=True)
        self.max_steps = int(check_range("env.max_steps", self.max_steps, 1, 1e6))
        self.substeps = int(check_range("env.substeps", self.substeps, 1, 1000))
        self.episode_pool = int(check_range("env.episode_pool", self.episode_pool, 1, 1_000_000))
        check_choice("env.nonfinite_action", self.nonfinite_action, ("zero", "error"))
        if not isinstance(self.compile, bool):
            raise ConfigError(f"env.compile = {self.compile!r} must be true or false")
        for name, cls in (
            ("vehicle", VehicleConfig),
            ("scene", SceneConfig),
            ("lidar", LidarConfig),
            ("control", ControlConfig),
            ("reward", RewardConfig),
            ("tolerance", ToleranceConfig),
        ):
            setattr(self, name, from_mapping(cls, getattr(self, name), f"env.{name}"))

    @classmethod
    def from_hydra(cls, env: Any = None, control: Any = None) -> EnvConfig:
        """Build from the composed Hydra nodes ``cfg.env`` and ``cfg.control``.

        ``env.num_envs`` (a constructor argument of :class:`TruckEnv`) is ignored here.
        """

        def plain(node: Any) -> dict:
            if node is None:
                return {}
            return (
                OmegaConf.to_container(node, resolve=True)
                if OmegaConf.is_config(node)
                else dict(node)
            )

        data = plain(env)
        data.pop("num_envs", None)
        if control is not None:
            data["control"] = plain(control)
        return from_mapping(cls, data, "env")


class TruckEnv(EnvBase):
    """Batched tractor-trailer environment; see the module docstring for specs and reward.

    Args:
        num_envs: number of trucks N held as one batch (``batch_size=[N]``).
        device: torch device for all state and outputs.
        config: :class:`EnvConfig`, a mapping of its fields, or ``None`` for the defaults.
        seed: seed of the scene/vehicle generator; ``None`` draws one from torch's global RNG.
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int = 1,
        device: torch.device | str = "cpu",
        config: EnvConfig | dict | None = None,
        seed: int | None = None,
    ) -> None:
        if int(num_envs) < 1:
            raise ConfigError(f"num_envs = {num_envs} must be >= 1")
        super().__init__(device=device, batch_size=torch.Size([int(num_envs)]))
        self.config = from_mapping(EnvConfig, config, "env")
        cfg = self.config
        self.num_envs = int(num_envs)
        self.control = Control(cfg.control, cfg.dt, min_speed=cfg.vehicle.min_speed)
        self.rel_angles = beam_angles(cfg.lidar.num_beams, cfg.lidar.fov).to(self.device)
        self._param_index = torch.tensor(
            [PARAM_KEYS.index(k) for k in OBSERVED_PARAMS]
            + [
                PARAM_KEYS.index(_LONG_LIMIT[cfg.control.longitudinal]),
                PARAM_KEYS.index(_LAT_LIMIT[cfg.control.lateral]),
            ],
            device=self.device,
        )
        self._state: TensorDict | None = None
        self._pool: TensorDict | None = None
        self._restore: TensorDictBase | None = None  # state for the next reset (reset_to)
        self._difficulty = torch.full(
            (self.num_envs,), cfg.tolerance.difficulty, device=self.device
        )
        self._make_specs()
        compile_fn = (lambda f: torch.compile(f, dynamic=False)) if cfg.compile else (lambda f: f)
        self._transition_fn = compile_fn(self._transition)
        self._features_fn = compile_fn(self._features)
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        self.set_seed(seed)

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        n, r = self.num_envs, self.config.lidar.num_beams
        shape, col = (n,), (n, 1)
        info = {k: Categorical(2, col, dtype=torch.bool, device=self.device) for k in FLAG_KEYS}
        for k in REWARD_TERMS + ERROR_KEYS + ("difficulty",):
            info[k] = Unbounded(col, dtype=torch.float32, device=self.device)
        info["step_count"] = Unbounded(col, dtype=torch.int64, device=self.device)
        self.observation_spec = Composite(
            observation=Unbounded((n, NUM_FEATURES), dtype=torch.float32, device=self.device),
            lidar=Bounded(0.0, 1.0, (n, r), dtype=torch.float32, device=self.device),
            **info,
            shape=shape,
            device=self.device,
        )
        self.action_spec = Bounded(-1.0, 1.0, (n, 2), dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded(col, dtype=torch.float32, device=self.device)
        self.done_spec = Composite(
            done=Categorical(2, col, dtype=torch.bool, device=self.device),
            terminated=Categorical(2, col, dtype=torch.bool, device=self.device),
            truncated=Categorical(2, col, dtype=torch.bool, device=self.device),
            shape=shape,
            device=self.device,
        )

    # ------------------------------------------------------------------ seeding / curriculum
    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        self.rng = torch.Generator(device=self.device)
        self.rng.manual_seed(int(seed))
        self._pool = None

    def set_difficulty(self, difficulty: float) -> None:
        """Set the curriculum difficulty ``d`` (>= 0) for every truck; used from the next step on.

        Tolerances become ``position * 2**-d`` metres and ``heading_deg * 2**-d`` degrees.
        """
        d = check_range("difficulty", difficulty, 0.0, 30.0)
        self._difficulty.fill_(d)

    @property
    def difficulty(self) -> float:
        """Current difficulty (all trucks share it)."""
        return self.get_difficulty()

    def get_difficulty(self) -> float:
        """Current difficulty; a method, so ``ParallelEnv`` dispatches it to every worker."""
        return float(self._difficulty[0])

    def tolerances(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-truck ``(position [m], heading [rad])`` tolerances, each ``[N]``."""
        return self._tolerances(self._difficulty)

    def _tolerances(self, difficulty: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # paper: tolerances = 30 m and 60 deg times 2**-difficulty
        scale = torch.pow(2.0, -difficulty)
        tol = self.config.tolerance
        return tol.position * scale, math.radians(tol.heading_deg) * scale

    # ------------------------------------------------------------------ reset
    def _new_episodes(self, m: int) -> TensorDict:
        """Fresh state for ``m`` episodes, taken from a pool refilled ``episode_pool`` at a time.

        Scene generation costs ~17 ms for one scene but ~0.5 ms per scene in batches of 1,024, and
        a training batch resets a few trucks every step, so episodes are made ahead in batches.
        The pool is cleared by :meth:`set_seed`, so a seed still fixes the sequence of scenes.
        """
        pool = self._pool
        if pool is None or pool.batch_size[0] < m:
            fresh = self._generate(max(m, self.config.episode_pool))
            pool = fresh if pool is None else torch.cat((pool, fresh))
        self._pool = pool[m:]
        return pool[:m]

    def _generate(self, m: int) -> TensorDict:
        """``m`` new episodes: vehicles, scenes, start pose at rest."""
        cfg = self.config
        params = sample_vehicle_params(cfg.vehicle, m, self.rng, self.device)
        scenes = generate_scenes(cfg.scene, params, self.rng, self.device)
        zeros = torch.zeros(m, device=self.device)
        pose = torch.cat((scenes.start, zeros[:, None]), dim=-1)
        td = TensorDict(
            {
                "pose": pose,
                "goal": scenes.goal,
                "segments": scenes.segments,
                "mask": scenes.mask,
                "kind": scenes.kind,
                "params": TensorDict(params, batch_size=[m]),
                "step_count": torch.zeros(m, dtype=torch.int64, device=self.device),
                **self.control.zero_state(m, self.device),
            },
            batch_size=[m],
            device=self.device,
        )
        td.update(self._errors(td["pose"], td["goal"]))
        return td

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        """Reset all trucks, or only those flagged by ``tensordict["_reset"]`` (``[N, 1]`` bool).

        On a partial reset only the reset rows of the returned tensordict are meaningful: TorchRL
        merges them with ``where(_reset, new, old)``, so the other rows are left at zero and the
        observation (LiDAR included) is computed for the reset trucks alone.
        """
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if self._restore is not None:
            self._state, self._restore = self._restore, None
            out = self._observe()
        elif self._state is None or reset is None:
            self._state = self._new_episodes(self.num_envs)
            out = self._observe()
        else:
            idx = reset.reshape(self.num_envs).nonzero().squeeze(-1)  # one sync per reset call
            out = self.observation_spec.zero()
            if idx.numel():
                self._state[idx] = self._new_episodes(idx.numel())
                part = self._features(self._flat_state(idx), self._difficulty[idx])
                for k, v in part.items():
                    out[k][idx] = v
        false_col = torch.zeros(self.num_envs, 1, dtype=torch.bool, device=self.device)
        out.update({k: torch.zeros(self.num_envs, 1, device=self.device) for k in REWARD_TERMS})
        out.update({k: false_col for k in FLAG_KEYS})
        out.update(done=false_col, terminated=false_col, truncated=false_col)
        return out

    def reset_to(self, state: TensorDictBase) -> TensorDictBase:
        """Reset every truck to a saved full state and return the reset tensordict.

        Replays an episode from its start (same scene, vehicle and pose) without drawing from the
        scene generator, so the sequence of later random scenes is unchanged.

        Args:
            state: ``[N]`` states as saved by :meth:`state_of` right after a reset (stack them,
                e.g. ``state.unsqueeze(0)`` for ``N = 1``).
        """
        if tuple(state.batch_size) != (self.num_envs,):
            raise ValueError(
                f"reset_to needs a state of batch size [{self.num_envs}], got {list(state.batch_size)}"
            )
        self._restore = state.to(self.device).clone()
        return self.reset()

    # ------------------------------------------------------------------ step
    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict["action"]
        if self.config.nonfinite_action == "error":
            finite = torch.isfinite(action).all(-1)
            if not bool(finite.all()):
                bad = (~finite).nonzero().squeeze(-1).tolist()
                raise ValueError(f"non-finite action for env(s) {bad}: {action[~finite].tolist()}")
        new, out = self._transition_fn(action, self._flat_state(), self._difficulty)
        self._state.update(new)
        return TensorDict(out, batch_size=[self.num_envs], device=self.device)

    def _flat_state(self, index: torch.Tensor | None = None) -> dict[str, Any]:
        """The state (rows ``index``, default all) as plain tensors, ``params`` as a dict."""
        s = self._state if index is None else self._state[index]
        flat = {k: s[k] for k in _STATE_KEYS}
        flat["params"] = {k: s["params", k] for k in PARAM_KEYS}
        return flat

    def _transition(
        self, action: torch.Tensor, s: dict[str, Any], difficulty: torch.Tensor
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """One step for all N trucks as pure tensor ops (the part ``env.compile`` compiles).

        Args:
            action: ``[N, 2]`` raw actions (may hold NaN/inf, which are zeroed and flagged).
            s: state from :meth:`_flat_state`.
            difficulty: ``[N]`` curriculum difficulty.

        Returns:
            ``(new_state, out)``: updated state entries ``{key: [N]...}`` and the step output
            ``{key: [N, ...]}`` (observation, reward terms, flags, done signals).
        """
        cfg, w = self.config, self.config.reward
        finite = torch.isfinite(action).all(-1)
        action = torch.where(finite[:, None], action, torch.zeros_like(action)).clamp(-1.0, 1.0)
        params = s["params"]
        ctrl = self.control.step(action, {k: s[k] for k in CONTROL_KEYS}, params)
        pose, _ = kinematics_step(
            s["pose"], ctrl["speed"], ctrl["steer"], params, cfg.dt, cfg.substeps
        )
        collision = truck_collides(pose, params, s["segments"], s["mask"])
        jack = jackknifed(pose, params)
        err = self._errors(pose, s["goal"])
        step_count = s["step_count"] + 1

        tol_pos, tol_ang = self._tolerances(difficulty)
        failed = collision | jack
        success = (
            (err["pos_error"] <= tol_pos)
            & (err["tractor_heading_error"] <= tol_ang)
            & (err["trailer_heading_error"] <= tol_ang)
            & ~failed
        )
        terminated = success | failed
        truncated = (step_count >= cfg.max_steps) & ~terminated

        zero = torch.zeros_like(tol_pos)
        terms = {
            "r_progress": w.progress * (s["pos_error"] - err["pos_error"]),
            "r_tractor_heading": w.tractor_heading
            * (s["tractor_heading_error"] - err["tractor_heading_error"]),
            "r_trailer_heading": w.trailer_heading
            * (s["trailer_heading_error"] - err["trailer_heading_error"]),
            "r_time": zero + w.time,
            "r_success": torch.where(success, w.success, zero),
            "r_collision": torch.where(failed, w.collision, zero),
            "r_timeout": torch.where(truncated, w.timeout, zero),
        }
        reward = torch.stack(list(terms.values())).sum(0)

        new = {"pose": pose, "step_count": step_count, **ctrl, **err}
        out = {k: v[:, None] for k, v in terms.items()}
        out.update(
            reward=reward[:, None],
            success=success[:, None],
            collision=collision[:, None],
            jackknife=jack[:, None],
            action_nonfinite=~finite[:, None],
            done=(terminated | truncated)[:, None],
            terminated=terminated[:, None],
            truncated=truncated[:, None],
        )
        out.update(self._features({**s, **new}, difficulty))
        return new, out

    # ------------------------------------------------------------------ observation
    @staticmethod
    def _errors(pose: torch.Tensor, goal: torch.Tensor) -> dict[str, torch.Tensor]:
        """Errors to the goal, each ``[M]``: position [m] and tractor/trailer heading [rad].

        The goal is a rear-axle pose with the trailer aligned, so the position error is taken at
        the tractor rear axle and both headings are compared with the goal heading.
        """
        pos = torch.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])
        tractor = wrap_angle(goal[:, 2] - pose[:, 2]).abs()
        trailer = wrap_angle(goal[:, 2] - pose[:, 2] - pose[:, 3]).abs()
        return {
            "pos_error": pos,
            "tractor_heading_error": tractor,
            "trailer_heading_error": trailer,
        }

    def sensor_origin(self, pose: torch.Tensor, params: Any) -> torch.Tensor:
        """LiDAR origin ``[N, 2]`` [m]: the centre of the tractor body."""
        ahead = 0.5 * (params["wheelbase"] + params["front_overhang"] - params["rear_overhang"])
        offset = torch.stack((ahead, torch.zeros_like(ahead)), dim=-1)
        return pose[:, :2] + rotate(offset, pose[:, 2])

    def _scan(self, pose: torch.Tensor, params: Any, segments, mask) -> torch.Tensor:
        """LiDAR ranges ``[N, R]`` [m] from the tractor centre."""
        lidar = self.config.lidar
        origin = self.sensor_origin(pose, params)
        return lidar_scan(
            origin, pose[:, 2], segments, mask, self.rel_angles, lidar.max_range, lidar.method
        )

    def _features(self, s: dict[str, Any], difficulty: torch.Tensor) -> dict[str, torch.Tensor]:
        """Observation entries ``{key: [N, ...]}`` of the module docstring from state ``s``."""
        pose, goal, p = s["pose"], s["goal"], s["params"]
        theta, phi = pose[:, 2], pose[:, 3]
        goal_local = to_local(goal[:, None, :2], pose[:, :2], theta)[:, 0] / GOAL_SCALE
        d_tr = goal[:, 2] - theta
        d_tl = d_tr - phi
        motion = torch.stack(
            (
                s["speed"] / p["max_speed"],
                s["accel"] / p["max_accel"],
                s["jerk"] / p["max_jerk"],
                s["steer"] / p["max_steer"],
                s["steer_rate"] / p["max_steer_rate"],
                s["steer_accel"] / p["max_steer_accel"],
            ),
            dim=-1,
        )
        geometry = normalized_params(p, self.config.vehicle)[:, self._param_index]
        angles = torch.stack(
            (d_tr.sin(), d_tr.cos(), d_tl.sin(), d_tl.cos(), phi.sin(), phi.cos()), -1
        )
        ranges = self._scan(pose, p, s["segments"], s["mask"])
        return {
            "observation": torch.cat((goal_local, angles, motion, geometry), dim=-1),
            "lidar": ranges / self.config.lidar.max_range,
            # copies: a later partial reset writes the state in place, and these values must stay
            # those of the step that ended the episode
            **{k: s[k][:, None].clone() for k in ERROR_KEYS},
            "step_count": s["step_count"][:, None].clone(),
            "difficulty": difficulty[:, None].clone(),
        }

    def _observe(self) -> TensorDict:
        out = self._features_fn(self._flat_state(), self._difficulty)
        return TensorDict(out, batch_size=[self.num_envs], device=self.device)

    # ------------------------------------------------------------------ rendering
    def render_frame(self, index: int = 0, **draw_kwargs) -> np.ndarray:
        """RGB image ``[H, W, 3]`` uint8 of truck ``index``: scene, truck, goal, tolerance, LiDAR.

        Extra keyword arguments go to :func:`truckrl.viz.draw.draw_scene` (e.g. ``hud_lines``,
        ``size_px``); the view is centred on the tractor rear axle unless ``center`` is given.
        """
        from truckrl.viz.draw import draw_scene

        if self._state is None:
            raise RuntimeError("render_frame() needs reset() first")
        s = self._state[index : index + 1]
        tractor, trailer, _ = truck_corners(s["pose"], s["params"])
        origin = self.sensor_origin(s["pose"], s["params"])
        ranges = self._scan(s["pose"], s["params"], s["segments"], s["mask"])
        tol_pos, tol_ang = self.tolerances()
        return draw_scene(
            s["segments"][0].cpu(),
            s["mask"][0].cpu(),
            s["kind"][0].cpu(),
            tractor=tractor[0].cpu(),
            trailer=trailer[0].cpu(),
            goal=s["goal"][0].cpu(),
            goal_tolerance=(float(tol_pos[index]), float(tol_ang[index])),
            lidar_origin=origin[0].cpu(),
            lidar_ranges=ranges[0].cpu(),
            lidar_angles=(self.rel_angles + s["pose"][0, 2]).cpu(),
            **{"center": s["pose"][0, :2].cpu(), **draw_kwargs},
        )

    def state_of(self, index: int) -> TensorDict:
        """A copy of truck ``index``'s full internal state (pose, controls, params, scene)."""
        if self._state is None:
            raise RuntimeError("state_of() needs reset() first")
        return self._state[index].clone()
