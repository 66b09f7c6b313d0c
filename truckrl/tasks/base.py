"""The task core: a batch of episodes as a state, and pure functions that advance and read it.

No TorchRL here: a user can drive a task with plain tensors. :class:`~truckrl.env.TruckEnv` is a
thin adapter over these functions.

State (a ``TensorDict`` or a plain dict with ``batch [N]``)::

    pose        [N, 4]  tractor rear-axle x, y [m], heading theta [rad], articulation phi [rad]
    goal        [N, 3]  goal rear-axle x, y [m], heading [rad] (trailer aligned)
    segments    [N, E, 4] scene segments (x0, y0, x1, y1) [m];  mask [N, E] bool; kind [N, E] int8
    params      {key: [N]}  per-truck vehicle parameters (truckrl.sim.vehicle.PARAM_KEYS, plus
                            REVERSE_KEYS for a task that reverses)
    step_count  [N] int64
    speed, accel, jerk, steer, steer_rate, steer_accel   [N]  control state (truckrl.sim.control)
    <error keys of the task>  [N]  errors to the goal (intersection: pos_error [m], ...)
    route       {key: [N]}  scene metadata from the generator (route category, angles, ...);
                            other tasks name theirs scene_info (evaluation bins by it)

What differs between tasks lives in a :class:`Task` subclass: :meth:`Task.sample` (vehicles,
scene, start and goal), :meth:`Task.errors`, :meth:`Task.success`, :meth:`Task.reward_terms`
(and their weights, in the task's config) and :meth:`Task.observation_extras`. What every task
shares is final here: :meth:`Task.step` (control + kinematics), :meth:`Task.outcome`
(collision, jack-knife, success, timeout), :meth:`Task.observe` and :meth:`Task.transition`
(all of it, the function the env runs and compiles). A task that sets :attr:`Task.reverse`
gets trucks with a reverse speed limit and a control whose speed goes down to it.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar

import torch
from torch import Tensor

from truckrl.sim.collision import truck_collides
from truckrl.sim.control import CONTROL_KEYS, Control, commanded
from truckrl.sim.geometry import rotate, to_local
from truckrl.sim.lidar import beam_angles, lidar_scan
from truckrl.sim.vehicle import (
    PARAM_KEYS,
    jackknifed,
    kinematics_step,
    normalized_params,
    sample_vehicle_params,
)
from truckrl.tasks.bins import generic_bins
from truckrl.tasks.config import SENSOR_SCALE, EnvConfig, TaskConfig
from truckrl.tasks.schema import CategoryDim, Quantity

if TYPE_CHECKING:  # imported where a state is built: config-only imports stay light
    from tensordict import TensorDict

#: Size of the numeric observation every task starts with (paper: "26 scalars").
NUM_FEATURES = 26

#: Vehicle parameters observed at indices 14..23 (the two mode-dependent limits follow).
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


def sensor_origin(pose: Tensor, params: Any) -> Tensor:
    """LiDAR origin ``[N, 2]`` [m]: the centre of the tractor body.

    Args:
        pose: ``[N, 4]`` tractor rear-axle pose.
        params: per-truck vehicle parameters ``{key: [N]}``.
    """
    ahead = 0.5 * (params["wheelbase"] + params["front_overhang"] - params["rear_overhang"])
    offset = torch.stack((ahead, torch.zeros_like(ahead)), dim=-1)
    return pose[:, :2] + rotate(offset, pose[:, 2])


class Task:
    """One task: its episodes, errors, success test, reward terms and observation extras.

    A subclass sets the class attributes listed under Attributes.

    Args:
        cfg: the env config; ``cfg.task`` must be an instance of :attr:`config_class`.

    Attributes:
        name: the task's name (its module name).
        config_class: its :class:`TaskConfig` subclass.
        error_quantities: the errors to the goal it reports, in state and outputs.
        reward_keys: names of its reward terms, in summation order.
        reverse: whether its trucks may reverse (default False: forward only, the paper's).
        episode_pool: the reset pool's refill size [episodes] where ``env.episode_pool`` is
            unset (None); a task whose episodes cost more to draw one at a time sets more.
        category_dims: how evaluation splits its episodes by scene (:class:`CategoryDim` over
            the metadata its scenes record in ``state["route"]``); a task whose split needs more
            than independent dimensions overrides :meth:`category_bins` instead.
        compact_scene: whether the env hands :meth:`transition` the scene compacted (valid
            segments first, padding cut: :class:`~truckrl.env.compaction.CompactScene`); False
            for a task whose step reads its own scene (:meth:`sensed`), which the env then
            hands the state's ``segments`` and ``mask`` as they are, slot for slot.
    """

    name: ClassVar[str]
    config_class: ClassVar[type[TaskConfig]]
    error_quantities: ClassVar[tuple[Quantity, ...]]
    reward_keys: ClassVar[tuple[str, ...]]
    reverse: ClassVar[bool] = False
    episode_pool: ClassVar[int] = 256
    category_dims: ClassVar[tuple[CategoryDim, ...]] = ()
    compact_scene: ClassVar[bool] = True

    @classmethod
    def category_bins(cls, info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]] | None:
        """Named bins ``{dimension: {bin: bool [E]}}`` of ``E`` episodes from their scene metadata
        ``info`` (``[E]`` tensors), or None where the task declares no dimensions."""
        return generic_bins(info, cls.category_dims) if cls.category_dims else None

    def __init__(self, cfg: EnvConfig) -> None:
        if not isinstance(cfg.task, self.config_class):
            raise TypeError(f"{type(self).__name__} needs env.task = {self.config_class.__name__}")
        self.cfg = cfg
        self.control = Control(
            cfg.control, cfg.dt, min_speed=cfg.vehicle.min_speed, reverse=self.reverse
        )
        self.rel_angles = beam_angles(cfg.lidar.num_beams, cfg.lidar.fov)
        (_, lon), (_, lat) = commanded(cfg.control.longitudinal, cfg.control.lateral)
        self.param_index = torch.tensor([PARAM_KEYS.index(k) for k in (*OBSERVED_PARAMS, lon, lat)])

    @property
    def error_keys(self) -> tuple[str, ...]:
        return tuple(q.key for q in self.error_quantities)

    @property
    def num_features(self) -> int:
        """Numeric observation size: the shared 26 plus the task's extras."""
        return NUM_FEATURES + self.num_extras

    num_extras: ClassVar[int] = 0
    #: State entries beyond the errors that :meth:`success` reads (e.g. ``"speed"`` for a goal
    #: that must be reached at rest); :meth:`outcome` passes them in ``err`` beside the errors.
    success_state_keys: ClassVar[tuple[str, ...]] = ()
    #: State entries of this task beyond the shared ones (module doc), constant per episode,
    #: that :meth:`transition` reads (e.g. a reference route). :meth:`complete_state` fills them
    #: in a state built by hand.
    extra_state_keys: ClassVar[tuple[str, ...]] = ()

    def to(self, device: torch.device | str) -> Task:
        self.rel_angles = self.rel_angles.to(device)
        self.param_index = self.param_index.to(device)
        return self

    # ------------------------------------------------------------------ task-specific
    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        """``m`` new episodes at their start (state layout in the module doc)."""
        raise NotImplementedError

    def draw_key(self, difficulty: float) -> Hashable:
        """What :meth:`sample_pool`'s episodes depend on at ``difficulty`` (the env's float);
        the default: nothing (``None``), the same draws at every difficulty. The env's episode
        pool drops its held episodes where it changes."""
        return None

    def sample_pool(
        self, m: int, rng: torch.Generator, device: torch.device, key: Hashable, carry: Any
    ) -> tuple[TensorDict, Any]:
        """An episode pool's refill: ``(between 1 and m new episodes at their start, what the
        next refill takes over)``, for the draw key ``key`` (:meth:`draw_key`; the episodes
        then start only under a difficulty of that key). ``carry`` is what the previous refill
        handed over (``None`` at first and after a new seed). The default: :meth:`sample` of
        ``m``, nothing carried."""
        return self.sample(m, rng, device), None

    def sample_params(
        self, m: int, rng: torch.Generator, device: torch.device
    ) -> dict[str, Tensor]:
        """``m`` trucks ``{key: [m]}`` from ``env.vehicle`` (with a reverse limit if
        :attr:`reverse`)."""
        return sample_vehicle_params(self.cfg.vehicle, m, rng, device, reverse=self.reverse)

    def complete_state(self, state: TensorDict) -> TensorDict:
        """``state`` with any missing :attr:`extra_state_keys` derived from it (in place).

        A state that :meth:`sample` made has them; one built by hand (tests, the planner) may
        not. The default task has none.
        """
        return state

    def on_reset(self, state: TensorDict, difficulty: Tensor) -> TensorDict:
        """Fresh episodes ``state [m]`` as they start under ``difficulty [m]`` (their curriculum
        difficulty at reset); the default returns them unchanged.

        :class:`~truckrl.env.TruckEnv` calls it on every episode it draws at a reset (not on a
        state given to ``set_state``). A task with a start curriculum moves the start here; it
        must keep the state complete (errors recomputed) and must draw no random numbers (the
        episodes' draws come from :meth:`sample`), so a seed still fixes every episode. It sets
        new tensors and never writes into the given ones: the env's episode pool keeps the drawn
        episodes to prepare them again when the difficulty changes.
        """
        return state

    def idle_keys(self, difficulty: float) -> tuple[str, ...]:
        """State keys that the step of an episode started at ``difficulty`` (the env's own
        float) can go without, because what they hold stays still there; the default: none.

        :class:`~truckrl.env.TruckEnv` leaves them out of the state it steps and observes while
        every episode of its batch started at such a difficulty (a host-side rule: no device
        value is read), so a task that names some must read them only where they are present,
        and without them must step and observe exactly as with them.
        """
        return ()

    def errors(self, s: Mapping[str, Any]) -> dict[str, Tensor]:
        """Errors to the goal ``{key: [N]}`` for :attr:`error_quantities`.

        Args:
            s: the state (module doc) after the step: ``pose``, ``goal``, ``params`` and the
                control state (``speed`` [m/s], ...) are there.
        """
        raise NotImplementedError

    def success(self, err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
        """``[N]`` bool: the goal is reached within the tolerances (before failures count).

        ``err`` holds the errors and the :attr:`success_state_keys` entries of the state."""
        raise NotImplementedError

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        """Reward terms ``{key: [N]}`` (keys :attr:`reward_keys`) of one step."""
        raise NotImplementedError

    def observation_extras(self, s: dict[str, Any]) -> Tensor | None:
        """Extra numeric features ``[N, num_extras]`` appended after the shared 26 (or None)."""
        return None

    # ------------------------------------------------------------------ shared core
    def tolerances(self, difficulty: Tensor) -> tuple[Tensor, Tensor]:
        """``(position [m], heading [rad])`` tolerances, each ``[N]``, at ``difficulty [N]``."""
        # paper: tolerances = 30 m and 60 deg times 2**-difficulty
        scale = torch.pow(2.0, -difficulty)
        tol = self.cfg.tolerance
        return tol.position * scale, math.radians(tol.heading_deg) * scale

    def step(self, s: dict[str, Any], action: Tensor) -> dict[str, Tensor]:
        """Advance every truck by one ``dt``: control, kinematics, errors and step count.

        Args:
            s: state (module doc); ``params`` a mapping of ``[N]`` tensors.
            action: ``[N, 2]`` finite commands (clamped to ``[-1, 1]``).

        Returns:
            The updated state entries ``{key: [N, ...]}`` (pose, step_count, control, errors).
        """
        cfg = self.cfg
        params = s["params"]
        ctrl = self.control.step(action, {k: s[k] for k in CONTROL_KEYS}, params)
        pose, _ = kinematics_step(
            s["pose"], ctrl["speed"], ctrl["steer"], params, cfg.dt, cfg.substeps
        )
        err = self.errors({**s, **ctrl, "pose": pose})
        return {"pose": pose, "step_count": s["step_count"] + 1, **ctrl, **err}

    def outcome(self, s: dict[str, Any], difficulty: Tensor) -> dict[str, Tensor]:
        """How the state ends its episode: ``success``, ``collision``, ``jackknife``,
        ``terminated`` and ``truncated`` (timeout), each ``[N]`` bool."""
        params = s["params"]
        collision = truck_collides(s["pose"], params, s["segments"], s["mask"])
        jack = jackknifed(s["pose"], params)
        err = {k: s[k] for k in (*self.error_keys, *self.success_state_keys)}
        tol_pos, tol_ang = self.tolerances(difficulty)
        failed = collision | jack
        success = self.success(err, tol_pos, tol_ang) & ~failed
        terminated = success | failed
        truncated = (s["step_count"] >= self.cfg.max_steps) & ~terminated
        return {
            "success": success,
            "collision": collision,
            "jackknife": jack,
            "terminated": terminated,
            "truncated": truncated,
        }

    def observe(self, s: dict[str, Any], difficulty: Tensor) -> dict[str, Tensor]:
        """Observation entries ``{key: [N, ...]}`` (TruckEnv's docstring tabulates the indices).

        ``observation [N, F]`` numeric features, ``lidar [N, R]`` ranges / max range, plus copies
        of the errors, step count and difficulty as ``[N, 1]`` columns.
        """
        pose, goal, p = s["pose"], s["goal"], s["params"]
        theta, phi = pose[:, 2], pose[:, 3]
        goal_local = to_local(goal[:, None, :2], pose[:, :2], theta)[:, 0] / SENSOR_SCALE
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
        geometry = normalized_params(p, self.cfg.vehicle)[:, self.param_index]
        angles = torch.stack(
            (d_tr.sin(), d_tr.cos(), d_tl.sin(), d_tl.cos(), phi.sin(), phi.cos()), -1
        )
        features = [goal_local, angles, motion, geometry]
        extras = self.observation_extras(s)
        if extras is not None:
            features.append(extras)
        ranges = self.scan(s)
        return {
            "observation": torch.cat(features, dim=-1),
            "lidar": ranges / self.cfg.lidar.max_range,
            # copies: a later partial reset writes the state in place, and these values must stay
            # those of the step that ended the episode
            **{k: s[k][:, None].clone() for k in self.error_keys},
            "step_count": s["step_count"][:, None].clone(),
            "difficulty": difficulty[:, None].clone(),
        }

    def sensed(self, s: dict[str, Any]) -> dict[str, Any]:
        """``s`` as the collision test and the LiDAR read it (its ``segments`` and ``mask``).

        The default returns ``s``. A task whose scene holds more than the state's segments (moving
        vehicles) adds it here; :meth:`transition` calls it once per step and hands the result
        to :meth:`outcome` and :meth:`observe`, so such a task's overrides of those must accept
        an ``s`` that is already sensed.
        """
        return s

    def scan(self, s: dict[str, Any]) -> Tensor:
        """LiDAR ranges ``[N, R]`` [m] from the tractor centre."""
        lidar, pose = self.cfg.lidar, s["pose"]
        origin = sensor_origin(pose, s["params"])
        return lidar_scan(
            origin,
            pose[:, 2],
            s["segments"],
            s["mask"],
            self.rel_angles,
            lidar.max_range,
        )

    def transition(
        self, action: Tensor, s: dict[str, Any], difficulty: Tensor
    ) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
        """One whole env step for all N trucks as pure tensor ops (what ``env.compile`` compiles).

        Non-finite actions are replaced by 0 before they touch the state and flagged.

        ``s["segments"]`` / ``s["mask"]`` are read as a set (LiDAR minimum, collision any):
        :class:`~truckrl.env.TruckEnv` passes them valid-first with trailing padding cut
        (``[N, W <= E, 4]``; slot for slot where :attr:`compact_scene` is False), which gives
        the same outputs bit for bit.

        Args:
            action: ``[N, 2]`` raw actions (may hold NaN/inf).
            s: state (module doc), ``params`` as a mapping.
            difficulty: ``[N]`` curriculum difficulty.

        Returns:
            ``(new_state, out)``: updated state entries and the step output ``{key: [N, ...]}``
            (observation, reward and its terms, flags, done signals).
        """
        finite = torch.isfinite(action).all(-1)
        action = torch.where(finite[:, None], action, torch.zeros_like(action)).clamp(-1.0, 1.0)
        new = self.step(s, action)
        after = {**s, **new}
        seen = self.sensed(after)
        flags = self.outcome(seen, difficulty)
        terms = self.reward_terms(s, after, flags)
        reward = torch.stack(list(terms.values())).sum(0)
        out = {k: v[:, None] for k, v in terms.items()}
        out.update(
            reward=reward[:, None],
            success=flags["success"][:, None],
            collision=flags["collision"][:, None],
            jackknife=flags["jackknife"][:, None],
            action_nonfinite=~finite[:, None],
            done=(flags["terminated"] | flags["truncated"])[:, None],
            terminated=flags["terminated"][:, None],
            truncated=flags["truncated"][:, None],
        )
        out.update(self.observe(seen, difficulty))
        return new, out

    def initial_state(
        self, params: dict[str, Tensor], scene: dict[str, Tensor], device: torch.device
    ) -> TensorDict:
        """State at the start of ``m`` episodes from sampled vehicles and a scene batch.

        Args:
            params: ``{key: [m]}`` vehicle parameters.
            scene: ``pose [m, 3]`` start (rear axle, trailer aligned), ``goal [m, 3]``,
                ``segments``, ``mask``, ``kind`` and ``route`` (a mapping of ``[m]`` tensors).
        """
        from tensordict import TensorDict

        m = scene["goal"].shape[0]
        zeros = torch.zeros(m, device=device)
        pose = torch.cat((scene["start"], zeros[:, None]), dim=-1)
        td = TensorDict(
            {
                "pose": pose,
                "goal": scene["goal"],
                "segments": scene["segments"],
                "mask": scene["mask"],
                "kind": scene["kind"],
                "params": TensorDict(params, batch_size=[m]),
                "step_count": torch.zeros(m, dtype=torch.int64, device=device),
                **self.control.zero_state(m, device),
            },
            batch_size=[m],
            device=device,
        )
        if scene.get("route"):
            td["route"] = TensorDict(scene["route"], batch_size=[m])
        td.update(self.errors(td))
        return td
