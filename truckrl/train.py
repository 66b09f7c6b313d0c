"""``python -m truckrl.train``: PPO on TruckEnv with the success curriculum (the paper's setup).

    python -m truckrl.train                                # experiment=fast (CPU), paper curriculum
    python -m truckrl.train experiment=paper max_minutes=60           # the paper's PPO numbers
    python -m truckrl.train resume=outputs/2025-01-01/12-00-00        # continue a stopped run
    python -m truckrl.train -m ppo.lr=1e-4,3e-4                       # sweep (outputs/multirun/...)
    python -m truckrl.train --cfg job                                 # print the composed config

Each iteration collects ``collector.workers x num_envs x steps_per_env`` frames, feeds the finished
episodes to the curriculum (a promotion reaches every worker before the next collection), runs the
PPO update and logs to ``<run_dir>/tb``. ``<run_dir>/checkpoints/last.pt`` is written every
``checkpoint.interval`` iterations and at the end.

Resuming (``resume=<checkpoint or run dir>``) continues in the original run dir with the
checkpoint's model, optimizer, learning rate, curriculum, counters and RNG states, and with its
saved config except the keys in :data:`RESUME_OVERRIDES`, which come from the command line.
``total_frames`` counts all sessions together; ``max_minutes`` limits this session. The envs
restart with fresh episodes seeded from ``(seed, iteration)``: a faithful continuation, not a
bit-identical one.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import yaml
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from torchrl.collectors import Collector
from tqdm import tqdm

from truckrl.agent.checkpoint import (
    CHECKPOINT_DIR,
    LAST_NAME,
    load_training_state,
    restore_rng,
    save_training_state,
)
from truckrl.agent.collection import check_difficulty, make_env, set_difficulty
from truckrl.agent.curriculum import Curriculum
from truckrl.agent.heldout import heldout_due, heldout_scalars
from truckrl.agent.metrics import (
    EpisodeTracker,
    finished_in_time_order,
    hparam_metrics,
    iteration_scalars,
)
from truckrl.agent.network import make_actor_critic, parameter_count
from truckrl.agent.policy import saved_config
from truckrl.agent.ppo import PPO
from truckrl.cli import git_revision, hydra_entry, seed_everything, to_config
from truckrl.configs import RESUME_OVERRIDES, TrainConfig
from truckrl.run_logger import RunLogger
from truckrl.task import make_task


@dataclass
class Counters:
    iteration: int = 0
    frames: int = 0
    wall_time_s: float = 0.0


def resumed_config(saved: dict, current: dict) -> dict:
    """The checkpoint's config with :data:`RESUME_OVERRIDES` taken from ``current``."""
    ignored = sorted(
        k
        for k in set(current) | set(saved)
        if k not in RESUME_OVERRIDES and current.get(k) != saved.get(k)
    )
    if ignored:
        print(
            f"resume: keeping the checkpoint's {', '.join(ignored)} (differs from the command line)"
        )
    return {**saved, **{k: current[k] for k in RESUME_OVERRIDES if k in current}}


def should_stop(tc: TrainConfig, counters: Counters, cur: Curriculum, start: float) -> bool:
    if tc.total_frames is not None and counters.frames >= tc.total_frames:
        return True
    if tc.max_minutes is not None and time.monotonic() - start >= 60.0 * tc.max_minutes:
        return True
    return tc.stop_difficulty is not None and cur.difficulty >= tc.stop_difficulty


def train(tc: TrainConfig, run_dir: Path, state: dict | None = None) -> Counters:
    """Run (or, with a loaded checkpoint ``state``, resume) one training job.

    One recipe, top to bottom like TorchRL's ``ppo_mujoco.py`` (create env, models, PPO,
    collector, logger; then the loop): splitting it would hide the order the parts depend on.
    """
    cfg_yaml = yaml.safe_dump(asdict(tc), sort_keys=False)
    counters = Counters(**state["counters"]) if state else Counters()
    seed_everything(tc.seed)

    # Create environment
    c = tc.collector
    env = make_env(tc.env, c.workers, c.num_envs, tc.seed, counters.iteration, tc.device)
    num_obs = env.observation_spec["observation"].shape[-1]
    num_beams = env.observation_spec["lidar"].shape[-1]
    task = make_task(tc.env)  # the task's vocabulary: reward terms and errors

    # Create models, PPO (GAE, ClipPPOLoss, Adam, KL schedule) and curriculum
    ac = make_actor_critic(tc.model, num_obs, num_beams, env.action_spec.shape[-1])
    ac.model.to(tc.device)
    ppo = PPO(ac, tc.ppo)
    curriculum = Curriculum(tc.curriculum)
    if state:
        ac.model.load_state_dict(state["model"])
        ppo.load_state_dict(state["ppo"])
        curriculum.load_state_dict(state["curriculum"])
        restore_rng(state["rng"])  # after the model is built: its init draws from the RNG
        print(f"resumed {run_dir} at iteration {counters.iteration}, frames {counters.frames:,}")
    print(f"model: {parameter_count(ac.model):,} parameters ({num_beams} LiDAR beams)")
    tolerance = set_difficulty(env, curriculum.difficulty)

    # Create collector
    collector = Collector(
        env,
        ac.actor,
        frames_per_batch=tc.collector.frames_per_batch,
        total_frames=-1,
        device=tc.device,
        auto_register_policy_transforms=False,  # the policy is stateless: no InitTracker needed
    )

    # Create logger (a resumed run drops what the killed run logged after its checkpoint)
    logger = RunLogger(run_dir, purge_step=counters.frames + 1 if state else None)
    if not state:
        logger.config(cfg_yaml, asdict(tc), hparam_metrics(0.0, 0.0))
        (run_dir / "source.json").write_text(json.dumps(git_revision()) + "\n")
    print(f"run dir: {run_dir}; batch {tc.collector.frames_per_batch:,} frames/iteration")

    def save(final: bool = False) -> None:
        counters.wall_time_s = wall_at_start + time.monotonic() - session_start
        ckpt_dir = run_dir / CHECKPOINT_DIR
        paths = [ckpt_dir / LAST_NAME]
        keep = tc.checkpoint.keep_every
        if keep and (counters.iteration % keep == 0 or final):
            paths.append(ckpt_dir / f"iter_{counters.iteration:06d}.pt")
        for p in paths:
            save_training_state(
                p,
                model=ac.model,
                ppo=ppo,
                curriculum=curriculum,
                counters=asdict(counters),
                config_yaml=cfg_yaml,
                num_obs=num_obs,
                num_beams=num_beams,
                source=git_revision(),
            )

    # Training loop
    tracker = EpisodeTracker(task.reward_keys, task.error_quantities)
    session_start, wall_at_start = time.monotonic(), counters.wall_time_s
    video_ok = tc.log.video_interval > 0
    pbar = tqdm(total=tc.total_frames, initial=counters.frames, unit="frame", unit_scale=True,
                dynamic_ncols=True, disable=not tc.log.progress_bar)  # fmt: skip
    batches = iter(collector)
    finished = False  # a crash must not overwrite the last good checkpoint
    try:
        while not should_stop(tc, counters, curriculum, session_start):
            t0 = time.perf_counter()
            batch = next(batches)
            t1 = time.perf_counter()

            # Episode statistics and curriculum
            check_difficulty(batch, curriculum.difficulty)
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
            timing = {"perf/fps": frames / (t2 - t0), "perf/fps_collect": frames / (t1 - t0),
                      "perf/collect_s": t1 - t0, "perf/learn_s": t2 - t1}  # fmt: skip
            if counters.iteration % tc.log.interval == 0 or promoted:
                cur = {**curriculum.state_dict(), "tolerance_position_m": tolerance[0],
                       "tolerance_heading_deg": tolerance[1]}  # fmt: skip
                scalars = iteration_scalars(stats, learn, cur, timing, task.error_quantities)
                logger.scalars(scalars, counters.frames)
            pbar.update(frames)
            pbar.set_postfix(fps=f"{timing['perf/fps']:.0f}", diff=curriculum.difficulty,
                             ema=f"{curriculum.ema:.2f}", refresh=False)  # fmt: skip
            if video_ok and logger.video_due(counters.iteration, tc.log.video_interval):
                video_ok = logger.rollout_video(
                    ac.actor, tc.env, curriculum.difficulty, tc.seed, tc.log.video_steps,
                    tc.device, counters.iteration, counters.frames, tc.log.video_fps,
                )  # fmt: skip
            # Held-out scenes every log.eval_interval_min minutes (truckrl/agent/heldout.py)
            elapsed, window = time.monotonic() - session_start, time.perf_counter() - t0
            if heldout_due(tc.log.eval_interval_min, elapsed, window):
                evals = heldout_scalars(
                    ac.actor, tc.env, curriculum.difficulty, tc.log.eval_episodes, tc.device
                )
                logger.scalars(evals, counters.frames)
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


@hydra_entry("train", TrainConfig)
def main(tc: TrainConfig, raw: DictConfig) -> None:
    run_dir, state = Path(HydraConfig.get().runtime.output_dir), None
    if tc.resume:
        state = load_training_state(tc.resume)
        current = OmegaConf.to_container(raw, resolve=True)
        current.pop("hydra", None)
        tc = to_config(TrainConfig, resumed_config(saved_config(state), current))
        ckpt = state["path"]
        run_dir = ckpt.parent.parent if ckpt.parent.name == CHECKPOINT_DIR else ckpt.parent
    train(tc, run_dir, state)


if __name__ == "__main__":
    main()
