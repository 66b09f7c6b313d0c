"""``truckrl tools scenes``: random scenes of a task, with the truck at its start pose and the
goal, as a PNG grid (:func:`truckrl.viz.scenes.render_grid`).

    truckrl tools scenes count=4 seed=0 out=docs/scenes.png
    truckrl tools scenes task=NAME env.max_steps=300 out=scenes.png

The scenes are the task's own (:meth:`truckrl.tasks.Task.sample`) with the env config's
defaults, changed by ``env.FIELD=VALUE``. Bad input prints one line and exits with code 2.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

from truckrl.config.fields import ConfigError, param, validate
from truckrl.tasks.config import DEFAULT_TASK

PROG = "truckrl tools scenes"
ABOUT = "Render random scenes of a task (truck at its start pose, goal) to a PNG grid."


@dataclass
class ScenesConfig:
    """What to draw and where."""

    task: str = param(DEFAULT_TASK, doc="task folder under truckrl/tasks/ (or a dotted package)")
    count: int = param(4, lo=1, hi=1024, doc="scenes drawn")
    seed: int = param(0, lo=0, hi=2**62, doc="generator seed: same seed, same scenes")
    out: str = param("scenes.png", doc="PNG file to write")
    cols: int = param(2, lo=1, hi=64, doc="tiles per row")
    tile: int = param(400, lo=16, hi=4096, unit="px", doc="tile side")
    half_extent: float = param(50.0, lo=0.0, hi=1e4, lo_open=True, unit="m", doc="view half-extent")
    device: str = param("cpu", doc="torch device the scenes are sampled on")
    env: dict[str, Any] = param({}, doc="env config fields, e.g. env.max_steps=300")

    def __post_init__(self) -> None:
        validate(self)
        if not self.out.lower().endswith(".png"):
            raise ConfigError(f"out = {self.out!r} must end in .png")


def run(cfg: ScenesConfig) -> None:
    from pathlib import Path

    import cv2
    import torch

    from truckrl.config.fields import build
    from truckrl.config.schemas import check_device
    from truckrl.tasks import EnvConfig, make_task
    from truckrl.viz.scenes import render_grid

    check_device("device", cfg.device)
    env = dict(cfg.env)
    env["task"] = {**dict(env.get("task") or {}), "name": cfg.task}
    env_cfg = build(EnvConfig, env, "env")
    device = torch.device(cfg.device)
    task = make_task(env_cfg).to(device)
    state = task.sample(cfg.count, torch.Generator(device=device).manual_seed(cfg.seed), device)
    grid = render_grid(
        state,
        cols=min(cfg.cols, cfg.count),
        tile_px=cfg.tile,
        view_half_extent=cfg.half_extent,
        title=env_cfg.task.name,
    )
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR)):
        raise ConfigError(f"out = {cfg.out!r}: could not be written")
    print(f"wrote {out} ({cfg.count} scenes of task {env_cfg.task.name}, seed {cfg.seed})")


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(ScenesConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)


if __name__ == "__main__":
    sys.exit(main())
