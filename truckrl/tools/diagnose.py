"""``python -m truckrl.tools.diagnose``: where a ``uturn`` policy fails.

    python -m truckrl.tools.diagnose outputs/uturn3/checkpoints/last.pt --difficulty 4 --episodes 300

Runs the checkpoint's mean action on the scenes that ``python -m truckrl.evaluate
episodes=N seed=S`` scores and prints, per branch side and outcome, how many episodes pulled
past the branch, turned round, how deep the trailer got into the branch, and what the collided
trucks touched (:mod:`truckrl.tasks.uturn.diagnosis`). ``--output FILE`` also writes the rows as JSON.
Bad options print one line and exit with code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from truckrl.cli import OneLineArgParser, check_scene_options, run_or_fail


def parser() -> argparse.ArgumentParser:
    p = OneLineArgParser(
        prog="python -m truckrl.tools.diagnose", description=__doc__.split("\n")[0]
    )
    p.add_argument("checkpoint", help="a uturn checkpoint (file or run dir, or pretrained:NAME)")
    p.add_argument("--difficulty", type=float, help="default: the checkpoint's")
    p.add_argument("--episodes", type=int, default=300, help="held-out scenes (default 300)")
    p.add_argument("--seed", type=int, default=12345, help="scene seed (default 12345)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--output", help="JSON file for the rows")
    return p


def run(args: argparse.Namespace) -> list[dict]:
    from truckrl.config.fields import ConfigError

    check_scene_options(args)

    import torch

    from truckrl.rl.policy import load_policy
    from truckrl.tasks.uturn.diagnosis import diagnose_uturn, format_diagnosis, summarize_diagnosis

    torch.set_num_threads(args.threads)
    policy = load_policy(args.checkpoint)
    if policy.env_config.task.name != "uturn":
        raise ConfigError(
            f"checkpoint {args.checkpoint}: task {policy.env_config.task.name!r}; the diagnosis "
            "is for task 'uturn'"
        )
    difficulty = policy.difficulty if args.difficulty is None else args.difficulty
    d = diagnose_uturn(policy.actor, policy.env_config, difficulty, args.episodes, args.seed)
    rows = summarize_diagnosis(d)
    print(f"{policy.path}: {args.episodes} scenes (seed {args.seed}) at difficulty {difficulty:g}")
    print(format_diagnosis(rows))
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text(json.dumps(rows, indent=1))
    return rows


def main(argv: list[str] | None = None) -> int:
    return run_or_fail(run, parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
