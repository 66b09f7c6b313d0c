"""``truckrl train``: PPO on TruckEnv with the success curriculum (the paper's setup).

    truckrl train                                         # experiment=demos (CPU), paper curriculum
    truckrl train resume=outputs/DATE/TIME      # continue a stopped run
    truckrl train --help                                  # options and examples

The loop is a :class:`~truckrl.rl.trainer.Trainer`: each iteration collects ``collector.workers
x num_envs x steps_per_env`` frames, feeds finished episodes to the curriculum in start order
(:mod:`truckrl.rl.cohorts`; a promotion reaches every worker before the next collection), runs
the PPO update and logs to ``<run_dir>/tb``.
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
checkpoint's state and saved config but for what the command line sets of
:data:`~truckrl.config.schemas.RESUME_OVERRIDES` (a resume without ``total_frames`` keeps the
run's frame budget); an older checkpoint branches into a new run dir. ``total_frames`` counts
all sessions, ``max_minutes`` this one. The envs restart with fresh episodes seeded from ``(seed,
iteration)``: a faithful continuation, not a bit-identical one.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import yaml

from truckrl.cli import hydra_entry, workers_ignore_stop_signals

#: ``time.monotonic()`` when ``truckrl train`` started (this module's import, before Hydra and
#: torch load); the first job of the process measures its minutes from here.
_STARTED = [time.monotonic()]
workers_ignore_stop_signals(__name__)  # ParallelEnv workers: this process stops and closes them
log = logging.getLogger("truckrl.train")


def train(tc: Any, run_dir: Path, state: dict | None = None, parent: dict | None = None,
          stop: Any = None, init: dict | None = None, started: float | None = None) -> Any:  # fmt: skip
    """Run (or, with a loaded checkpoint ``state``, resume) one training job; return its counters.
    ``stop``: installed :class:`~truckrl.rl.session.StopSignals` (:func:`run` installs them).
    ``init``: a loaded checkpoint whose network weights start a new run (``tc.init``; ignored
    when resuming). ``started``: ``time.monotonic()`` at the session's start, from which its
    minutes count (default: now). The job is a :class:`~truckrl.rl.trainer.Trainer`, iterated
    until a stop reason; a signal ends it at the next iteration boundary (during a collection,
    at once) with a checkpoint.
    """
    started = time.monotonic() if started is None else started
    # Heavy imports here, not at module level: `--help` and config errors answer before they load
    import torch

    from truckrl.cli import git_revision, seed_everything
    from truckrl.rl.session import StopSignals
    from truckrl.rl.trainer import Trainer

    if tc.threads is not None:  # before any torch work: a reduction's order depends on it
        torch.set_num_threads(tc.threads)
    stop = stop or StopSignals()
    source = git_revision()  # once: checkpoints record the commit the session started from
    trainer = Trainer(tc, run_dir, state, parent, stop, init, source, started=started)
    seed_everything(tc.seed)
    trainer.setup()
    reason = None  # why the loop ended; None after an error (the last good checkpoint stays)
    try:
        while (reason := trainer.stop_reason()) is None:
            trainer.iterate()
    except KeyboardInterrupt:  # raised by StopSignals while collecting (or with no handlers)
        reason = stop.name or "SIGINT"
    finally:
        trainer.close(reason)
    for line in trainer.final_lines(reason):
        log.info(line)
    stop.hand_over()  # under submitit: requeue the job (it resumes by itself)
    return trainer.counters


def run(
    tc: Any,
    job_dir: Path,
    explicit_dir: bool = True,
    started: float | None = None,
    given: tuple[str, ...] | None = None,
) -> Any:
    """Plan the session (run dir, resume or branch; :func:`~truckrl.rl.session.plan_session`)
    and train; ``tc.resume``'s checkpoint supplies the config but for ``RESUME_OVERRIDES``, of
    which a resume takes only what its command line sets (``given``, the dotted paths of its
    overrides; None: all of them, :func:`~truckrl.rl.session.resumed_config`).
    ``started``: ``time.monotonic()`` at the session's start (default: now)."""
    started = time.monotonic() if started is None else started
    from truckrl.config.schemas import RESUME_OVERRIDES, TrainConfig
    from truckrl.rl.checkpoint import load_training_state
    from truckrl.rl.logger import check_backend
    from truckrl.rl.session import StopSignals, merged_config, plan_session

    check_backend(
        tc.log.backend, tc.log.backend_args
    )  # a missing extra: one line before any work (log: as given)
    stop = StopSignals().install()  # from here on a signal stops at the next iteration boundary
    try:
        plan = plan_session(tc.resume, tc.overwrite, job_dir, explicit_dir)
        if plan.state:
            tc = merged_config(plan.state, asdict(tc), TrainConfig, RESUME_OVERRIDES, log, given)
            tc.check_stops()
        init = load_training_state(tc.init) if tc.init and not plan.state else None
        return train(tc, plan.run_dir, plan.state, plan.parent, stop, init, started)
    finally:
        stop.restore()


def prepare_argv(argv: list[str]) -> list[str]:
    """``train_env.FIELD=VALUE`` and ``log.backend_args.KEY=VALUE`` as Hydra's ``+...`` (a key
    of a free-form dict), then the run-dir checks of :func:`truckrl.rl.session.prepare_argv`."""
    from truckrl.cli import plus_overrides
    from truckrl.rl.session import prepare_argv as check_run_dir

    argv = plus_overrides(plus_overrides(argv, "train_env."), "log.backend_args.")
    return check_run_dir(argv)


@hydra_entry("train", "TrainConfig", prepare="truckrl.train:prepare_argv")
def main(tc: Any, raw: Any) -> float:
    """Train; return :func:`~truckrl.rl.progress.sweep_objective` of the run's last checkpoint
    (what a sweeper such as ``+launch=optuna`` optimizes)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from truckrl.rl.checkpoint import load_checkpoint
    from truckrl.rl.progress import sweep_objective
    from truckrl.rl.session import ignore_stop_signals, override_paths

    hc = HydraConfig.get()
    named = any(o.startswith("hydra.run.dir=") for o in hc.overrides.hydra)
    started = _STARTED.pop() if _STARTED else None  # a sweep's later jobs: their own start
    run_dir = Path(hc.runtime.output_dir)  # a resume in place runs Hydra in the run dir
    given = override_paths(list(hc.overrides.task))
    run(tc, run_dir, explicit_dir=hc.mode == RunMode.RUN and named, started=started, given=given)
    ignore_stop_signals()  # the run is over: a late Ctrl-C must not turn the exit into a traceback
    state = load_checkpoint(run_dir)  # the run's last.pt: its config (a resume's) and curriculum
    cc = yaml.safe_load(state["config"])["curriculum"]
    return sweep_objective(state["curriculum"], cc["threshold"], cc["step"])


if __name__ == "__main__":
    main()
