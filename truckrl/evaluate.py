"""``python -m truckrl.evaluate``: score a checkpoint on fixed seeded scenes with the mean action.

    python -m truckrl.evaluate checkpoint=outputs/2025-01-01/12-00-00 difficulty=2 episodes=200

Runs one deterministic episode in each of ``episodes`` scenes drawn from ``seed`` (the same seed
gives the same scenes, so checkpoints are compared on identical tasks) at ``difficulty`` (default:
the checkpoint's curriculum difficulty), with the env and control config saved in the checkpoint.
Prints success/collision/jack-knife/timeout rates and mean / p95 final errors (position [m],
tractor and trailer heading [deg]) as a table and as JSON on stdout, and writes the JSON to
``output`` (default ``<hydra run dir>/eval.json``). Config: ``conf/evaluate.yaml``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from truckrl.agent.checkpoint import CheckpointError
from truckrl.agent.policy import load_policy
from truckrl.agent.rollout import evaluate_policy, summarize
from truckrl.sim.validation import ConfigError, check_range

CONFIG_PATH = str(Path(__file__).resolve().parent.parent / "conf")


def evaluate(cfg: DictConfig, out_dir: Path) -> dict:
    """Load, run and summarise; return the JSON-ready result."""
    if cfg.checkpoint is None or str(cfg.checkpoint) == "":
        raise ConfigError("checkpoint is required: checkpoint=<file or run dir>")
    check_range("episodes", cfg.episodes, 1, 1e7)
    check_range("seed", cfg.seed, 0, 2**62)
    policy = load_policy(cfg.checkpoint, cfg.device)
    difficulty = policy.difficulty if cfg.difficulty is None else float(cfg.difficulty)
    check_range("difficulty", difficulty, 0.0, 30.0)

    results, (tol_pos, tol_deg) = evaluate_policy(
        policy.actor, policy.env_config, difficulty, int(cfg.episodes), int(cfg.seed), cfg.device
    )
    summary = {
        "checkpoint": str(policy.path),
        "iteration": int(policy.counters["iteration"]),
        "frames": int(policy.counters["frames"]),
        "difficulty": difficulty,
        "tolerance_position_m": tol_pos,
        "tolerance_heading_deg": tol_deg,
        "seed": int(cfg.seed),
        **summarize(results),
    }
    output = Path(cfg.output) if cfg.output else out_dir / "eval.json"
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(summary, indent=2) + "\n")
    summary["output"] = str(output)
    return summary


def print_table(s: dict) -> None:
    print(
        f"{s['episodes']} episodes at difficulty {s['difficulty']} "
        f"(tolerance {s['tolerance_position_m']:.3g} m, {s['tolerance_heading_deg']:.3g} deg)"
    )
    print(
        f"success {s['success_rate']:.3f}  collision {s['collision_rate']:.3f}  "
        f"jackknife {s['jackknife_rate']:.3f}  timeout {s['timeout_rate']:.3f}"
    )
    print(f"{'final error':<30}{'mean':>10}{'p95':>10}")
    for k, unit in (
        ("pos_error", "m"),
        ("tractor_heading_error", "deg"),
        ("trailer_heading_error", "deg"),
    ):
        name = f"{k} [{unit}]"
        print(f"{name:<30}{s[f'{k}_{unit}_mean']:>10.3f}{s[f'{k}_{unit}_p95']:>10.3f}")


@hydra.main(version_base=None, config_path=CONFIG_PATH, config_name="evaluate")
def main(cfg: DictConfig) -> None:
    try:
        summary = evaluate(cfg, Path(HydraConfig.get().runtime.output_dir))
    except (ConfigError, CheckpointError) as e:
        print(f"{type(e).__name__}: {e}", file=sys.stderr)
        sys.exit(2)
    print_table(summary)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
