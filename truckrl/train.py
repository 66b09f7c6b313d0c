"""``python -m truckrl.train``: PPO on TruckEnv with the success curriculum (the paper's setup).

Config: ``conf/train.yaml`` with the groups ``env``, ``control``, ``curriculum`` (paper | none),
``ppo`` (fast | paper: also sets the rollout shape ``collector.*`` and ``env.num_envs``) and
``model``. Examples::

    python -m truckrl.train                                # fast preset, paper curriculum
    python -m truckrl.train ppo=paper max_minutes=60       # the paper's PPO numbers
    python -m truckrl.train resume=outputs/2025-01-01/12-00-00   # continue a stopped run
    python -m truckrl.train -m ppo.lr=1e-4,3e-4            # sweep (outputs/multirun/...)
    python -m truckrl.train --cfg job                      # print the composed config

Each iteration collects ``collector.workers x env.num_envs x collector.steps_per_env`` frames,
feeds the finished episodes to the curriculum (a promotion is sent to every worker before the next
collection), runs the PPO update and logs to ``<run_dir>/tb``. Checkpoints go to
``<run_dir>/checkpoints/last.pt`` every ``checkpoint.interval`` iterations and at the end.

Resuming (``resume=<checkpoint or run dir>``) continues in the original run dir with the
checkpoint's model, optimizer, learning rate, curriculum, counters and RNG states, and with its
saved config except the keys in :data:`RESUME_OVERRIDES` (stopping criteria, logging, device),
which come from the command line. ``total_frames`` counts all sessions together; ``max_minutes``
limits this session. The environments restart with fresh episodes seeded from ``(seed,
iteration)``, so a resumed run is a faithful continuation but not bit-identical to an
uninterrupted one.
"""

from __future__ import annotations

import functools
import math
import random
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, ParallelEnv
from tqdm import tqdm

from truckrl.agent.checkpoint import (
    CHECKPOINT_DIR,
    CHECKPOINT_VERSION,
    LAST_NAME,
    CheckpointError,
    capture_rng,
    load_checkpoint,
    resolve_checkpoint,
    restore_rng,
    save_checkpoint,
)
from truckrl.agent.curriculum import Curriculum, CurriculumConfig
from truckrl.agent.metrics import EpisodeTracker, finished_in_time_order
from truckrl.agent.network import ModelConfig, make_actor_critic, parameter_count
from truckrl.agent.ppo import PPO, PPOConfig
from truckrl.agent.rollout import record_episode
from truckrl.agent.run_logger import RunLogger
from truckrl.env import EnvConfig, TruckEnv
from truckrl.sim.validation import ConfigError, check_range, from_mapping

CONFIG_PATH = str(Path(__file__).resolve().parent.parent / "conf")

#: Top-level keys a resumed run takes from the command line; all others come from the checkpoint.
RESUME_OVERRIDES = (
    "total_frames",
    "max_minutes",
    "stop_difficulty",
    "resume",
    "device",
    "log",
    "checkpoint",
)


# ---------------------------------------------------------------------------------- config
@dataclass(frozen=True)
class CollectorConfig:
    """Rollout shape: ``workers`` processes x ``env.num_envs`` trucks x ``steps_per_env`` steps."""

    workers: int = 1
    steps_per_env: int = 64

    def __post_init__(self) -> None:
        check_range("collector.workers", self.workers, 1, 4096)
        check_range("collector.steps_per_env", self.steps_per_env, 1, 1e6)


@dataclass(frozen=True)
class LogConfig:
    """TensorBoard and console output (``log.*``)."""

    interval: int = 1
    video_interval: int = 50
    video_steps: int = 200
    video_fps: float = 10.0
    progress_bar: bool = True

    def __post_init__(self) -> None:
        check_range("log.interval", self.interval, 1, 1e9)
        check_range("log.video_interval", self.video_interval, 0, 1e9)
        check_range("log.video_steps", self.video_steps, 1, 1e5)
        check_range("log.video_fps", self.video_fps, 0.0, 1000.0, lo_open=True)


@dataclass(frozen=True)
class CheckpointConfig:
    """Checkpoint cadence (``checkpoint.*``)."""

    interval: int = 10
    keep_every: int = 0

    def __post_init__(self) -> None:
        check_range("checkpoint.interval", self.interval, 1, 1e9)
        check_range("checkpoint.keep_every", self.keep_every, 0, 1e9)


@dataclass(frozen=True)
class TrainConfig:
    """The validated training config (built from the composed Hydra config)."""

    seed: int = 0
    device: str = "cpu"
    total_frames: int | None = None
    max_minutes: float | None = None
    stop_difficulty: float | None = None
    resume: str | None = None
    num_envs: int = 256
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    log: LogConfig = field(default_factory=LogConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    env: EnvConfig = field(default_factory=EnvConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)

    @property
    def frames_per_batch(self) -> int:
        return self.collector.workers * self.num_envs * self.collector.steps_per_env

    @classmethod
    def from_hydra(cls, cfg: DictConfig) -> TrainConfig:
        """Validate everything before any work starts; errors name the offending field."""
        c = OmegaConf.to_container(cfg, resolve=True)
        num_envs = c["env"].get("num_envs", 256)
        check_range("env.num_envs", num_envs, 1, 1e7)
        check_range("seed", c["seed"], 0, 2**62)
        if c.get("total_frames") is not None:
            check_range("total_frames", c["total_frames"], 1, 1e15)
        if c.get("max_minutes") is not None:
            check_range("max_minutes", c["max_minutes"], 0.0, 1e7, lo_open=True)
        if c.get("total_frames") is None and c.get("max_minutes") is None:
            raise ConfigError("set total_frames and/or max_minutes (both are null)")
        if c.get("stop_difficulty") is not None:
            check_range("stop_difficulty", c["stop_difficulty"], 0.0, 30.0)
        try:
            torch.device(c["device"])
        except (RuntimeError, TypeError):
            raise ConfigError(f"device = {c['device']!r} is not a torch device") from None
        tc = cls(
            seed=int(c["seed"]),
            device=str(c["device"]),
            total_frames=None if c.get("total_frames") is None else int(c["total_frames"]),
            max_minutes=c.get("max_minutes"),
            stop_difficulty=c.get("stop_difficulty"),
            resume=c.get("resume"),
            num_envs=int(num_envs),
            collector=from_mapping(CollectorConfig, c["collector"], "collector"),
            log=from_mapping(LogConfig, c["log"], "log"),
            checkpoint=from_mapping(CheckpointConfig, c["checkpoint"], "checkpoint"),
            env=EnvConfig.from_hydra(cfg.env, cfg.control),
            model=from_mapping(ModelConfig, c["model"], "model"),
            ppo=from_mapping(PPOConfig, c["ppo"], "ppo"),
            curriculum=from_mapping(CurriculumConfig, c["curriculum"], "curriculum"),
        )
        tc.ppo.check_batch(tc.frames_per_batch)
        return tc


def resumed_config(saved_yaml: str, current: DictConfig) -> DictConfig:
    """The checkpoint's config with :data:`RESUME_OVERRIDES` taken from ``current``."""
    saved = OmegaConf.create(saved_yaml)
    ignored = sorted(
        k
        for k in set(current.keys()) | set(saved.keys())
        if k not in RESUME_OVERRIDES and OmegaConf.select(current, k) != OmegaConf.select(saved, k)
    )
    if ignored:
        print(
            f"resume: keeping the checkpoint's {', '.join(ignored)} (differs from the command line)"
        )
    for k in RESUME_OVERRIDES:
        if k in current:
            saved[k] = current[k]
    return saved


# ---------------------------------------------------------------------------------- factories
def env_seed(seed: int, iteration: int, worker: int) -> int:
    """Independent, reproducible seed per (run seed, session start iteration, worker)."""
    return int(np.random.SeedSequence([seed, iteration, worker]).generate_state(1)[0])


def make_env(tc: TrainConfig, iteration: int) -> EnvBase:
    """One in-process TruckEnv (``workers=1``) or a ParallelEnv of batched TruckEnvs."""
    make = functools.partial(TruckEnv, num_envs=tc.num_envs, device=tc.device, config=tc.env)
    if tc.collector.workers == 1:
        return make(seed=env_seed(tc.seed, iteration, 0))
    fns = [
        functools.partial(make, seed=env_seed(tc.seed, iteration, w))
        for w in range(tc.collector.workers)
    ]
    env = ParallelEnv(tc.collector.workers, fns, device=tc.device)
    env.start()
    return env


def set_difficulty(env: EnvBase, difficulty: float) -> tuple[float, float]:
    """Send the difficulty to every worker; return the tolerances a worker now reports.

    Returns:
        ``(position [m], heading [deg])`` read back from the (first) environment.
    """
    env.set_difficulty(difficulty)
    tol = env.tolerances()
    pos, ang = tol[0] if isinstance(env, ParallelEnv) else tol
    return float(pos.reshape(-1)[0]), math.degrees(float(ang.reshape(-1)[0]))


# ---------------------------------------------------------------------------------- training
@dataclass
class Counters:
    iteration: int = 0
    frames: int = 0
    wall_time_s: float = 0.0


def checkpoint_state(
    ac, ppo: PPO, curriculum: Curriculum, counters: Counters, cfg_yaml: str, seed: int, spec
) -> dict[str, Any]:
    return {
        "version": CHECKPOINT_VERSION,
        "model": ac.model.state_dict(),
        "ppo": ppo.state_dict(),
        "curriculum": curriculum.state_dict(),
        "counters": vars(counters).copy(),
        "rng": capture_rng(),
        "env_seed": seed,
        "num_obs": spec[0],
        "num_beams": spec[1],
        "config": cfg_yaml,
    }


def train(cfg: DictConfig, run_dir: Path) -> Counters:
    """Run (or resume) one training job; return the final counters."""
    state = None
    if cfg.get("resume"):
        ckpt_path = resolve_checkpoint(cfg.resume)
        state = load_checkpoint(ckpt_path)
        cfg = resumed_config(state["config"], cfg)
        run_dir = (
            ckpt_path.parent.parent if ckpt_path.parent.name == CHECKPOINT_DIR else ckpt_path.parent
        )
    tc = TrainConfig.from_hydra(cfg)
    cfg_yaml = OmegaConf.to_yaml(cfg, resolve=True)
    counters = Counters(**state["counters"]) if state else Counters()
    if state:
        restore_rng(state["rng"])
    else:
        torch.manual_seed(tc.seed)
        np.random.seed(tc.seed)  # noqa: NPY002 (third-party code draws from the global generator)
        random.seed(tc.seed)

    # Create environment
    env = make_env(tc, counters.iteration)
    num_obs = env.observation_spec["observation"].shape[-1]
    num_beams = env.observation_spec["lidar"].shape[-1]

    # Create models
    ac = make_actor_critic(tc.model, num_obs, num_beams, env.action_spec.shape[-1])
    ac.model.to(tc.device)
    print(f"model: {parameter_count(ac.model):,} parameters ({num_beams} LiDAR beams)")

    # Create PPO (GAE, ClipPPOLoss, Adam, KL schedule) and curriculum
    ppo = PPO(ac, tc.ppo)
    curriculum = Curriculum(tc.curriculum)
    if state:
        ac.model.load_state_dict(state["model"])
        ppo.load_state_dict(state["ppo"])
        curriculum.load_state_dict(state["curriculum"])
        print(f"resumed {run_dir} at iteration {counters.iteration}, frames {counters.frames:,}")
    tolerance = set_difficulty(env, curriculum.difficulty)

    # Create collector
    collector = Collector(
        env,
        ac.actor,
        frames_per_batch=tc.frames_per_batch,
        total_frames=-1,
        device=tc.device,
        auto_register_policy_transforms=False,  # the policy is stateless: no InitTracker needed
    )

    # Create logger
    # steps up to the checkpoint's frame count were logged before it was written: keep them
    logger = RunLogger(run_dir, purge_step=counters.frames + 1 if state else None)
    if not state:
        logger.config(cfg_yaml, OmegaConf.to_container(cfg, resolve=True), hparam_metrics(0, 0))
    print(f"run dir: {run_dir}; batch {tc.frames_per_batch:,} frames/iteration")

    # Training loop
    tracker = EpisodeTracker()
    session_start = time.monotonic()
    wall_at_start = counters.wall_time_s
    video_ok = tc.log.video_interval > 0
    pbar = tqdm(
        total=tc.total_frames,
        initial=counters.frames,
        unit="frame",
        unit_scale=True,
        dynamic_ncols=True,
        disable=not tc.log.progress_bar,
    )

    def save(final: bool = False) -> None:
        counters.wall_time_s = wall_at_start + time.monotonic() - session_start
        st = checkpoint_state(
            ac, ppo, curriculum, counters, cfg_yaml, tc.seed, (num_obs, num_beams)
        )
        ckpt_dir = run_dir / CHECKPOINT_DIR
        save_checkpoint(ckpt_dir / LAST_NAME, st)
        keep = tc.checkpoint.keep_every
        if keep and (counters.iteration % keep == 0 or final):
            save_checkpoint(ckpt_dir / f"iter_{counters.iteration:06d}.pt", st)

    batches = iter(collector)
    finished = False  # a crash must not overwrite the last good checkpoint
    try:
        while not should_stop(tc, counters, curriculum, session_start):
            t0 = time.perf_counter()
            batch = next(batches)
            t1 = time.perf_counter()

            # Episode statistics and curriculum
            env_difficulty = batch["next", "difficulty"][..., -1, :]
            expected = torch.full_like(env_difficulty, curriculum.difficulty)
            if not torch.isclose(env_difficulty, expected).all():
                raise RuntimeError(
                    f"difficulty {curriculum.difficulty} did not reach every environment worker"
                )
            stats = tracker.update(batch)
            promoted = curriculum.update(
                finished_in_time_order(batch, "success"),
                finished_in_time_order(batch, "difficulty"),
            )
            if promoted:
                tolerance = set_difficulty(env, curriculum.difficulty)

            # PPO update
            learn = ppo.update(batch)
            collector.update_policy_weights_()
            t2 = time.perf_counter()

            frames = batch.numel()
            counters.iteration += 1
            counters.frames += frames
            counters.wall_time_s = wall_at_start + time.monotonic() - session_start
            timing = {
                "perf/fps": frames / (t2 - t0),
                "perf/fps_collect": frames / (t1 - t0),
                "perf/collect_s": t1 - t0,
                "perf/learn_s": t2 - t1,
            }
            if counters.iteration % tc.log.interval == 0 or promoted:
                logger.scalars(
                    iteration_scalars(stats, learn, curriculum, tolerance, timing),
                    counters.frames,
                )
            pbar.update(frames)
            pbar.set_postfix(
                fps=f"{timing['perf/fps']:.0f}",
                diff=curriculum.difficulty,
                ema=f"{curriculum.ema:.2f}",
                succ=f"{stats['success_rate'].item():.2f}",
                refresh=False,
            )
            if video_ok and counters.iteration % tc.log.video_interval == 0:
                video_ok = log_video(logger, ac, tc, curriculum.difficulty, counters)
            if counters.iteration % tc.checkpoint.interval == 0:
                save()
        finished = True
    except KeyboardInterrupt:
        print("interrupted: saving a checkpoint", file=sys.stderr)
        finished = True
    finally:
        pbar.close()
        if finished:
            save(final=True)
        logger.close()
        collector.shutdown()
        if not env.is_closed:
            env.close()
    print(
        f"done: iteration {counters.iteration}, frames {counters.frames:,}, "
        f"difficulty {curriculum.difficulty}, checkpoint {run_dir / CHECKPOINT_DIR / LAST_NAME}"
    )
    return counters


def should_stop(tc: TrainConfig, counters: Counters, cur: Curriculum, session_start: float) -> bool:
    if tc.total_frames is not None and counters.frames >= tc.total_frames:
        return True
    if tc.max_minutes is not None and time.monotonic() - session_start >= 60.0 * tc.max_minutes:
        return True
    return tc.stop_difficulty is not None and cur.difficulty >= tc.stop_difficulty


def hparam_metrics(difficulty: float, ema: float) -> dict[str, float]:
    return {"hparam/difficulty": difficulty, "hparam/success_ema": ema}


def iteration_scalars(stats, learn, curriculum, tolerance, timing) -> dict[str, float]:
    """All TensorBoard scalars of one iteration (NaN-valued ones, e.g. no episode ended, dropped)."""
    keys = list(stats)
    values = torch.stack([stats[k] for k in keys]).tolist()  # one device sync
    out = {}
    for k, v in zip(keys, values, strict=True):
        if k.startswith("return/"):
            out[f"reward_episode/{k[7:]}"] = v
        elif k.startswith("step/"):
            out[f"reward_step/{k[5:]}"] = v
        else:
            name = {"final_pos_error": "final_pos_error_m", "episodes": "count"}.get(k, k)
            if name.startswith("final_") and name.endswith("_error"):
                name += "_deg"
            out[f"episode/{name}"] = v
    out["episode/success_ema"] = curriculum.ema
    out.update(
        {f"loss/{k[5:]}": learn[k] for k in ("loss_objective", "loss_critic", "loss_entropy")}
    )
    for k in ("entropy", "kl", "kl_approx", "clip_fraction", "grad_norm", "lr", "action_std"):
        out[f"train/{k}"] = learn[k]
    out["curriculum/difficulty"] = curriculum.difficulty
    out["curriculum/promotions"] = curriculum.promotions
    out["curriculum/tolerance_position_m"] = tolerance[0]
    out["curriculum/tolerance_heading_deg"] = tolerance[1]
    out.update(hparam_metrics(curriculum.difficulty, curriculum.ema))
    out.update(timing)
    return {k: v for k, v in out.items() if math.isfinite(v)}


def log_video(logger: RunLogger, ac, tc: TrainConfig, difficulty: float, counters) -> bool:
    """Record one deterministic episode (same seed every time); False disables further videos."""
    try:
        frames = record_episode(
            ac.actor, tc.env, difficulty, tc.seed, tc.log.video_steps, tc.device
        )
    except ImportError as e:
        warnings.warn(f"rollout videos disabled: {e}", stacklevel=1)
        return False
    logger.video(frames, counters.iteration, counters.frames, tc.log.video_fps)
    return True


@hydra.main(version_base=None, config_path=CONFIG_PATH, config_name="train")
def main(cfg: DictConfig) -> None:
    try:
        train(cfg, Path(HydraConfig.get().runtime.output_dir))
    except (ConfigError, CheckpointError) as e:
        print(f"{type(e).__name__}: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
