"""One PPO training job as an object: :meth:`Trainer.setup`, then :meth:`Trainer.iterate` until
:meth:`Trainer.stop_reason` names a reason, then :meth:`Trainer.close`.

``truckrl train`` drives it (resume, signals, the last lines) and ``python -m
truckrl.bench train`` times the same :meth:`~Trainer.iterate`, so the benchmark measures what
users run.

:meth:`~Trainer.setup` is the recipe top to bottom like TorchRL's ``ppo_mujoco.py``: env, models,
PPO and its demonstrations, curriculum, collector, logger. One :meth:`~Trainer.iterate` collects
``collector.workers x num_envs x steps_per_env`` frames, feeds finished episodes to the
curriculum in start order (:mod:`truckrl.rl.cohorts`; a promotion reaches every worker before the
next collection), runs the PPO update and logs to ``<run_dir>/tb``; videos, held-out checks and
checkpoints follow when due. The first held-out check that meets ``log.quality_target`` at
``log.quality_difficulty`` logs ``quality_reached`` (``truckrl.rl.progress.Quality``; with
``stop_on_quality`` the run stops there).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
import yaml

from truckrl.config.fields import ConfigError
from truckrl.evaluation.heldout import heldout_due, heldout_scalars
from truckrl.rl import checkpoint as ckpt
from truckrl.rl import collection
from truckrl.rl.cohorts import StartOrderFeed
from truckrl.rl.curriculum import Curriculum
from truckrl.rl.logger import RunLogger
from truckrl.rl.metrics import EpisodeTracker, hparam_metrics, iteration_scalars
from truckrl.rl.network import make_actor_critic, parameter_count
from truckrl.rl.ppo import PPO
from truckrl.rl.progress import Progress, Quality, stop_lines, stop_reason
from truckrl.rl.session import Counters, StopSignals, write_parent
from truckrl.tasks import make_task
from truckrl.tasks.config import with_env_overrides

#: The training run's log (``truckrl.train`` is what users and tests listen to).
log = logging.getLogger("truckrl.train")

#: Spans one :meth:`Trainer.iterate` writes into its ``timings`` argument [s], in order; the PPO
#: update adds its own (:meth:`PPO.update <truckrl.rl.ppo.PPO.update>`).
SPANS = ("collect_s", "stats_s", "update_s", "weights_s", "log_s", "periodic_s")


class Trainer:
    """One training job (or, with a loaded checkpoint ``state``, its continuation).

    Args:
        tc: the ``truckrl.config.schemas.TrainConfig``.
        run_dir: where checkpoints, events, videos and records go.
        state: a loaded checkpoint to resume from (None: a new run).
        parent: the run a branch continues (``truckrl.rl.session.plan_session``).
        stop: installed ``truckrl.rl.session.StopSignals`` (default: none installed).
        init: a loaded checkpoint whose network weights start a new run (``tc.init``; ignored
            when resuming).
        source: the source's git revision, recorded in every checkpoint (the entry point reads
            it once per session).
        sync_timings: wait for the device at each span end, so each span holds its own kernels
            (the benchmark; training does not pay for it).
        started: ``time.monotonic()`` at the session's start (the entry point's, so start-up
            and demonstrations count; default: now).

    The caller seeds the global generators (``truckrl.cli.seed_everything(tc.seed)``) before
    :meth:`setup`: the env, the network's init and the demonstrations draw from them.
    """

    def __init__(self, tc: Any, run_dir: Path, state: dict | None = None,
                 parent: dict | None = None, stop: StopSignals | None = None,
                 init: dict | None = None, source: dict | None = None,
                 sync_timings: bool = False, started: float | None = None) -> None:  # fmt: skip
        self.tc, self.run_dir, self.state, self.parent, self.init = tc, run_dir, state, parent, init
        self.stop = stop or StopSignals()
        self.sync_timings = sync_timings
        self.counters = Counters(**state["counters"]) if state else Counters()
        self.session_start = time.monotonic() if started is None else started
        self.wall_at_start = self.counters.wall_time_s  # demonstrations count too
        self.quality = Quality(tc.log.quality_target, tc.log.quality_difficulty,
                               self.counters.quality)  # fmt: skip
        self.cfg_yaml = yaml.safe_dump(asdict(tc), sort_keys=False)
        self.source = source or {}

    # ------------------------------------------------------------------ setup
    def setup(self) -> None:
        """Build env, models, PPO, curriculum, collector and logger; a bad checkpoint or missing
        demonstrations raise their one-line errors after closing the env workers."""
        tc, state = self.tc, self.state
        fixed_order_gradients(tc.device)

        # Create environment
        c = tc.collector
        train_env = with_env_overrides(tc.env, tc.train_env, fixed=True, where="train_env")
        self.env = collection.make_env(
            train_env, c.workers, c.num_envs, tc.seed, self.counters.iteration, tc.device
        )
        self.num_obs = self.env.observation_spec["observation"].shape[-1]
        self.num_beams = self.env.observation_spec["lidar"].shape[-1]
        self.task = make_task(tc.env)  # the task's vocabulary: reward terms and errors

        # Create models, PPO (GAE, ClipPPOLoss, Adam, KL schedule) and curriculum
        self.ac = make_actor_critic(tc.model, self.num_obs, self.num_beams,
                                    self.env.action_spec.shape[-1])  # fmt: skip
        self.ac.model.to(tc.device)
        demos = self._start_weights()
        self.ppo = PPO(self.ac, tc.ppo)
        # the demonstrations stay in the update (not in a fine-tune: init= skips the demos)
        if bc_weight(tc.demos, self.counters.frames) > 0 and (state or self.init is None):
            self.ppo.demos = self.demonstration_samples(demos[1]).to(tc.device)
            self.ppo.bc_batch = tc.demos.bc_batch
            self.ppo.bc_executed = tc.demos.bc_loss == "executed"
        self.curriculum = Curriculum(tc.curriculum)
        if state:
            self._restore()
        log.info(f"model: {parameter_count(self.ac.model):,} parameters "
                 f"({self.num_beams} LiDAR beams)")  # fmt: skip
        self.tolerance = collection.set_difficulty(self.env, self.curriculum.difficulty)

        # Create collector
        self.collector = collection.make_collector(
            self.env, self.ac, c.frames_per_batch, c.compile_policy, tc.device
        )
        self._open_logger(demos[0])

        # Loop state
        self.best_so_far = ckpt.best_record(self.run_dir / ckpt.CHECKPOINT_DIR / ckpt.BEST_NAME)
        self.tracker = EpisodeTracker(self.task.reward_keys, self.task.error_quantities)
        self.feed = StartOrderFeed()  # curriculum evidence unbiased by the synchronous (re)start
        self.video_ok = tc.log.video_interval > 0
        self.progress = Progress(tc.total_frames, tc.max_minutes, tc.stop_difficulty,
                                 tc.log.progress_bar)  # fmt: skip
        self.batches = iter(self.collector)

    def _start_weights(self) -> tuple[dict | None, Any]:
        """A fine-tune's weights (``init``) or a start cloned from demonstrations; returns the
        demonstrations' summary and samples (None, None without)."""
        tc = self.tc
        if not self.state and self.init is not None:  # fine-tuning: another run's weights only
            init = self.init
            try:
                ckpt.load_init_weights(init, self.ac.model, self.num_obs, self.num_beams)
            except ckpt.CheckpointError:
                self.env.close()  # the workers, before the one-line error
                raise
            skipped = "; demos skipped" if tc.demos.episodes > 0 or tc.demos.bc_coeff > 0 else ""
            log.info(f"init: weights of {init['path']} (iteration {init['counters']['iteration']}, "
                     f"difficulty {init['curriculum']['difficulty']:g}){skipped}")  # fmt: skip
        elif not self.state and tc.demos.episodes > 0:  # a start cloned from demonstrations
            return clone_demonstrations(self.ac, tc, self.env)
        return None, None

    def demonstration_samples(self, fresh: Any) -> Any:
        """The samples the cloning term keeps fitting (:func:`cloning_samples`); the benchmark
        overrides this with stand-ins."""
        return cloning_samples(self.tc, self.run_dir, self.state, self.parent, fresh, self.env)

    def _restore(self) -> None:
        """The checkpoint's weights, optimizer, curriculum and RNG (after the model is built: its
        init draws from the RNG)."""
        state, tc = self.state, self.tc
        per_iteration = tc.ppo.num_epochs * tc.ppo.num_minibatches  # optimizer steps
        try:
            ckpt.restore_training(state, self.ac.model, self.ppo, self.curriculum, self.num_obs,
                                  self.num_beams, per_iteration)  # fmt: skip
        except ckpt.CheckpointError:
            self.env.close()  # the workers, before the one-line error
            raise
        ckpt.restore_rng(state["rng"])
        self.stop.last_checkpoint = str(state["path"])
        log.info(f"resumed {state['path']} at iteration {self.counters.iteration}, "
                 f"frames {self.counters.frames:,} -> run dir {self.run_dir}")  # fmt: skip

    def _open_logger(self, demos: dict | None) -> None:
        """The run's logger (``log.backend``); a new run records its config, source, demos and parent (a
        continued run drops what the killed run logged after its checkpoint)."""
        tc, run_dir = self.tc, self.run_dir
        continued = self.state is not None and self.parent is None
        purge = self.counters.frames + 1 if continued else None
        self.logger = RunLogger(run_dir, purge_step=purge, backend=tc.log.backend,
                                backend_args=tc.log.backend_args)  # fmt: skip
        before = (yaml.safe_load(self.state["config"]) or {}).get("log", {}) if continued else {}
        if (
            before.get("backend", tc.log.backend) != tc.log.backend
        ):  # log.* comes from the command line
            log.info(f"log.backend: {tc.log.backend} from here on; the earlier sessions logged "
                     f"to {before['backend']} (resume with log.backend={before['backend']} to "
                     "keep one log)")  # fmt: skip
        if not continued:
            self.logger.config(self.cfg_yaml, asdict(tc), hparam_metrics(0.0, 0.0))
            (run_dir / "source.json").write_text(json.dumps(self.source) + "\n")
            if demos:
                (run_dir / "demos.json").write_text(json.dumps(demos, indent=2) + "\n")
            if self.parent:
                write_parent(run_dir, self.parent)
        log.info(f"run dir: {run_dir}; batch {tc.collector.frames_per_batch:,} frames/iteration; "
                 f"{torch.get_num_threads()} torch threads")  # fmt: skip

    # ------------------------------------------------------------------ the loop
    @property
    def minutes(self) -> float:
        """Wall clock of this session [min]."""
        return (time.monotonic() - self.session_start) / 60.0

    @property
    def run_minutes(self) -> float:
        """Wall clock of the run [min]: the earlier sessions' (to their last checkpoint) and
        this one's, each from its start (demonstrations included)."""
        return (self.wall_at_start + time.monotonic() - self.session_start) / 60.0

    def stop_reason(self) -> str | None:
        """Why the run stops now (a signal, quality, difficulty, frames, minutes), or None."""
        tc, cur = self.tc, self.curriculum
        quality = tc.stop_on_quality and self.quality.reached is not None
        return self.stop.name or stop_reason(self.counters.frames, self.minutes, cur.difficulty,
                                             tc.total_frames, tc.max_minutes, tc.stop_difficulty,
                                             quality)  # fmt: skip

    def _span(self, timings: dict | None, name: str, since: float) -> float:
        """End span ``name`` begun at ``since`` (waiting for the device first when syncing)."""
        if self.sync_timings and self.tc.device.startswith("cuda"):
            torch.cuda.synchronize(self.tc.device)
        now = time.perf_counter()
        if timings is not None:
            timings[name] = now - since
        return now

    def iterate(self, timings: dict | None = None) -> dict[str, float]:
        """One collection, curriculum step and PPO update, then the scalars, video, held-out
        check and checkpoint that are due. Returns the iteration's metrics (frames, ``perf/*``,
        the update's losses); ``timings`` receives :data:`SPANS` and the update's spans [s].

        A stop signal during the collection raises KeyboardInterrupt (the partial batch is
        dropped); :meth:`close` with the reason then saves.
        """
        tc, cur, counters = self.tc, self.curriculum, self.counters
        t0 = time.perf_counter()
        with self.stop.interruptible():  # a signal here drops the partial batch at once
            batch = next(self.batches)
        t1 = self._span(timings, "collect_s", t0)

        # Episode statistics and curriculum
        collection.check_difficulty(batch, cur.difficulty)
        stats = self.tracker.update(batch)
        promoted = cur.update(*self.feed.update(batch))
        if promoted:
            self.tolerance = collection.set_difficulty(self.env, cur.difficulty)
            log.info(f"difficulty {cur.difficulty:g} ({self.tolerance[0]:.3g} m, "
                     f"{self.tolerance[1]:.3g} deg) at {self.minutes:.1f} min, "
                     f"{counters.frames:,} frames")  # fmt: skip
        t_stats = self._span(timings, "stats_s", t1)

        # PPO update
        self.ppo.bc_coeff = bc_weight(tc.demos, counters.frames)
        learn = self.ppo.update(batch, timings=timings)
        if "loss_bc" in learn:
            learn["bc_coeff"] = self.ppo.bc_coeff
        t_update = self._span(timings, "update_s", t_stats)
        self.collector.update_policy_weights_()
        t2 = self._span(timings, "weights_s", t_update)

        frames = batch.numel()
        counters.iteration += 1
        counters.frames += frames
        timing = {"perf/fps": frames / (t2 - t0), "perf/fps_collect": frames / (t1 - t0),
                  "perf/collect_s": t1 - t0, "perf/learn_s": t2 - t1}  # fmt: skip
        if counters.iteration % tc.log.interval == 0 or promoted:
            shown = {**cur.state_dict(), "tolerance_position_m": self.tolerance[0],
                     "tolerance_heading_deg": self.tolerance[1]}  # fmt: skip
            scalars = iteration_scalars(stats, learn, shown, timing, self.task.error_quantities)
            self.logger.scalars(scalars, counters.frames)
        self.progress.update(counters.frames, self.minutes, cur.difficulty, cur.ema,
                             timing["perf/fps"])  # fmt: skip
        t_log = self._span(timings, "log_s", t2)
        self._periodic(t0, frames)
        self._span(timings, "periodic_s", t_log)
        return {"frames": float(frames), "promoted": float(promoted), **timing, **learn}

    def _periodic(self, t0: float, frames: int) -> None:
        """What is due after the iteration begun at ``t0`` that collected ``frames`` frames: a
        video, a held-out check (and best.pt when it beats every earlier one), last.pt."""
        tc, cur, counters = self.tc, self.curriculum, self.counters
        if self.video_ok and self.logger.video_due(counters.iteration, tc.log.video_interval):
            self.video_ok = self.logger.rollout_video(
                self.ac.actor, tc.env, cur.difficulty, tc.seed, tc.log.video_steps, tc.device,
                counters.iteration, counters.frames, tc.log.video_fps,
            )  # fmt: skip
        # Held-out scenes every log.eval_interval_frames frames, else every log.eval_interval_min
        # minutes (truckrl/evaluation/heldout.py)
        if tc.log.eval_interval_frames is not None:
            due = frames_due(tc.log.eval_interval_frames, counters.frames, frames)
        else:
            elapsed, window = time.monotonic() - self.session_start, time.perf_counter() - t0
            due = heldout_due(tc.log.eval_interval_min, elapsed, window)
        if due:
            evals = heldout_scalars(
                self.ac.actor, tc.env, cur.difficulty, tc.log.eval_episodes, tc.device
            )
            self.logger.scalars(evals, counters.frames)
            self._check_quality(evals["eval/success_rate"], float(cur.difficulty))
            record = (float(cur.difficulty), evals["eval/success_rate"])
            if tc.checkpoint.keep_best and (self.best_so_far is None or record > self.best_so_far):
                self.best_so_far = record
                self.save(best={"difficulty": record[0], "success_rate": record[1],
                                "frames": counters.frames})  # fmt: skip
                log.info(f"best.pt: held-out success {record[1]:.3f} at difficulty "
                         f"{record[0]:g} ({counters.frames:,} frames)")  # fmt: skip
        if counters.iteration % tc.checkpoint.interval == 0:
            self.save()

    def _check_quality(self, success_rate: float, difficulty: float) -> None:
        """Log ``quality_reached`` (a line and ``quality/*`` scalars) when this held-out check is
        the run's first to meet the target; the record goes into the counters (checkpoints)."""
        counters = self.counters
        reached = self.quality.check(success_rate, difficulty, self.run_minutes,
                                     counters.frames, counters.iteration)  # fmt: skip
        if reached is not None:
            counters.quality = dict(reached)
            self.logger.scalars(self.quality.scalars(), counters.frames)
            log.info(self.quality.line())

    # ------------------------------------------------------------------ saving and closing
    def save(self, final: bool = False, best: dict | None = None) -> None:
        """Write last.pt (and iter_XXXXXX.pt when due or ``final``); with ``best``, only best.pt.

        Raises:
            CheckpointError: the file cannot be written (the last good one stays intact).
        """
        counters = self.counters
        counters.wall_time_s = self.wall_at_start + time.monotonic() - self.session_start
        ckpt_dir = self.run_dir / ckpt.CHECKPOINT_DIR
        paths = [ckpt_dir / (ckpt.BEST_NAME if best else ckpt.LAST_NAME)]
        keep = self.tc.checkpoint.keep_every
        if keep and not best and (counters.iteration % keep == 0 or final):
            paths.append(ckpt_dir / f"iter_{counters.iteration:06d}.pt")
        for p in paths:
            try:
                ckpt.save_training_state(
                    p, model=self.ac.model, ppo=self.ppo, curriculum=self.curriculum,
                    counters=asdict(counters), config_yaml=self.cfg_yaml, num_obs=self.num_obs,
                    num_beams=self.num_beams, source=self.source, heldout=best,
                )  # fmt: skip
            except OSError as e:  # full disk, lost permission: stop; the last good one is intact
                why = f"{e.strerror or e}; the last good checkpoint is intact: "
                why += self.stop.last_checkpoint
                raise ckpt.CheckpointError(f"cannot write checkpoint {p} ({why})") from None
        if not best:
            self.stop.last_checkpoint = str(paths[0])

    def close(self, reason: str | None) -> None:
        """End the session: with a ``reason``, the final checkpoint and the hyper-parameter
        table; always the progress bar, logger, collector and env workers (after an error,
        ``reason`` None, the last good checkpoint stays)."""
        self.progress.close()
        try:
            if reason is not None:
                self.save(final=True)
                final = hparam_metrics(self.curriculum.difficulty, self.curriculum.ema)
                self.logger.final(asdict(self.tc), final, self.counters.frames)
        finally:
            self.logger.close()
            self.collector.shutdown()
            if not self.env.is_closed:
                self.env.close()

    def final_lines(self, reason: str | None) -> list[str]:
        """The last lines of the session: why it stopped, where its checkpoint is, what next."""
        return stop_lines(reason, self.run_dir, self.counters.iteration, self.counters.frames,
                          self.minutes, self.curriculum.difficulty, self.quality.line())  # fmt: skip


def fixed_order_gradients(device: Any) -> None:
    """On a CPU, torch's deterministic algorithms for this process: the compiled loss's backward
    then sums the LiDAR encoder's weight gradients (gathered into its ring matrix,
    :class:`~truckrl.rl.network.LidarEncoder`) in a fixed order instead of with atomic adds from
    several threads, so the same seed and threads repeat a run at any thread count. Other
    devices keep torch's default."""
    if torch.device(device).type == "cpu":
        torch.use_deterministic_algorithms(True, warn_only=True)


def frames_due(interval: int, frames: int, window: int) -> bool:
    """Whether a multiple of ``interval`` frames was passed by the last ``window`` frames, with
    ``frames`` the run's total (all sessions) after them.

    Called once per iteration with ``window`` = the iteration's frames, it is true at the first
    iteration that ends at or past each multiple, with no state to keep; a resumed run keeps the
    schedule, since ``frames`` counts every session.
    """
    return frames // interval > max(frames - window, 0) // interval


def bc_weight(dc: Any, frames: int) -> float:
    """The cloning term's weight after ``frames`` frames: ``dc.bc_coeff`` falling linearly to 0
    at ``dc.bc_frames`` (``DemosConfig`` in ``truckrl.config.schemas``)."""
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
    (``truckrl.rl.imitation.bootstrap``); returns its summary and the samples. A demonstrator that
    solves nothing is a one-line :class:`ConfigError`."""
    from truckrl.rl.imitation import bootstrap

    dc = tc.demos
    how = "planning" if dc.source == "planner" else "driving (the task's scripted driver)"
    log.info(f"demonstrations: {how} {dc.episodes} scenes (seed {dc.seed}) at difficulty "
             f"{dc.difficulty:g}, then behaviour cloning")  # fmt: skip
    last = [time.monotonic()]

    def progress(done: int, total: int) -> None:
        if time.monotonic() - last[0] > 30.0 or done == total:
            last[0] = time.monotonic()
            log.info(f"  planner: {done}/{total} scenes")

    def on_round(r: int, d: dict) -> None:
        log.info(f"DAgger round {r}: the clone solved {d['clone_success_rate']:.1%} of "
                 f"{d['scenes']} scenes, {d['samples_added']:,} states labelled, action MSE "
                 f"{d['losses'][-1]:.4f}, {d['seconds'] / 60:.1f} min")  # fmt: skip

    try:
        demos, samples = bootstrap(ac, tc.env, dc, tc.device, tc.seed, progress, on_round)
    except ValueError as e:
        env.close()  # the workers, before the one-line error
        raise ConfigError(f"demos: {e}") from None
    log.info(f"demonstrations: {demos['plans_kept']} of {dc.episodes} scenes solved, "
             f"{demos['samples']:,} samples, action MSE {demos['losses'][0]:.4f} -> "
             f"{demos['losses'][-1]:.4f}, {demos['seconds'] / 60:.1f} min")  # fmt: skip
    return demos, samples
