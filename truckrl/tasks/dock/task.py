"""Task ``dock``: reverse a tractor-trailer from the apron into a free loading bay.

* Episodes: :func:`truckrl.tasks.dock.scene.generate_dock_scenes` (a row of bays with side walls
  at a dock face, parked trailers in some other bays, an apron closed by a far curb; the truck
  pulled forward on the apron; rules and metadata in that module). The trucks may reverse
  (:attr:`DockTask.reverse`): each has a ``max_reverse_speed`` (``env.vehicle``).
* Goal: the trailer's rear-centre ``dock_gap`` in front of the dock face in the middle of the bay,
  the trailer along the bay axis (the goal pose in the state is the tractor rear axle of that
  truck at articulation 0, heading out of the bay).
* Errors (measured on the trailer): ``trailer_rear_error`` [m], the trailer rear-centre (trailer
  axle minus ``trailer_rear_overhang`` along the trailer heading ``theta + phi``) to the goal's;
  ``trailer_heading_error`` [rad], ``|theta + phi - goal heading|`` wrapped.
* Success: both errors within the tolerances **and the truck at rest**, ``|v| <= rest_speed``.
  The speed is not an error quantity (errors are compared with a position or an angle
  tolerance by every consumer: the planner's score, the HUD, evaluation); the success test reads
  it from the state through :attr:`Task.success_state_keys`.
* Tolerances: ``env.tolerance.position * 2**-d`` and ``env.tolerance.heading_deg * 2**-d`` as for
  the intersection task, but never below ``final_position`` (0.15 m) and ``final_heading``
  (0.1 rad). The preset ``experiment=dock`` sets ``env.tolerance.position = 19.2`` m
  (``0.15 * 2**7``) and ``heading_deg = 180``: the heading tolerance reaches its floor at
  ``d = log2(pi / 0.1) = 4.97`` and the position tolerance at ``d = 7`` (the final tolerance,
  the preset's ``stop_difficulty``). With the default ``env.tolerance`` (30 m, 60 deg) the floors
  are reached at ``d = 3.39`` (heading) and ``d = 7.64`` (position).
* Reward: ``progress`` per metre of trailer-rear distance gained, ``trailer_heading`` per radian of
  trailer heading error corrected (both potential-based), ``time`` per step, and the paper's
  terminal values: +5 success, -7 collision or jack-knife, -8 timeout. Each term is its own
  reward key (logged separately).
* Start curriculum (:meth:`DockTask.on_reset`, ``env.task.start``): at low difficulty the truck
  starts **pulled straight out of the bay** (the goal truck moved ``D`` metres along the bay
  axis), ``D`` growing with the difficulty; from ``apron_difficulty[0]`` on a growing share of the
  episodes (all from ``apron_difficulty[1]`` on) keep the generator's apron start. Both starts are
  collision-free by construction: the pulled truck stays in the target bay's strip, which holds no
  segment up to ``start_clearance`` before the far curb (``pull_room``,
  :mod:`~truckrl.tasks.dock.scene`), and the apron start lies in the start band that no segment
  enters.
* Observation extras (after the shared 26): the goal rear-centre in the trailer frame (origin the
  trailer rear-centre, x along the trailer heading) / 50 m (2), ``max_reverse_speed`` mapped from
  its ``env.vehicle`` range to [-1, 1] (1), and ``speed / max_reverse_speed`` (1). The trailer
  heading error's sin/cos are shared features 4 and 5 already.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import to_local, wrap_angle
from truckrl.sim.vehicle import trailer_axle, trailer_rear_offset
from truckrl.tasks.base import Task
from truckrl.tasks.config import SENSOR_SCALE, EnvConfig, TaskConfig, TerminalRewardConfig
from truckrl.tasks.dock.scene import (
    START_PULLED,
    DockSceneConfig,
    generate_dock_scenes,
)
from truckrl.tasks.schema import CategoryDim, Quantity

if TYPE_CHECKING:
    from tensordict import TensorDict

#: State entry holding the scene metadata ``{key: [N]}`` (:data:`DOCK_INFO_KEYS`); evaluation
#: bins episodes by it (``category_dims``). ``route`` is the intersection task's.
INFO_KEY = "scene_info"


@dataclass
class DockRewardConfig(TerminalRewardConfig):
    """Reward weights of the dock task (terminal values: the paper's)."""

    progress: float = param(0.1, unit="1/m", doc="per metre the trailer rear-centre gains")
    trailer_heading: float = param(
        0.5, unit="1/rad", doc="per radian of trailer heading correction", source="paper"
    )


@dataclass
class StartCurriculumConfig:
    """Start-distance curriculum (``env.task.start.*``; :meth:`DockTask.on_reset`)."""

    enabled: bool = param(True, doc="false: every episode starts on the apron")
    pull_distance: tuple[float, float] = param(
        (4.0, 24.0),
        lo=0.0,
        hi=500.0,
        unit="m",
        doc="longest pull-out from the bay at difficulty 0 and from apron_difficulty min on "
        "(linear between); each episode draws D in [1/2, 1] of it, at most its pull_room",
    )
    apron_difficulty: tuple[float, float] = param(
        (2.0, 5.0),
        lo=0.0,
        hi=30.0,
        unit="-",
        doc="difficulties where the share of apron starts rises from 0 to 1 (linear between)",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.start")


@dataclass
class DockConfig(TaskConfig):
    """Config of the dock task: scene rules, rest test, tolerance floors, curriculum, rewards."""

    name: str = param("dock", choices=("dock",), doc="task folder")
    scene: DockSceneConfig = field(default_factory=DockSceneConfig)
    reward: DockRewardConfig = field(default_factory=DockRewardConfig)
    start: StartCurriculumConfig = field(default_factory=StartCurriculumConfig)
    rest_speed: float = param(
        0.1, lo=0.0, lo_open=True, hi=10.0, unit="m/s", doc="success needs |speed| <= this"
    )
    final_position: float = param(
        0.15,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        unit="m",
        doc="position tolerance floor (the halving stops here)",
        source="gym-truck-backerupper",
    )
    final_heading: float = param(
        0.1,
        lo=0.0,
        lo_open=True,
        hi=math.pi,
        unit="rad",
        doc="heading tolerance floor (the halving stops here)",
        source="gym-truck-backerupper",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task")


def trailer_rear(pose: Tensor, params: dict[str, Tensor]) -> Tensor:
    """Trailer rear-centre ``[N, 2]`` [m]: the trailer axle minus ``trailer_rear_overhang`` along
    the trailer heading ``theta + phi``."""
    psi = pose[:, 2] + pose[:, 3]
    back = torch.stack((psi.cos(), psi.sin()), -1) * params["trailer_rear_overhang"][:, None]
    return trailer_axle(pose, params) - back


def goal_rear(goal: Tensor, params: dict[str, Tensor]) -> Tensor:
    """The goal's trailer rear-centre ``[N, 2]`` [m] (goal = tractor rear axle, articulation 0)."""
    u = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)
    return goal[:, :2] - trailer_rear_offset(params)[:, None] * u


class DockTask(Task):
    """Reverse into a loading bay; see the module docstring."""

    name = "dock"
    config_class = DockConfig
    reverse = True
    error_quantities = (
        Quantity("trailer_rear_error", "m", "trailer rear"),
        Quantity("trailer_heading_error", "rad", "trailer heading"),
    )
    success_state_keys = ("speed",)
    category_dims = (
        CategoryDim("start", "start_kind", names=("apron", "pulled out")),
        CategoryDim(
            "start distance [m]", "start_goal_distance", edges=(0.0, 10.0, 20.0, 40.0, 80.0)
        ),
        CategoryDim("neighbours parked", "neighbours_occupied", names=("none", "one", "both")),
        CategoryDim("bay width [m]", "bay_width", edges=(3.5, 4.0, 4.5)),
    )
    reward_keys = (
        "r_progress",
        "r_trailer_heading",
        "r_time",
        "r_success",
        "r_collision",
        "r_timeout",
    )
    num_extras = 4

    def __init__(self, cfg: EnvConfig) -> None:
        super().__init__(cfg)
        widest = max(cfg.vehicle.tractor_width[1], cfg.vehicle.trailer_width[1])
        narrowest = cfg.task.scene.bay_width[0]
        if widest >= narrowest:
            raise ConfigError(
                f"env.task.scene.bay_width min ({narrowest}) must exceed the widest truck "
                f"(env.vehicle tractor_width / trailer_width max: {widest})"
            )

    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        from tensordict import TensorDict

        params = self.sample_params(m, rng, device)
        scenes = generate_dock_scenes(self.cfg.task.scene, params, rng, device)
        scene = {k: getattr(scenes, k) for k in ("start", "goal", "segments", "mask", "kind")}
        state = self.initial_state(params, scene, device)
        state[INFO_KEY] = TensorDict(scenes.info, batch_size=[m])
        return state

    def on_reset(self, state: TensorDict, difficulty: Tensor) -> TensorDict:
        """The start-distance curriculum (module doc): episodes whose ``apron_draw`` is at least
        the apron share at their difficulty start pulled straight out of the bay by
        ``D = D_max(d) * (1 + pull_draw) / 2`` (at most ``pull_room``), at rest, articulation 0.
        Their metadata is updated (``start_kind`` = pulled, offsets and distances)."""
        cur = self.cfg.task.start
        if not cur.enabled:
            return state
        info = state[INFO_KEY]
        d = difficulty.to(state["pose"].dtype)
        a0, a1 = cur.apron_difficulty
        share = ((d - a0) / (a1 - a0)).clamp(0.0, 1.0) if a1 > a0 else (d >= a0).float()
        pulled = info["apron_draw"] >= share
        grow = (d / a0).clamp(0.0, 1.0) if a0 > 0 else torch.ones_like(d)
        d_max = cur.pull_distance[0] + (cur.pull_distance[1] - cur.pull_distance[0]) * grow
        dist = torch.minimum(0.5 * d_max * (1.0 + info["pull_draw"]), info["pull_room"])
        dist = dist.clamp_min(0.0)
        goal = state["goal"]
        u = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)
        moved = torch.cat((goal[:, :2] + dist[:, None] * u, goal[:, 2:3], 0.0 * dist[:, None]), -1)
        state["pose"] = torch.where(pulled[:, None], moved, state["pose"])
        state.update(self.errors(state))
        zero = torch.zeros_like(dist)
        new_info = {
            "start_kind": torch.full_like(info["start_kind"], START_PULLED),
            "start_lateral_offset": zero,
            "start_distance": self.cfg.task.scene.dock_gap + dist,
            "start_heading": zero,
            "start_goal_distance": dist,
        }
        for k, v in new_info.items():
            info[k] = torch.where(pulled, v, info[k])
        return state

    def errors(self, s: dict[str, Any]) -> dict[str, Tensor]:
        """Trailer rear-centre to the goal's [m]; trailer heading to the goal heading [rad]."""
        pose, goal, p = s["pose"], s["goal"], s["params"]
        rear = trailer_rear(pose, p)
        target = goal_rear(goal, p)
        return {
            "trailer_rear_error": torch.hypot(target[:, 0] - rear[:, 0], target[:, 1] - rear[:, 1]),
            "trailer_heading_error": wrap_angle(goal[:, 2] - pose[:, 2] - pose[:, 3]).abs(),
        }

    def tolerances(self, difficulty: Tensor) -> tuple[Tensor, Tensor]:
        """The halving tolerances of the base class, floored at ``final_position`` [m] and
        ``final_heading`` [rad] (module doc)."""
        pos, ang = super().tolerances(difficulty)
        t = self.cfg.task
        return pos.clamp_min(t.final_position), ang.clamp_min(t.final_heading)

    def success(self, err: dict[str, Tensor], tol_pos: Tensor, tol_ang: Tensor) -> Tensor:
        return (
            (err["trailer_rear_error"] <= tol_pos)
            & (err["trailer_heading_error"] <= tol_ang)
            & (err["speed"].abs() <= self.cfg.task.rest_speed)
        )

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        w = self.cfg.task.reward
        zero = torch.zeros_like(after["trailer_rear_error"])
        failed = flags["collision"] | flags["jackknife"]
        return {
            "r_progress": w.progress * (before["trailer_rear_error"] - after["trailer_rear_error"]),
            "r_trailer_heading": w.trailer_heading
            * (before["trailer_heading_error"] - after["trailer_heading_error"]),
            "r_time": zero + w.time,
            "r_success": torch.where(flags["success"], w.success, zero),
            "r_collision": torch.where(failed, w.collision, zero),
            "r_timeout": torch.where(flags["truncated"], w.timeout, zero),
        }

    def observation_extras(self, s: dict[str, Any]) -> Tensor:
        """``[N, 4]``: goal rear-centre in the trailer frame / 50 m (x along the trailer, y left),
        normalised reverse speed limit, speed / reverse speed limit."""
        pose, p = s["pose"], s["params"]
        rear = trailer_rear(pose, p)
        psi = pose[:, 2] + pose[:, 3]
        rel = to_local(goal_rear(s["goal"], p)[:, None], rear, psi)[:, 0] / SENSOR_SCALE
        lo, hi = self.cfg.vehicle.max_reverse_speed
        rev = p["max_reverse_speed"]
        norm = (rev - 0.5 * (lo + hi)) * (2.0 / (hi - lo)) if hi > lo else rev * 0.0
        return torch.cat((rel, norm[:, None], (s["speed"] / rev)[:, None]), -1)


TASK = DockTask
