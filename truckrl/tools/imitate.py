"""``python -m truckrl.tools.imitate``: a PPO start cloned from planner demonstrations.

    python -m truckrl.plan --episodes 600 --seed 99991 --difficulty 4 --output demos.json
    python -m truckrl.tools.imitate demos.json --out outputs/bc
    python -m truckrl.train resume=outputs/bc

Rebuilds the scenes of a ``python -m truckrl.plan`` JSON (its ``episodes``, ``seed`` and env
config), replays its successful action sequences, fits the training config's actor to them
(:mod:`truckrl.rl.imitation`) and writes ``<out>/checkpoints/last.pt``: a training checkpoint at
iteration 0 (the curriculum at its start, a fresh optimizer) with the train config composed from
``OVERRIDE``s like ``python -m truckrl.train`` would, so that ``train resume=<out>`` continues it
as a run of its own. ``python -m truckrl.train demos.episodes=N`` (the default experiment) does
all of this inside the run. The plan must have been made with the same env config as the training
(apart from ``compile`` and the reward weights). Use a seed that no evaluation uses: the held-out
seeds are ``evaluate``'s 12345 and training's own (``truckrl/evaluation/heldout.py``). Bad options
print one line and exit with code 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from datetime import datetime
from pathlib import Path

from truckrl.cli import OneLineArgParser, run_or_fail
from truckrl.config.schemas import DemosConfig

_DEMOS = DemosConfig()  # the defaults that `train demos.episodes=N` clones with too
#: Options: (default, low, high, help).
NUMERIC = {
    "epochs": (_DEMOS.epochs, 1, 100_000, "passes over the demonstration samples"),
    "lr": (_DEMOS.lr, 1e-7, 1.0, "Adam learning rate"),
    "batch_size": (_DEMOS.batch_size, 1, 10_000_000, "samples per minibatch"),
    "std": (_DEMOS.std, 1e-3, 10.0, "policy std set after cloning [action units]"),
    "threads": (2, 1, 1024, "torch CPU threads"),
}


def parser() -> argparse.ArgumentParser:
    p = OneLineArgParser(
        prog="python -m truckrl.tools.imitate",
        description="Clone planner demonstrations into a training checkpoint that "
        "`python -m truckrl.train resume=<out>` continues.",
    )
    p.add_argument("plan", help="JSON written by python -m truckrl.plan")
    p.add_argument("overrides", nargs="*", help="train config overrides (KEY=VALUE), as for train")
    for name, (default, lo, hi, text) in NUMERIC.items():
        kind = int if isinstance(default, int) else float
        p.add_argument(f"--{name.replace('_', '-')}", type=kind, default=default,
                       help=f"{text} (default {default:g}, {lo:g} .. {hi:g})")  # fmt: skip
    p.add_argument("--out", help="run dir to create (default outputs/imitate/<date>/<time>)")
    return p


def run(args: argparse.Namespace) -> Path:
    from truckrl.config.fields import ConfigError

    for name, (_, lo, hi, _) in NUMERIC.items():
        value = getattr(args, name)
        if not lo <= value <= hi:
            raise ConfigError(f"--{name.replace('_', '-')} = {value:g} must be in [{lo:g}, {hi:g}]")
    try:
        plan = json.loads(Path(args.plan).read_text())
        meta = {k: plan[k] for k in ("episodes", "seed", "difficulty", "env", "per_episode")}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"plan {args.plan}: not a python -m truckrl.plan JSON ({e})") from None
    out = Path(args.out or f"outputs/imitate/{datetime.now():%Y-%m-%d/%H-%M-%S}")
    if (out / "checkpoints" / "last.pt").exists():
        raise ConfigError(f"--out {out} already holds a checkpoint: choose another dir")

    import torch
    import yaml

    from truckrl.cli import compose_config, git_revision
    from truckrl.config.schemas import TrainConfig
    from truckrl.planning.planner import held_out_states
    from truckrl.rl.checkpoint import save_training_state
    from truckrl.rl.curriculum import Curriculum
    from truckrl.rl.imitation import (
        SAMPLES_NAME,
        behaviour_clone,
        demonstrations,
        plan_demos,
        save_samples,
        set_action_std,
    )
    from truckrl.rl.network import make_actor_critic
    from truckrl.rl.ppo import PPO

    tc = compose_config("train", TrainConfig, args.overrides)
    # as stored; the reward weights do not change what a plan does (the planner has its own cost),
    # nor does the LiDAR (a plan is actions from start states; the samples' scans are replayed
    # with this run's sensor, so a plan from the paper's 16 beams serves the default run's 32)
    mine = json.loads(json.dumps({**dataclasses.asdict(tc.env), "compile": None, "lidar": None}))
    theirs = {**meta["env"], "compile": None, "lidar": None}
    for cfg in (mine, theirs):
        if isinstance(cfg.get("task"), dict):
            cfg["task"] = {k: v for k, v in cfg["task"].items() if k != "reward"}
    if mine != theirs:
        diff = sorted(k for k in mine if mine[k] != theirs.get(k))
        raise ConfigError(
            f"plan {args.plan} was made with another env config (env.{', env.'.join(diff)}); "
            "plan with the training's env settings"
        )
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    index, actions = plan_demos(plan)
    if not index:
        raise ConfigError(f"plan {args.plan} has no successful episode to learn from")
    states = held_out_states(tc.env, int(meta["episodes"]), int(meta["seed"]))[torch.tensor(index)]
    samples, kept = demonstrations(tc.env, states, actions, float(meta["difficulty"]))
    print(f"{kept} of {len(index)} successful plans replayed to success: {samples.numel()} samples")
    torch.manual_seed(tc.seed)
    ac = make_actor_critic(tc.model, samples["observation"].shape[1], samples["lidar"].shape[1])
    losses = behaviour_clone(ac, samples, args.epochs, args.lr, args.batch_size, seed=tc.seed)
    set_action_std(ac, args.std)
    print(
        f"behaviour cloning: {args.epochs} epochs, action MSE {losses[0]:.4f} -> {losses[-1]:.4f}"
    )
    ckpt = save_training_state(
        out / "checkpoints" / "last.pt",
        model=ac.model,
        ppo=PPO(ac, tc.ppo),
        curriculum=Curriculum(tc.curriculum),
        counters={"iteration": 0, "frames": 0, "wall_time_s": 0.0},
        config_yaml=yaml.safe_dump(dataclasses.asdict(tc), sort_keys=False),
        num_obs=samples["observation"].shape[1],
        num_beams=samples["lidar"].shape[1],
        source=git_revision(),
    )
    save_samples(out / SAMPLES_NAME, samples)  # for train resume=<out> with demos.bc_coeff > 0
    (out / "imitation.json").write_text(
        json.dumps(
            {"plan": str(args.plan), "plans_kept": kept, "samples": samples.numel(),
             "epochs": args.epochs, "lr": args.lr, "batch_size": args.batch_size,
             "std": args.std, "losses": losses, "seconds": time.perf_counter() - t0},
            indent=2,
        ) + "\n"
    )  # fmt: skip
    print(f"checkpoint: {ckpt}\ntrain: python -m truckrl.train resume={out}")
    return out


def main(argv: list[str] | None = None) -> None:
    if run_or_fail(run, parser().parse_args(argv)):
        sys.exit(2)


if __name__ == "__main__":
    main()
