"""Configuration of the task core and of TruckEnv: every default is written here, once.

The fields carry their range, unit and meaning (:func:`truckrl.config.fields.param`);
``truckrl tools configs`` prints them as a table. Hydra composes these dataclasses as
structured configs (:func:`truckrl.config.schemas.register`); YAML files only hold presets.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from truckrl.config.fields import ConfigError, build, param, validate
from truckrl.sim.control import ControlConfig
from truckrl.sim.lidar import LidarConfig
from truckrl.sim.vehicle import VehicleConfig

#: [m] Scale of goal positions in the observation and of the LiDAR range (paper: "scaled by 50
#: meters", "maximum sensor range of 50 meters").
SENSOR_SCALE = 50.0
#: Largest curriculum difficulty accepted anywhere (tolerances shrink by 2**-30: far below float32
#: resolution of a pose, so higher values mean nothing).
MAX_DIFFICULTY = 30.0


@dataclass
class TerminalRewardConfig:
    """The paper's per-step and terminal reward weights (paper, "Rewards"); every task's reward
    config extends it with its progress terms."""

    time: float = param(0.0, unit="1/step", doc="every step", source="paper")
    success: float = param(5.0, doc="on success", source="paper")
    collision: float = param(-7.0, doc="on collision or jack-knife", source="paper")
    timeout: float = param(-8.0, doc="on timeout", source="paper")

    def __post_init__(self) -> None:
        validate(self, "env.task.reward")


#: The task a config without ``task.name`` runs: the paper's. The only place outside a task's
#: folder that names a task (tests/test_layers.py checks this).
DEFAULT_TASK = "intersection"


@dataclass
class TaskConfig:
    """Base of every task's config; ``name`` picks the task folder ``truckrl/tasks/<name>/``."""

    name: str = param(DEFAULT_TASK, doc="task package under truckrl/tasks/")


@dataclass
class ToleranceConfig:
    """Goal tolerances at difficulty 0 and the starting difficulty (paper, "Curriculum")."""

    position: float = param(
        30.0,
        lo=0.0,
        hi=1e4,
        lo_open=True,
        unit="m",
        doc="position tolerance at difficulty 0",
        source="paper",
    )
    heading_deg: float = param(
        60.0,
        lo=0.0,
        hi=180.0,
        lo_open=True,
        unit="deg",
        doc="heading tolerance at difficulty 0",
        source="paper",
    )
    difficulty: float = param(
        0.0,
        lo=0.0,
        hi=MAX_DIFFICULTY,
        unit="-",
        doc="starting difficulty d; tolerances scale by 2**-d",
    )

    def __post_init__(self) -> None:
        validate(self, "env.tolerance")

    @property
    def heading(self) -> float:
        """Heading tolerance at difficulty 0 [rad]."""
        return math.radians(self.heading_deg)


@dataclass
class EnvConfig:
    """Everything that defines a TruckEnv except its batch size and device."""

    dt: float = param(0.1, lo=0.0, hi=1.0, lo_open=True, unit="s", doc="step", source="paper")
    max_steps: int = param(
        200, lo=1, hi=1_000_000, unit="steps", doc="steps before timeout", source="paper"
    )
    substeps: int = param(1, lo=1, hi=1000, unit="-", doc="Euler sub-steps per dt (1 = paper)")
    nonfinite_action: str = param(
        "zero",
        choices=("zero", "error"),
        doc="zero: replace NaN/inf actions by 0 and flag them; error: raise (syncs every step)",
    )
    compile: bool = param(
        False,
        doc="torch.compile the step and observation (a compile per process; pays off for big N)",
    )
    episode_pool: int | None = param(
        None,
        lo=1,
        hi=1_000_000,
        unit="episodes",
        doc="episodes generated per refill of the reset pool (batched generation is cheaper; "
        "null: the task's own, Task.episode_pool)",
    )
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    tolerance: ToleranceConfig = field(default_factory=ToleranceConfig)
    #: The task's own config (a :class:`TaskConfig` subclass, chosen by its ``name``); ``None``
    #: means the default task, :data:`DEFAULT_TASK`.
    task: Any = None

    def __post_init__(self) -> None:
        validate(self, "env")
        if self.task is None:
            self.task = {}
        if isinstance(self.task, Mapping):
            from truckrl.tasks.registry import task_class

            name = self.task.get("name", TaskConfig.name)
            self.task = build(task_class(name).config_class, self.task, "env.task")
        elif not isinstance(self.task, TaskConfig):
            raise ConfigError(f"env.task must be a task config, got {self.task!r}")
        if self.episode_pool is None:
            from truckrl.tasks.registry import task_class

            self.episode_pool = task_class(self.task.name).episode_pool


def flat_overrides(tree: dict, prefix: str = "env") -> dict[str, Any]:
    """``{"task": {"scene": {"x": 1}}}`` -> ``{"env.task.scene.x": 1}``, in key order."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        if isinstance(v, dict) and v:
            out.update(flat_overrides(v, f"{prefix}.{k}"))
        else:
            out[f"{prefix}.{k}"] = v
    return out


def with_env_overrides(
    env_cfg: EnvConfig, overrides: dict, fixed: bool, where: str = "env"
) -> EnvConfig:
    """``env_cfg`` with ``overrides`` (nested field -> value) merged in and checked.

    Args:
        fixed: the task and the LiDAR beam count must stay (a policy's observation sizes).
        where: the overrides' name in error messages (``env``, ``train_env``).

    Raises:
        ConfigError: an unknown field or a bad value (naming ``<where>.<field>``), or a change
            of the task or beam count under ``fixed``.
    """
    if not overrides:
        return env_cfg

    def merge(base: Any, new: dict, where: str) -> dict:
        if not isinstance(base, dict):
            raise ConfigError(f"{where} is a value, not a group: set {where}=VALUE")
        out = dict(base)
        for k, v in new.items():
            out[k] = merge(out.get(k, {}), v, f"{where}.{k}") if isinstance(v, dict) else v
        return out

    task = overrides.get("task")
    name = task.get("name") if isinstance(task, dict) else None
    if fixed and name is not None and name != env_cfg.task.name:  # before its fields are mixed in
        raise ConfigError(f"{where}.task.name = {name!r}: the env's task is {env_cfg.task.name!r}")
    try:
        merged = build(EnvConfig, merge(asdict(env_cfg), overrides, where), "env")
    except ConfigError as e:  # build names fields env.*: name them as the user wrote them
        raise ConfigError(re.sub(r"\benv\.", f"{where}.", str(e), count=1)) from None
    if fixed and merged.lidar.num_beams != env_cfg.lidar.num_beams:
        raise ConfigError(
            f"{where}.lidar.num_beams = {merged.lidar.num_beams}: the env has "
            f"{env_cfg.lidar.num_beams} beams (the policy's input size)"
        )
    return merged
