"""``truckrl tools diagnose``: where a policy fails, for a task whose folder has a diagnosis.

    truckrl tools diagnose checkpoint=outputs/RUN/checkpoints/last.pt difficulty=4 episodes=300

Runs the checkpoint's mean action on the scenes that ``truckrl eval episodes=N seed=S`` scores
and prints the rows of ``truckrl/tasks/<task>/diagnosis.py`` (the checkpoint's task): its
``diagnose``, ``summarize_diagnosis`` and ``format_diagnosis``.
``out=FILE`` also writes the rows as JSON. A task without a diagnosis, and any other bad input,
prints one line and exits with code 2.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from truckrl.config.fields import ConfigError, param, validate
from truckrl.tasks import MAX_DIFFICULTY

PROG = "truckrl tools diagnose"
ABOUT = "Where a policy fails: the diagnosis of its task (truckrl/tasks/<task>/diagnosis.py)."


@dataclass
class DiagnoseConfig:
    """Which policy on which scenes."""

    checkpoint: str | None = param(None, doc="checkpoint file, run dir or pretrained[:task]")
    difficulty: float | None = param(
        None, lo=0.0, hi=MAX_DIFFICULTY, doc="null: the checkpoint's curriculum difficulty"
    )
    episodes: int = param(300, lo=1, hi=100_000, doc="held-out scenes")
    seed: int = param(12345, lo=0, hi=2**62, doc="scene seed (evaluate's by default)")
    threads: int = param(1, lo=1, hi=1024, doc="torch CPU threads")
    out: str | None = param(None, doc="JSON file for the rows; null: none")

    def __post_init__(self) -> None:
        validate(self)
        if not self.checkpoint:
            raise ConfigError("checkpoint is required: checkpoint=<file, run dir or pretrained>")


#: What a task folder's ``diagnosis.py`` provides: ``diagnose(actor, env_cfg, difficulty, episodes,
#: seed) -> {key: [E] tensor}``, ``summarize_diagnosis(d) -> rows`` and ``format_diagnosis(rows)``.
CONTRACT = ("diagnose", "summarize_diagnosis", "format_diagnosis")


def diagnosis_module(task: str, checkpoint: str):
    """``<task package>.diagnosis``, which provides :data:`CONTRACT`.

    Raises:
        ConfigError: the task has no diagnosis module, or it lacks a function of the contract.
    """
    import importlib

    from truckrl.tasks.registry import task_package

    name = f"{task_package(task)}.diagnosis"
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name is None or not name.startswith(e.name):
            raise  # the module exists but something it imports is missing
        raise ConfigError(
            f"checkpoint = {checkpoint!r}: its task {task!r} has no diagnosis ({name})"
        ) from None
    missing = [f for f in CONTRACT if not callable(getattr(module, f, None))]
    if missing:
        lacks = ", ".join(f"{f}()" for f in missing)
        raise ConfigError(f"{name} lacks {lacks} (a diagnosis provides {', '.join(CONTRACT)})")
    return module


def run(cfg: DiagnoseConfig) -> list[dict]:
    import json
    from pathlib import Path

    import torch

    from truckrl.rl.policy import load_policy

    torch.set_num_threads(cfg.threads)
    policy = load_policy(cfg.checkpoint)
    task = policy.env_config.task.name
    module = diagnosis_module(task, cfg.checkpoint)
    difficulty = policy.difficulty if cfg.difficulty is None else cfg.difficulty
    d = module.diagnose(policy.actor, policy.env_config, difficulty, cfg.episodes, cfg.seed)
    rows = module.summarize_diagnosis(d)
    print(f"{policy.path}: {cfg.episodes} scenes (seed {cfg.seed}) at difficulty {difficulty:g}")
    print(module.format_diagnosis(rows))
    if cfg.out:
        Path(cfg.out).parent.mkdir(parents=True, exist_ok=True)
        Path(cfg.out).write_text(json.dumps(rows, indent=1))
    return rows


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(DiagnoseConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)


if __name__ == "__main__":
    sys.exit(main())
