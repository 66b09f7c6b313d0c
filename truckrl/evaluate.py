"""``python -m truckrl.evaluate``: score a checkpoint on fixed seeded scenes with the mean action.

    python -m truckrl.evaluate checkpoint=outputs/2025-01-01/12-00-00 difficulty=2 episodes=200

Runs one deterministic episode in each of ``episodes`` scenes drawn from ``seed`` (the same seed
gives the same scenes, so checkpoints are compared on identical tasks) at ``difficulty`` (default:
the checkpoint's curriculum difficulty), with the env config saved in the checkpoint. Prints the
outcome rates and mean / p95 final errors, then the same per scene category (route, turn angle
split left / right, crossing angle, trailer length, road width, goal distance; see
:mod:`truckrl.agent.categories`), then everything as one line of JSON (the category rows under
``"categories"``), and writes that JSON to ``output``: by default
``<run dir of the checkpoint>/eval/<difficulty>-<seed>.json``, beside the evaluated run. The
output location is checked before any episode runs; if the write still fails at the end, the
results are printed first and the error after them. Fields: ``EvaluateConfig`` in
``truckrl/configs.py``.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig

from truckrl.cli import hydra_entry

if TYPE_CHECKING:
    from truckrl.configs import EvaluateConfig
    from truckrl.task import Quantity

#: Folder of a run dir that default evaluation outputs go to.
EVAL_DIR = "eval"


def default_output(checkpoint: Path, difficulty: float, seed: int) -> Path:
    """``<run dir>/eval/<difficulty>-<seed>.json`` (difficulty as ``2`` or ``2.5``)."""
    from truckrl.agent.session import run_dir_of

    return run_dir_of(checkpoint) / EVAL_DIR / f"{difficulty:g}-{seed}.json"


def check_writable(path: Path) -> None:
    """Create ``path``'s folder and a probe file in it, or raise :class:`ConfigError` (one line).

    The JSON is written by replacing ``path`` with a file made in the same folder, so a writable
    folder is what the final write needs.
    """
    from truckrl.sim.validation import ConfigError

    try:
        if path.is_dir():
            raise IsADirectoryError(21, "is a directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"):
            pass
    except OSError as e:
        raise ConfigError(f"output={path}: cannot write there ({e.strerror or e})") from None


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` atomically (a temporary file in the same folder, renamed)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(data, indent=2) + "\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def evaluate(ec: EvaluateConfig) -> dict:
    """Load, check the output, run, summarise, print and write; return the JSON-ready result.

    Raises:
        CheckpointError: the checkpoint cannot be used (before any episode runs).
        ConfigError: the output cannot be written: before any episode runs when the check finds
            it, or after printing the results when the final write fails.
    """
    from truckrl.agent.checkpoint import resolve_checkpoint

    resolve_checkpoint(ec.checkpoint)  # a wrong path is reported before torchrl loads

    from truckrl.agent.categories import episode_bins, format_category_table, summarize_by_category
    from truckrl.agent.policy import load_policy
    from truckrl.agent.rollout import evaluate_policy, summarize
    from truckrl.sim.scene import ROUTE_KEYS
    from truckrl.sim.validation import ConfigError

    policy = load_policy(ec.checkpoint, ec.device)
    difficulty = policy.difficulty if ec.difficulty is None else ec.difficulty
    output = Path(ec.output) if ec.output else default_output(policy.path, difficulty, ec.seed)
    check_writable(output)
    results, (tol_pos, tol_deg), errors = evaluate_policy(
        policy.actor, policy.env_config, difficulty, ec.episodes, ec.seed, ec.device
    )
    has_route = all(k in results for k in ROUTE_KEYS)
    summary = {
        "checkpoint": str(policy.path),
        "iteration": int(policy.counters["iteration"]),
        "frames": int(policy.counters["frames"]),
        "difficulty": difficulty,
        "tolerance_position_m": tol_pos,
        "tolerance_heading_deg": tol_deg,
        "seed": ec.seed,
        **summarize(results, errors),
        "categories": summarize_by_category(results, episode_bins(results)) if has_route else [],
    }
    print_table(summary, errors)
    print()
    if has_route:
        print("by scene category (bins [lo, hi); heading = tractor's):")
        print(format_category_table(summary["categories"]))
    else:
        print("no per-category table: this task's scenes record no route")
    print(json.dumps({**summary, "output": str(output)}))
    try:
        write_json(output, summary)
    except OSError as e:
        sys.stdout.flush()  # the results first, then the one-line error (stderr)
        raise ConfigError(
            f"output={output}: the results above were not written ({e.strerror or e})"
        ) from None
    return {**summary, "output": str(output)}


def print_table(s: dict, errors: tuple[Quantity, ...]) -> None:
    from truckrl.task import OUTCOMES

    print(
        f"{s['episodes']} episodes at difficulty {s['difficulty']} "
        f"(tolerance {s['tolerance_position_m']:.3g} m, {s['tolerance_heading_deg']:.3g} deg)"
    )
    print("  ".join(f"{o.name} {s[f'{o.name}_rate']:.3f}" for o in OUTCOMES))
    print(f"{'final error':<30}{'mean':>10}{'p95':>10}")
    for q in errors:
        key = f"{q.key}_{q.shown_unit}"
        print(f"{f'{q.key} [{q.shown_unit}]':<30}{s[f'{key}_mean']:>10.3f}{s[f'{key}_p95']:>10.3f}")


@hydra_entry("evaluate", "EvaluateConfig")
def main(ec: EvaluateConfig, raw: DictConfig) -> None:
    evaluate(ec)


if __name__ == "__main__":
    main()
