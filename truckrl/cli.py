"""What every Hydra entry point shares: the config path, validation before any work, the
one-line error with exit code 2, seeding and the run's provenance.

Usage in an entry point::

    @hydra_entry("train", TrainConfig)
    def main(cfg: TrainConfig, raw: DictConfig) -> None: ...
"""

from __future__ import annotations

import functools
import random
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import hydra
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from truckrl.agent.checkpoint import CheckpointError
from truckrl.configs import register
from truckrl.sim.validation import ConfigError, build

CONFIG_PATH = str(Path(__file__).resolve().parent / "conf")  # package data: works installed too

T = TypeVar("T")


def to_config(schema: type[T], cfg: DictConfig | dict) -> T:
    """The composed Hydra config (or a plain dict) as a validated ``schema`` instance."""
    data = OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else dict(cfg)
    data.pop("hydra", None)
    return build(schema, data)


def hydra_entry(config_name: str, schema: type[T]) -> Callable:
    """Decorate ``fn(cfg: schema, raw: DictConfig)`` into a Hydra main with the shared handling.

    Bad config values and unusable checkpoints print one line (``error: ...``) and exit with
    code 2 before any work starts.
    """
    register()

    def decorate(fn: Callable[[T, DictConfig], Any]) -> Callable[[], None]:
        @hydra.main(version_base=None, config_path=CONFIG_PATH, config_name=config_name)
        @functools.wraps(fn)
        def main(raw: DictConfig) -> None:
            try:
                fn(to_config(schema, raw), raw)
            except (ConfigError, CheckpointError) as e:
                print(f"error: {e}", file=sys.stderr)
                sys.exit(2)

        return main

    return decorate


def seed_everything(seed: int) -> None:
    """Seed torch, numpy's global generator (third-party code draws from it) and ``random``."""
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002
    random.seed(seed)


def git_revision() -> dict[str, str | bool]:
    """The source's git commit and whether the work tree had changes (``{}`` outside git)."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():  # an installed copy: not this source tree's repository
        return {}

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"commit": commit, "dirty": dirty}
