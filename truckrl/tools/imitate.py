"""``truckrl tools imitate``: a PPO start cloned from planner demonstrations.

    truckrl plan episodes=600 seed=99991 difficulty=4 out=demos.json
    truckrl tools imitate plan=demos.json out=outputs/bc
    truckrl train resume=outputs/bc

Rebuilds the scenes of a ``truckrl plan`` JSON (its ``episodes``, ``seed`` and env config),
replays its successful action sequences, fits the training config's actor to them
(:mod:`truckrl.rl.imitation`) and writes ``<out>/checkpoints/last.pt``: a training checkpoint at
iteration 0 (the curriculum at its start, a fresh optimizer) with the train config composed from
``train.KEY=VALUE`` overrides like ``truckrl train KEY=VALUE`` would, so that ``train
resume=<out>`` continues it as a run of its own. ``init=CHECKPOINT`` clones into that
checkpoint's weights instead of a fresh actor-critic (``std=null`` keeps its std; ``epochs=0``
leaves the weights as they are, since a few Adam steps at the cloning rate can break a trained
policy): with
``train.demos.bc_coeff > 0`` the resumed run is a fine-tune that keeps cloning the plan, for
example the planner's solutions of the scenes a policy fails (``truckrl plan checkpoint=
skip_solved=true``, which writes those sequences only). ``truckrl train demos.episodes=N`` (the default
experiment) does all of this inside the run. The plan must have been made with the same env
config as the training (apart from ``compile`` and the reward weights). Use a seed that no
evaluation uses: the held-out seeds are ``eval``'s 12345 and training's own
(``truckrl/evaluation/heldout.py``). Bad input prints one line and exits with code 2.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from truckrl.config.fields import ConfigError, param, validate
from truckrl.config.schemas import DemosConfig

PROG = "truckrl tools imitate"
ABOUT = "Clone planner demonstrations into a training checkpoint that `truckrl train resume=<out>` continues."
_DEMOS = DemosConfig()  # the defaults that `train demos.episodes=N` clones with too


@dataclass
class ImitateConfig:
    """The plan to learn from, the cloning, and where the checkpoint goes."""

    plan: str | None = param(None, doc="JSON written by truckrl plan; required")
    out: str | None = param(None, doc="run dir to create; null: outputs/imitate/<date>/<time>")
    epochs: int = param(
        _DEMOS.epochs,
        lo=0,
        hi=100_000,
        doc="passes over the demonstration samples (0: none, for init=: the weights as they "
        "are, the samples kept for the resumed run's cloning term)",
    )
    lr: float = param(_DEMOS.lr, lo=1e-7, hi=1.0, doc="Adam learning rate")
    batch_size: int = param(_DEMOS.batch_size, lo=1, hi=10_000_000, doc="samples per minibatch")
    std: float | None = param(
        _DEMOS.std,
        lo=1e-3,
        hi=10.0,
        unit="action units",
        doc="policy std set after cloning (null: the start's, within model.max_std)",
    )
    init: str | None = param(
        None,
        doc="start from this checkpoint's weights (run dir, .pt file, pretrained[:TASK]) "
        "instead of a fresh actor-critic: the clone as a fine-tune",
    )
    threads: int = param(2, lo=1, hi=1024, doc="torch CPU threads")
    train: dict[str, Any] = param(
        {}, doc="train config overrides, as for truckrl train (train.experiment=fast)"
    )

    def __post_init__(self) -> None:
        validate(self)
        if not self.plan:
            raise ConfigError("plan is required: plan=<JSON written by truckrl plan>")
        if self.epochs == 0 and not self.init:
            raise ConfigError("epochs = 0 needs init= (without it the weights are untrained)")


def run(args: ImitateConfig, overrides: list[str]) -> Path:
    """Clone ``args.plan`` into a checkpoint under ``args.out``; ``overrides``: the train config's
    (``train.KEY=VALUE`` without ``train.``, as written)."""
    plan, meta = _read_plan(args.plan)
    out = Path(args.out or f"outputs/imitate/{datetime.now():%Y-%m-%d/%H-%M-%S}")
    if (out / "checkpoints" / "last.pt").exists():
        raise ConfigError(f"out = {str(out)!r} already holds a checkpoint: choose another dir")

    import torch

    from truckrl.cli import compose_config
    from truckrl.config.schemas import TrainConfig

    tc = compose_config("train", TrainConfig, overrides)
    _check_env_config(args.plan, tc, meta["env"])
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    ac, samples, kept, losses = _clone(args, tc, plan, meta)
    ckpt = _write_run(out, tc, ac, samples)
    (out / "imitation.json").write_text(
        json.dumps(
            {"plan": str(args.plan), "plans_kept": kept, "samples": samples.numel(),
             "epochs": args.epochs, "lr": args.lr, "batch_size": args.batch_size,
             "std": args.std, "losses": losses, "seconds": time.perf_counter() - t0},
            indent=2,
        ) + "\n"
    )  # fmt: skip
    print(f"checkpoint: {ckpt}\ntrain: truckrl train resume={out}")
    return out


def _read_plan(path: str) -> tuple[dict, dict]:
    """The ``truckrl plan`` JSON at ``path`` and its ``episodes``, ``seed``, ``difficulty``,
    ``env`` and ``per_episode`` entries; anything else is a :class:`ConfigError`."""
    try:
        plan = json.loads(Path(path).read_text())
        meta = {k: plan[k] for k in ("episodes", "seed", "difficulty", "env", "per_episode")}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"plan {path}: not a truckrl plan JSON ({e})") from None
    return plan, meta


def _check_env_config(plan_path: str, tc: Any, plan_env: dict) -> None:
    """Raise a :class:`ConfigError` naming the differing ``env.`` keys when the plan's env config
    (``plan_env``, as stored in the JSON) is not the training's, ``compile``, ``lidar`` and the
    task's reward weights aside."""
    # as stored; the reward weights do not change what a plan does (the planner has its own cost),
    # nor does the LiDAR (a plan is actions from start states; the samples' scans are replayed
    # with this run's sensor, so a plan from the paper's 16 beams serves the default run's 32)
    mine = json.loads(json.dumps({**dataclasses.asdict(tc.env), "compile": None, "lidar": None}))
    theirs = {**plan_env, "compile": None, "lidar": None}
    for cfg in (mine, theirs):
        if isinstance(cfg.get("task"), dict):
            cfg["task"] = {k: v for k, v in cfg["task"].items() if k != "reward"}
    if mine != theirs:
        diff = sorted(k for k in mine if mine[k] != theirs.get(k))
        raise ConfigError(
            f"plan {plan_path} was made with another env config (env.{', env.'.join(diff)}); "
            "plan with the training's env settings"
        )


def _clone(args: ImitateConfig, tc: Any, plan: dict, meta: dict) -> tuple[Any, Any, int, list]:
    """Replay the plan's successful episodes on their rebuilt start states, then fit a fresh
    actor-critic (seeded by ``tc.seed``) to the replayed samples and set its action std.
    Returns the actor-critic, the samples (flat TensorDict: ``observation`` [S, F], ``lidar``
    [S, R], ``action``), how many plans replayed to success, and the per-epoch action MSE."""
    import torch

    from truckrl.planning import held_out_states
    from truckrl.rl.imitation import behaviour_clone, demonstrations, plan_demos, set_action_std
    from truckrl.rl.network import make_actor_critic

    index, actions = plan_demos(plan)
    if not index:
        raise ConfigError(f"plan {args.plan} has no successful episode to learn from")
    # the scenes as the plan saw them: a task with a start curriculum (uturn, network) places
    # its starts by the difficulty
    difficulty = float(meta["difficulty"])
    states = held_out_states(tc.env, int(meta["episodes"]), int(meta["seed"]), "cpu", difficulty)
    samples, kept = demonstrations(tc.env, states[torch.tensor(index)], actions, difficulty)
    n = int(samples.batch_size[0])
    print(f"{kept} of {len(index)} successful plans replayed to success: {n} samples")
    if kept == 0:
        raise ConfigError(
            f"plan {args.plan}: none of its {len(index)} successful plans replays to success "
            "with this training's env config (plan with its env settings)"
        )
    torch.manual_seed(tc.seed)
    num_obs, num_beams = samples["observation"].shape[1], samples["lidar"].shape[1]
    ac = make_actor_critic(tc.model, num_obs, num_beams)
    if args.init:
        _load_start(args.init, ac, num_obs, num_beams)
    executed = tc.demos.bc_loss == "executed"  # as the resumed run's cloning term
    losses = []
    if args.epochs:
        losses = behaviour_clone(
            ac, samples, args.epochs, args.lr, args.batch_size, tc.seed, executed
        )
    if args.std is not None:
        set_action_std(ac, args.std)
    if losses:
        print(f"behaviour cloning: {args.epochs} epochs, action MSE {losses[0]:.4f} -> "
              f"{losses[-1]:.4f}")  # fmt: skip
    else:
        print(f"no cloning before training: the weights of {args.init}")
    return ac, samples, kept, losses


def _load_start(init: str, ac: Any, num_obs: int, num_beams: int) -> None:
    """``init``'s network weights into ``ac`` (as ``train init=``; the log-std clamped to this
    config's ``model.max_std``); a checkpoint that does not fit is a :class:`ConfigError`."""
    from truckrl.rl import checkpoint as ckpt

    try:
        ckpt.load_init_weights(ckpt.load_training_state(init), ac.model, num_obs, num_beams)
    except ckpt.CheckpointError as e:
        raise ConfigError(f"init = {init!r}: {e}") from None
    import torch

    with torch.no_grad():
        ac.gaussian.project_()


def _write_run(out: Path, tc: Any, ac: Any, samples: Any) -> Path:
    """Write ``<out>/checkpoints/last.pt`` (iteration 0: curriculum at its start, fresh
    optimizer, the composed train config) and the samples; returns the checkpoint path."""
    import yaml

    from truckrl.cli import git_revision
    from truckrl.rl.checkpoint import save_training_state
    from truckrl.rl.curriculum import Curriculum
    from truckrl.rl.imitation import SAMPLES_NAME, save_samples
    from truckrl.rl.ppo import PPO

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
    return ckpt


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    argv = sys.argv[1:] if argv is None else list(argv)
    cfg = key_value_config(ImitateConfig, argv, PROG, ABOUT)
    # the train overrides as written (Hydra parses them; YAML would reformat their values)
    overrides = [a.removeprefix("train.") for a in argv if a.startswith("train.")]
    return run_or_fail(lambda c: run(c, overrides), cfg)


if __name__ == "__main__":
    sys.exit(main())
