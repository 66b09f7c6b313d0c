"""``truckrl tools paths``: draw where policies drive, side by side in the same scenes.

    truckrl tools paths checkpoints=[outputs/A,outputs/B] out=paths.png category="[route right]"

Runs each checkpoint's mean action on the scenes that ``truckrl eval episodes=N seed=S`` scores
(the same scenes for every checkpoint), picks ``count`` of them (those in every ``category`` that
the first checkpoint ends with ``outcome``), and writes a PNG: one row per checkpoint, one column
per scene, each the scene with the rear-axle trace and the tractor and trailer outlines every
``every`` steps (:mod:`truckrl.viz.paths`). A category is a row of the table ``truckrl eval``
prints, ``DIMENSION BIN`` (``route right``, ``turn [deg] right 110-180``): the task's bins
(:meth:`truckrl.tasks.Task.category_bins`). It prints each checkpoint's success on the chosen
scenes and the scene indices drawn. Bad input prints one line and exits with code 2.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from truckrl.config.fields import ConfigError, param, validate
from truckrl.tasks import MAX_DIFFICULTY

PROG = "truckrl tools paths"
ABOUT = "Draw where policies drive, side by side in the same held-out scenes, to a PNG."
OUTCOME_CHOICES = ("failed", "solved", "any")


@dataclass
class PathsConfig:
    """Which policies, which scenes, and where to draw them."""

    checkpoints: tuple[str, ...] = param((), min_len=0, doc="checkpoints (file, run dir or "
                                         "pretrained[:task]), one row each; required")  # fmt: skip
    out: str | None = param(None, doc="PNG file to write; required")
    episodes: int = param(1000, lo=1, hi=100_000, doc="held-out scenes")
    seed: int = param(12345, lo=0, hi=2**62, doc="scene seed (evaluate's by default)")
    difficulty: float | None = param(
        None, lo=0.0, hi=MAX_DIFFICULTY, doc="null: the first checkpoint's"
    )
    category: tuple[str, ...] = param(
        (), min_len=0, doc="scene categories 'DIMENSION BIN' as truckrl eval prints them; all"
    )
    outcome: str = param("failed", choices=OUTCOME_CHOICES, doc="by the first checkpoint")
    count: int = param(4, lo=1, hi=64, doc="scenes drawn")
    every: int = param(12, lo=1, hi=100_000, unit="steps", doc="between drawn outlines")
    labels: tuple[str, ...] | None = param(None, doc="one row label per checkpoint")
    threads: int = param(2, lo=1, hi=1024, doc="torch CPU threads")

    def __post_init__(self) -> None:
        for name in ("checkpoints", "category", "labels"):  # one value for a list of one
            if isinstance(getattr(self, name), str):
                setattr(self, name, (getattr(self, name),))
        validate(self)
        if not self.checkpoints:
            raise ConfigError("checkpoints is required: checkpoints=[RUN_DIR,...]")
        if not self.out or not self.out.lower().endswith(".png"):
            raise ConfigError(f"out = {self.out!r}: a PNG file to write (out=paths.png)")
        if self.labels is not None and len(self.labels) != len(self.checkpoints):
            raise ConfigError(
                f"labels: {len(self.labels)} given for {len(self.checkpoints)} checkpoints"
            )


def outcome_names(results: dict, episodes: list[int]) -> list[str]:
    """The outcome name (success, collision, jackknife or timeout) of each of ``episodes``."""
    from truckrl.tasks import OUTCOMES

    return [
        next((o.name for o in OUTCOMES if bool(results[o.flag][i])), "timeout") for i in episodes
    ]


def select(results: dict, task: str, categories: tuple[str, ...]):
    """Bool ``[E]``: the episodes in every one of ``categories`` (``"DIMENSION BIN"``) of the
    task's bins (:meth:`truckrl.tasks.Task.category_bins`) of ``results``' scene info."""
    import torch

    from truckrl.evaluation.categories import category_mask, task_bins

    keep = torch.ones_like(results["success"])
    return category_mask(task_bins(task, results) if categories else {}, categories, task, keep)


def run(cfg: PathsConfig) -> dict:
    import torch

    from truckrl.evaluation.rollout import evaluate_policy
    from truckrl.planning import held_out_states
    from truckrl.rl.policy import load_policy

    torch.set_num_threads(cfg.threads)
    policies = [load_policy(c) for c in cfg.checkpoints]
    difficulty = policies[0].difficulty if cfg.difficulty is None else cfg.difficulty
    starts, runs = [], []
    for pol in policies:
        starts.append(held_out_states(pol.env_config, cfg.episodes, cfg.seed, "cpu", difficulty))
        res, _, _ = evaluate_policy(
            pol.actor, pol.env_config, difficulty, cfg.episodes, cfg.seed, record_paths=True
        )
        runs.append(res)
    for c, s in zip(cfg.checkpoints[1:], starts[1:], strict=True):
        if not torch.equal(s["goal"], starts[0]["goal"]) or not torch.equal(
            s["segments"], starts[0]["segments"]
        ):
            raise ConfigError(
                f"{c}: its scenes for seed {cfg.seed} differ from {cfg.checkpoints[0]}'s "
                "(their scene or vehicle configs differ)"
            )
    tasks = [p.env_config.task.name for p in policies]
    chosen = select(runs[0], tasks[0], cfg.category)
    n = int(chosen.sum())
    if cfg.outcome != "any":
        chosen &= runs[0]["success"] if cfg.outcome == "solved" else ~runs[0]["success"]
    scenes = torch.nonzero(chosen).squeeze(-1)[: cfg.count].tolist()
    what = ", ".join(cfg.category) or "in all"
    print(f"{n} of {cfg.episodes} scenes (seed {cfg.seed}, difficulty {difficulty:g}) {what}:")
    labels = cfg.labels or [str(p.path) for p in policies]
    for label, res, task in zip(labels, runs, tasks, strict=True):
        in_cat = select(res, task, cfg.category)
        rate = res["success"][in_cat].float().mean().item() if n else float("nan")
        print(f"  {label}: success {100 * rate:.1f} %")
    if not scenes:
        raise ConfigError(
            f"no scene to draw: none of the {n} is {cfg.outcome} by {cfg.checkpoints[0]}"
        )
    print(f"drawn: scenes {scenes} ({cfg.outcome} by the first)")
    draw(cfg, labels, runs, starts, scenes)
    return {"scenes": scenes, "count_in_category": n}


def draw(cfg: PathsConfig, labels: list[str], runs: list, starts: list, scenes: list[int]):
    """Write the grid of ``scenes`` (columns) by checkpoints (rows) to ``cfg.out``."""
    from pathlib import Path

    import cv2

    from truckrl.viz.paths import draw_path, grid

    rows = []
    for label, res, start in zip(labels, runs, starts, strict=True):
        names = outcome_names(res, scenes)
        rows.append(
            [
                draw_path(start[i], res["path"][i], label=f"{label} #{i}: {name}", every=cfg.every)
                for i, name in zip(scenes, names, strict=True)
            ]
        )
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), grid(rows)[:, :, ::-1]):
        raise ConfigError(f"out = {cfg.out!r}: could not be written")
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(PathsConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)


if __name__ == "__main__":
    sys.exit(main())
