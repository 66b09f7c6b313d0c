"""``python -m truckrl.evaluate``: score a checkpoint on fixed seeded scenes with the mean action.

    python -m truckrl.evaluate checkpoint=outputs/2025-01-01/12-00-00 difficulty=2 episodes=200

Runs one deterministic episode in each of ``episodes`` scenes drawn from ``seed`` (the same seed
gives the same scenes, so checkpoints are compared on identical tasks) at ``difficulty`` (default:
the checkpoint's curriculum difficulty), with the env config saved in the checkpoint. Prints the
outcome rates and mean / p95 final errors as a table and as JSON on stdout, and writes the JSON to
``output`` (default ``<hydra run dir>/eval.json``). Fields: ``EvaluateConfig`` in
``truckrl/configs.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from truckrl.agent.policy import load_policy
from truckrl.agent.rollout import evaluate_policy, summarize
from truckrl.cli import hydra_entry
from truckrl.configs import EvaluateConfig
from truckrl.task import OUTCOMES, Quantity


def evaluate(ec: EvaluateConfig, out_dir: Path) -> dict:
    """Load, run and summarise; return the JSON-ready result."""
    policy = load_policy(ec.checkpoint, ec.device)
    difficulty = policy.difficulty if ec.difficulty is None else ec.difficulty
    results, (tol_pos, tol_deg), errors = evaluate_policy(
        policy.actor, policy.env_config, difficulty, ec.episodes, ec.seed, ec.device
    )
    summary = {
        "checkpoint": str(policy.path),
        "iteration": int(policy.counters["iteration"]),
        "frames": int(policy.counters["frames"]),
        "difficulty": difficulty,
        "tolerance_position_m": tol_pos,
        "tolerance_heading_deg": tol_deg,
        "seed": ec.seed,
        **summarize(results, errors),
    }
    output = Path(ec.output) if ec.output else out_dir / "eval.json"
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(summary, indent=2) + "\n")
    summary["output"] = str(output)
    print_table(summary, errors)
    return summary


def print_table(s: dict, errors: tuple[Quantity, ...]) -> None:
    print(
        f"{s['episodes']} episodes at difficulty {s['difficulty']} "
        f"(tolerance {s['tolerance_position_m']:.3g} m, {s['tolerance_heading_deg']:.3g} deg)"
    )
    print("  ".join(f"{o.name} {s[f'{o.name}_rate']:.3f}" for o in OUTCOMES))
    print(f"{'final error':<30}{'mean':>10}{'p95':>10}")
    for q in errors:
        key = f"{q.key}_{q.shown_unit}"
        print(f"{f'{q.key} [{q.shown_unit}]':<30}{s[f'{key}_mean']:>10.3f}{s[f'{key}_p95']:>10.3f}")


@hydra_entry("evaluate", EvaluateConfig)
def main(ec: EvaluateConfig, raw: DictConfig) -> None:
    summary = evaluate(ec, Path(HydraConfig.get().runtime.output_dir))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
