"""``python -m truckrl.train``: PPO on TruckEnv with the success curriculum (the paper's setup).

    python -m truckrl.train                                # experiment=demos (CPU), paper curriculum
    python -m truckrl.train resume=outputs/2025-01-01/12-00-00        # continue a stopped run
    python -m truckrl.train --help                                    # options and examples

Each iteration collects ``collector.workers x num_envs x steps_per_env`` frames, feeds finished
episodes to the curriculum in start order (:mod:`truckrl.rl.cohorts`; a promotion reaches
every worker before the next collection), runs the PPO update and logs to ``<run_dir>/tb``.
``<run_dir>/checkpoints/last.pt`` is written every ``checkpoint.interval`` iterations and at the
end; ``best.pt`` after each held-out evaluation that beats every earlier one (higher difficulty,
or the same difficulty and a higher success rate; ``checkpoint.keep_best``). A run stops at
``stop_difficulty`` (6, the paper's goal, in ``experiment=fast``; none in the default
``experiment=demos``, which trains on at 6), ``max_minutes`` (60),
``total_frames`` or a signal (at the next iteration boundary, with a checkpoint, exit 0;
:mod:`truckrl.rl.session`); its last lines say why and what to run next.

``train_env.FIELD=VALUE`` changes the env of the training envs only (a training scene mix,
e.g. ``train_env.task.scene.crossing_prob=1.0``); held-out checks, ``best.pt`` and evaluating
the checkpoints use ``env``.

``init=<checkpoint, run dir or pretrained[:task]>`` starts a new run from that checkpoint's
network weights under this command line's config (fine-tuning: another scene mix, reward or PPO
setting); its optimizer, curriculum and counters are not used, so give the difficulty to start
at as ``curriculum.start_difficulty``.

Resuming (``resume=<checkpoint or run dir>``) continues in the original run dir with the
checkpoint's state and saved config but for :data:`~truckrl.config.schemas.RESUME_OVERRIDES` (from the
command line); an older checkpoint branches into a new run dir. ``total_frames`` counts all
sessions, ``max_minutes`` this one. The envs restart with fresh episodes seeded from ``(seed,
iteration)``: a faithful continuation, not a bit-identical one.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from truckrl.cli import hydra_entry, workers_ignore_stop_signals

workers_ignore_stop_signals(__name__)  # ParallelEnv workers: this process stops and closes them
log = logging.getLogger("truckrl.train")


def train(tc: Any, run_dir: Path, state: dict | None = None, parent: dict | None = None,
          stop: Any = None, init: dict | None = None) -> Any:  # fmt: skip
    """Run (or, with a loaded checkpoint ``state``, resume) one training job; return its counters.
    ``stop``: installed :class:`~truckrl.rl.session.StopSignals` (:func:`run` installs them).
    ``init``: a loaded checkpoint whose network weights start a new run (``tc.init``; ignored
    when resuming).

    One recipe, top to bottom like TorchRL's ``ppo_mujoco.py`` (create env, models, PPO,
    collector, logger; then the loop): splitting it would hide the order the parts depend on.
    """
    # Heavy imports here, not at module level: `--help` and config errors answer before they load
    import yaml

    from truckrl.cli import git_revision, seed_everything
    from truckrl.evaluation.heldout import heldout_due, heldout_scalars
    from truckrl.rl import checkpoint as ckpt
    from truckrl.rl.cohorts import StartOrderFeed
    from truckrl.rl.collection import (
        check_difficulty,
        make_collector,
        make_env,
        set_difficulty,
    )
    from truckrl.rl.curriculum import Curriculum
    from truckrl.rl.logger import RunLogger, flatten
    from truckrl.rl.metrics import EpisodeTracker, hparam_metrics, iteration_scalars
    from truckrl.rl.network import make_actor_critic, parameter_count
    from truckrl.rl.ppo import PPO
    from truckrl.rl.progress import Progress, stop_lines, stop_reason
    from truckrl.rl.session import Counters, StopSignals, write_parent
    from truckrl.tasks import make_task
    from truckrl.tasks.config import with_env_overrides

    cfg_yaml = yaml.safe_dump(asdict(tc), sort_keys=False)
    source = git_revision()  # once: checkpoints record the commit the session started from
    counters = Counters(**state["counters"]) if state else Counters()
    session_start, wall_at_start = time.monotonic(), counters.wall_time_s  # demos count too
    seed_everything(tc.seed)
    stop = stop or StopSignals()

    # Create environment
    c = tc.collector
    train_env = with_env_overrides(tc.env, tc.train_env, fixed=True, where="train_env")
    env = make_env(train_env, c.workers, c.num_envs, tc.seed, counters.iteration, tc.device)
    num_obs = env.observation_spec["observation"].shape[-1]
    num_beams = env.observation_spec["lidar"].shape[-1]
    task = make_task(tc.env)  # the task's vocabulary: reward terms and errors

    # Create models, PPO (GAE, ClipPPOLoss, Adam, KL schedule) and curriculum
    ac = make_actor_critic(tc.model, num_obs, num_beams, env.action_spec.shape[-1])
    ac.model.to(tc.device)
    demos = samples = None
    if not state and init is not None:  # fine-tuning: another run's weights, nothing else
        try:
            ckpt.load_init_weights(init, ac.model, num_obs, num_beams)
        except ckpt.CheckpointError:
            env.close()  # the workers, before the one-line error
            raise
        skipped = "; demos skipped" if tc.demos.episodes > 0 or tc.demos.bc_coeff > 0 else ""
        log.info(f"init: weights of {init['path']} (iteration {init['counters']['iteration']}, "
                 f"difficulty {init['curriculum']['difficulty']:g}){skipped}")  # fmt: skip
    elif not state and tc.demos.episodes > 0:  # a start cloned from planner demonstrations
        demos, samples = clone_demonstrations(ac, tc, env)
    ppo = PPO(ac, tc.ppo)
    # the demonstrations stay in the update (not in a fine-tune: init= skips the demos)
    if bc_weight(tc.demos, counters.frames) > 0 and (state or init is None):
        ppo.demos = cloning_samples(tc, run_dir, state, parent, samples, env).to(tc.device)
        ppo.bc_batch = tc.demos.bc_batch
    curriculum = Curriculum(tc.curriculum)
    if state:
        per_iteration = tc.ppo.num_epochs * tc.ppo.num_minibatches  # optimizer steps
        try:
            ckpt.restore_training(
                state, ac.model, ppo, curriculum, num_obs, num_beams, per_iteration
            )
        except ckpt.CheckpointError:
            env.close()  # the workers, before the one-line error
            raise
        ckpt.restore_rng(state["rng"])  # after the model is built: its init draws from the RNG
        stop.last_checkpoint = str(state["path"])
        log.info(f"resumed {state['path']} at iteration {counters.iteration}, "
                 f"frames {counters.frames:,} -> run dir {run_dir}")  # fmt: skip
    log.info(f"model: {parameter_count(ac.model):,} parameters ({num_beams} LiDAR beams)")
    tolerance = set_difficulty(env, curriculum.difficulty)

    # Create collector
    collector = make_collector(
        env, ac, tc.collector.frames_per_batch, tc.collector.compile_policy, tc.device
    )

    # Create logger (a continued run drops what the killed run logged after its checkpoint)
    continued = state is not None and parent is None
    logger = RunLogger(run_dir, purge_step=counters.frames + 1 if continued else None)
    if not continued:
        logger.config(cfg_yaml, asdict(tc), hparam_metrics(0.0, 0.0))
        (run_dir / "source.json").write_text(json.dumps(source) + "\n")
        if demos:
            (run_dir / "demos.json").write_text(json.dumps(demos, indent=2) + "\n")
        if parent:
            write_parent(run_dir, parent)
    log.info(f"run dir: {run_dir}; batch {tc.collector.frames_per_batch:,} frames/iteration")

    def save(final: bool = False, best: dict | None = None) -> None:
        """Write last.pt (and iter_XXXXXX.pt when due); with ``best``, only best.pt."""
        counters.wall_time_s = wall_at_start + time.monotonic() - session_start
        ckpt_dir = run_dir / ckpt.CHECKPOINT_DIR
        paths = [ckpt_dir / (ckpt.BEST_NAME if best else ckpt.LAST_NAME)]
        keep = tc.checkpoint.keep_every
        if keep and not best and (counters.iteration % keep == 0 or final):
            paths.append(ckpt_dir / f"iter_{counters.iteration:06d}.pt")
        for p in paths:
            try:
                ckpt.save_training_state(p, model=ac.model, ppo=ppo, curriculum=curriculum,
                                         counters=asdict(counters), config_yaml=cfg_yaml,
                                         num_obs=num_obs, num_beams=num_beams, source=source,
                                         heldout=best)  # fmt: skip
            except OSError as e:  # full disk, lost permission: stop; the last good one is intact
                why = (
                    f"{e.strerror or e}; the last good checkpoint is intact: {stop.last_checkpoint}"
                )
                raise ckpt.CheckpointError(f"cannot write checkpoint {p} ({why})") from None
        if not best:
            stop.last_checkpoint = str(paths[0])

    # The best held-out result so far, (difficulty, success): a resumed run keeps its best.pt
    best_so_far = ckpt.best_record(run_dir / ckpt.CHECKPOINT_DIR / ckpt.BEST_NAME)

    # Training loop
    tracker = EpisodeTracker(task.reward_keys, task.error_quantities)
    feed = StartOrderFeed()  # curriculum evidence unbiased by the synchronous (re)start
    video_ok = tc.log.video_interval > 0
    progress = Progress(tc.total_frames, tc.max_minutes, tc.stop_difficulty, tc.log.progress_bar)
    batches = iter(collector)
    reason = None  # why the loop ended; None after an error (the last good checkpoint stays)
    try:
        while True:
            minutes = (time.monotonic() - session_start) / 60.0
            reason = stop.name or stop_reason(counters.frames, minutes, curriculum.difficulty,
                                              tc.total_frames, tc.max_minutes, tc.stop_difficulty)  # fmt: skip
            if reason is not None:
                break
            t0 = time.perf_counter()
            with stop.interruptible():  # a signal here drops the partial batch at once
                batch = next(batches)
            t1 = time.perf_counter()

            # Episode statistics and curriculum
            check_difficulty(batch, curriculum.difficulty)
            stats = tracker.update(batch)
            promoted = curriculum.update(*feed.update(batch))
            if promoted:
                tolerance = set_difficulty(env, curriculum.difficulty)
                log.info(f"difficulty {curriculum.difficulty:g} ({tolerance[0]:.3g} m, "
                         f"{tolerance[1]:.3g} deg) at {minutes:.1f} min, {counters.frames:,} frames")  # fmt: skip

            # PPO update
            ppo.bc_coeff = bc_weight(tc.demos, counters.frames)
            learn = ppo.update(batch)
            if "loss_bc" in learn:
                learn["bc_coeff"] = ppo.bc_coeff
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
            progress.update(counters.frames, (time.monotonic() - session_start) / 60.0,
                            curriculum.difficulty, curriculum.ema, timing["perf/fps"])  # fmt: skip
            if video_ok and logger.video_due(counters.iteration, tc.log.video_interval):
                video_ok = logger.rollout_video(
                    ac.actor, tc.env, curriculum.difficulty, tc.seed, tc.log.video_steps,
                    tc.device, counters.iteration, counters.frames, tc.log.video_fps,
                )  # fmt: skip
            # Held-out scenes every log.eval_interval_min minutes (truckrl/evaluation/heldout.py)
            elapsed, window = time.monotonic() - session_start, time.perf_counter() - t0
            if heldout_due(tc.log.eval_interval_min, elapsed, window):
                evals = heldout_scalars(
                    ac.actor, tc.env, curriculum.difficulty, tc.log.eval_episodes, tc.device
                )
                logger.scalars(evals, counters.frames)
                record = (float(curriculum.difficulty), evals["eval/success_rate"])
                if tc.checkpoint.keep_best and (best_so_far is None or record > best_so_far):
                    best_so_far = record
                    save(best={"difficulty": record[0], "success_rate": record[1],
                               "frames": counters.frames})  # fmt: skip
                    log.info(f"best.pt: held-out success {record[1]:.3f} at difficulty "
                             f"{record[0]:g} ({counters.frames:,} frames)")  # fmt: skip
            if counters.iteration % tc.checkpoint.interval == 0:
                save()
    except KeyboardInterrupt:  # raised by StopSignals while collecting (or with no handlers)
        reason = stop.name or "SIGINT"
    finally:
        progress.close()
        try:
            if reason is not None:
                save(final=True)
                final = hparam_metrics(curriculum.difficulty, curriculum.ema)  # HPARAMS table
                logger.writer.add_hparams(flatten(asdict(tc)), final, run_name=".",
                                          global_step=counters.frames)  # fmt: skip
        finally:
            logger.close()
            collector.shutdown()
            if not env.is_closed:
                env.close()
    minutes = (time.monotonic() - session_start) / 60.0
    for line in stop_lines(reason, run_dir, counters.iteration, counters.frames, minutes,
                           curriculum.difficulty):  # fmt: skip
        log.info(line)
    stop.hand_over()  # under submitit: requeue the job (it resumes by itself)
    return counters


def bc_weight(dc: Any, frames: int) -> float:
    """The cloning term's weight after ``frames`` frames: ``dc.bc_coeff`` falling linearly to 0
    at ``dc.bc_frames`` (:class:`~truckrl.config.schemas.DemosConfig`)."""
    return dc.bc_coeff * max(0.0, 1.0 - frames / dc.bc_frames)


def cloning_samples(
    tc: Any, run_dir: Path, state: dict | None, parent: dict | None, fresh: Any, env: Any
) -> Any:
    """The demonstration samples PPO keeps cloning (``demos.bc_coeff > 0``).

    A new run stores the samples it just cloned (``fresh``) as ``<run_dir>/demos.pt``; a resumed
    run reads that file back, from its own run dir or, for a branch, its parent's (``imitate``
    writes one beside its checkpoint too). No samples is a one-line :class:`ConfigError`, before
    any training.
    """
    from truckrl.config.fields import ConfigError
    from truckrl.rl.imitation import SAMPLES_NAME, load_samples, save_samples

    if fresh is not None:
        save_samples(run_dir / SAMPLES_NAME, fresh)
        return fresh
    places = [run_dir] + ([Path(parent["run_dir"])] if parent else [])
    for where in places:
        if (where / SAMPLES_NAME).exists():
            try:
                return load_samples(where / SAMPLES_NAME)
            except ValueError as e:
                env.close()
                raise ConfigError(f"demos.bc_coeff: {e}") from None
    env.close()  # the workers, before the one-line error
    files = " or ".join(str(p / SAMPLES_NAME) for p in places)
    if state:  # the saved config decides: demos.* cannot change on resume
        how = f"a resumed run reads {files}, which does not exist (put it back, or start a new "
        how += f"run from these weights: init={run_dir} demos.bc_coeff=0)"
    else:
        how = f"a new run needs demos.episodes > 0 or {files} (or demos.bc_coeff=0)"
    raise ConfigError(f"demos.bc_coeff = {tc.demos.bc_coeff:g} needs demonstrations: {how}")


def clone_demonstrations(ac: Any, tc: Any, env: Any) -> tuple[dict, Any]:
    """``demos.episodes`` planner (or scripted-driver) solutions cloned into ``ac``
    (:func:`imitation.bootstrap`); returns its summary and the samples. A demonstrator that
    solves nothing is a one-line :class:`ConfigError`."""
    from truckrl.config.fields import ConfigError
    from truckrl.rl.imitation import bootstrap

    dc = tc.demos
    how = "planning" if dc.source == "planner" else "driving (scripted turnaround)"
    log.info(f"demonstrations: {how} {dc.episodes} scenes (seed {dc.seed}) at difficulty "
             f"{dc.difficulty:g}, then behaviour cloning")  # fmt: skip
    last = [time.monotonic()]

    def progress(done: int, total: int) -> None:
        if time.monotonic() - last[0] > 30.0 or done == total:
            last[0] = time.monotonic()
            log.info(f"  planner: {done}/{total} scenes")

    try:
        demos, samples = bootstrap(ac, tc.env, dc, tc.device, tc.seed, progress)
    except ValueError as e:
        env.close()  # the workers, before the one-line error
        raise ConfigError(f"demos: {e}") from None
    log.info(f"demonstrations: {demos['plans_kept']} of {dc.episodes} scenes solved, "
             f"{demos['samples']:,} samples, action MSE {demos['losses'][0]:.4f} -> "
             f"{demos['losses'][-1]:.4f}, {demos['seconds'] / 60:.1f} min")  # fmt: skip
    return demos, samples


def run(tc: Any, job_dir: Path, explicit_dir: bool = True) -> Any:
    """Plan the session (run dir, resume or branch; :func:`~truckrl.rl.session.plan_session`)
    and train; ``tc.resume``'s checkpoint supplies the config but for ``RESUME_OVERRIDES``."""
    from truckrl.config.schemas import RESUME_OVERRIDES, TrainConfig
    from truckrl.rl.checkpoint import load_training_state
    from truckrl.rl.session import StopSignals, merged_config, plan_session

    stop = StopSignals().install()  # from here on a signal stops at the next iteration boundary
    try:
        plan = plan_session(tc.resume, tc.overwrite, job_dir, explicit_dir)
        if plan.state:
            tc = merged_config(plan.state, asdict(tc), TrainConfig, RESUME_OVERRIDES, log)
        init = load_training_state(tc.init) if tc.init and not plan.state else None
        return train(tc, plan.run_dir, plan.state, plan.parent, stop, init)
    finally:
        stop.restore()


def prepare_argv(argv: list[str]) -> list[str]:
    """``train_env.FIELD=VALUE`` as Hydra's ``+train_env.FIELD=VALUE`` (a key of a free-form
    dict), then the run-dir checks of :func:`truckrl.rl.session.prepare_argv`."""
    from truckrl.cli import plus_overrides
    from truckrl.rl.session import prepare_argv as check_run_dir

    return check_run_dir(plus_overrides(argv, "train_env."))


@hydra_entry("train", "TrainConfig", prepare="truckrl.train:prepare_argv")
def main(tc: Any, raw: Any) -> None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from truckrl.rl.session import ignore_stop_signals

    hc = HydraConfig.get()
    named = any(o.startswith("hydra.run.dir=") for o in hc.overrides.hydra)
    run(tc, Path(hc.runtime.output_dir), explicit_dir=hc.mode == RunMode.RUN and named)
    ignore_stop_signals()  # the run is over: a late Ctrl-C must not turn the exit into a traceback


if __name__ == "__main__":
    main()
