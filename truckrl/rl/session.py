"""What a training session does around its loop: stop signals, the run dir and resuming.

**Signals.** SIGINT, SIGTERM and SIGUSR2 (what SLURM sends through submitit before a time limit)
only set a flag (:class:`StopSignals`); the loop stops at the next iteration boundary, writes the
checkpoint and exits 0, so an interrupt never lands inside the PPO update or a checkpoint write.
While a batch is being collected, which changes nothing that is saved, the first signal raises
``KeyboardInterrupt`` at once and the partial batch is dropped: stopping does not wait for a whole
collection (or the first compile). A second signal exits at once (code 128 + signal) after killing
the env workers; the last checkpoint is intact (atomic writes) and a half-written temp file is
removed at the next start. ParallelEnv workers ignore these signals
(:func:`truckrl.cli.workers_ignore_stop_signals`): a Ctrl-C to the process group stops only the
trainer, which closes them. Under submitit, SIGUSR2 hands over to submitit's own handler (requeue the job) once
the checkpoint is written.

**Run dirs** (:func:`plan_session`). A run dir holding ``checkpoints/last.pt`` is only ever
continued by ``resume``; starting there without it is refused (or ``overwrite=true`` clears the
old run). Resuming from the newest checkpoint of a run continues in that run dir; resuming from
anything older (a kept ``iter_XXXXXX.pt``, a copied file) branches into a new run dir that
records its parent in ``parent.json``, so newer state is never overwritten. ``resume=auto``
continues the run dir's own checkpoint when there is one and starts fresh otherwise (what a
requeued SLURM job does).
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from truckrl.config.fields import ConfigError, build
from truckrl.rl.checkpoint import (
    CHECKPOINT_DIR,
    LAST_NAME,
    PRETRAINED_PREFIX,
    TMP_SUFFIX,
    CheckpointError,
    shipped_task,
)

#: Signals that stop training at the next iteration boundary.
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGUSR2") if hasattr(signal, name)
)
#: What a training run writes into its run dir (cleared by ``overwrite=true``).
RUN_OUTPUTS = (CHECKPOINT_DIR, "tb", "videos", "source.json", "parent.json")
RUN_OUTPUTS += ("demos.json", "demos.pt")  # the demonstrations' summary and samples (imitation)
RUN_OUTPUTS += ("csv", "wandb", "mlflow.db", "mlartifacts", "logger.json")  # other log.backends
PARENT_FILE = "parent.json"
AUTO = "auto"


class StopSignals:
    """Flag-setting handlers for :data:`STOP_SIGNALS` (see the module doc).

    Attributes:
        signum: the first stop signal received (None until then).
        collecting: True while a batch is collected; a first signal then raises KeyboardInterrupt.
        last_checkpoint: shown when a second signal exits at once.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self.collecting = False
        self.last_checkpoint = "none written yet"
        self._previous: dict[int, Any] = {}

    @property
    def name(self) -> str | None:
        return None if self.signum is None else signal.Signals(self.signum).name

    def install(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for s in STOP_SIGNALS:
                self._previous[s] = signal.signal(s, self._handle)
        return self

    def restore(self) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
        self._previous.clear()

    @contextlib.contextmanager
    def interruptible(self) -> Iterator[None]:
        """Let a first signal raise KeyboardInterrupt inside the block (used around collection)."""
        self.collecting = True
        try:
            if self.signum is not None:
                raise KeyboardInterrupt
            yield
        finally:
            self.collecting = False

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signum is not None:
            name = signal.Signals(signum).name
            print(
                f"second signal ({name}): exiting now; last checkpoint: {self.last_checkpoint}",
                file=sys.stderr,
                flush=True,
            )
            for child in multiprocessing.active_children():  # env workers: none left spinning
                child.kill()
            os._exit(128 + signum)
        self.signum = signum
        if self.collecting:
            raise KeyboardInterrupt

    def hand_over(self) -> None:
        """After the checkpoint is written: call the launcher's own SIGUSR2 handler, if any.

        submitit's handler requeues the job and exits; the requeued job resumes by itself
        (``resume=auto`` in ``conf/launch/slurm.yaml``).
        """
        usr2 = getattr(signal, "SIGUSR2", None)
        previous = self._previous.get(usr2)
        if self.signum == usr2 and callable(previous):
            previous(usr2, None)


def ignore_stop_signals() -> None:
    """Ignore :data:`STOP_SIGNALS` from now on (the process is about to exit)."""
    if threading.current_thread() is threading.main_thread():
        for s in STOP_SIGNALS:
            signal.signal(s, signal.SIG_IGN)


# ---------------------------------------------------------------------------------- run dirs
def run_dir_of(checkpoint: Path) -> Path:
    """The run dir of a checkpoint file (``<run>/checkpoints/last.pt`` -> ``<run>``).

    A policy shipped in the package (``checkpoint=pretrained[:<task>]``) has no run dir; its
    outputs (evaluation JSON, exports) go to ``outputs/pretrained/<task>`` under the current
    directory instead of into the installed package.
    """
    task = shipped_task(checkpoint)
    if task is not None:
        return Path("outputs") / PRETRAINED_PREFIX / task
    parent = checkpoint.parent
    return parent.parent if parent.name == CHECKPOINT_DIR else parent


def last_checkpoint(run_dir: Path) -> Path | None:
    """``<run_dir>/checkpoints/last.pt`` if it exists."""
    p = run_dir / CHECKPOINT_DIR / LAST_NAME
    return p if p.is_file() else None


def is_newest(checkpoint: Path) -> bool:
    """True when ``checkpoint`` is its run's newest state: ``checkpoints/last.pt`` itself, or a
    kept ``iter_XXXXXX.pt`` of the same iteration as ``last.pt`` (loaded to compare)."""
    from truckrl.rl.checkpoint import load_checkpoint

    if checkpoint.parent.name != CHECKPOINT_DIR:
        return False
    last = checkpoint.parent / LAST_NAME
    if checkpoint.resolve() == last.resolve():
        return True
    if not last.is_file():
        return False
    try:
        ours = load_checkpoint(checkpoint)["counters"]["iteration"]
        newest = load_checkpoint(last)["counters"]["iteration"]
    except (CheckpointError, KeyError, TypeError):
        return False
    return ours == newest


def check_dir_usable(path: Path, what: str = "run dir") -> None:
    """Check ``path`` is, or can be made as, a writable directory (nothing is left behind).

    Raises:
        ConfigError: one line naming the path and the reason.
    """
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{what} {path} is a file, not a directory")
    ancestor = path
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ConfigError(f"{what} {path} cannot be made: {ancestor} is a file")
    try:
        with tempfile.TemporaryFile(dir=ancestor, prefix=".truckrl-probe-"):
            pass
    except OSError as e:
        raise ConfigError(
            f"{what} {path} is not writable ({ancestor}: {e.strerror or e})"
        ) from None


def reuse_refusal(run_dir: Path) -> ConfigError:
    """The error for starting a new run where a checkpoint already is."""
    return ConfigError(
        f"run dir {run_dir} already holds a checkpoint ({CHECKPOINT_DIR}/{LAST_NAME}): continue "
        f"it with `truckrl train resume={run_dir}`, or start a new run in another dir "
        "(hydra.run.dir=...) or here with overwrite=true (deletes its checkpoints and TensorBoard "
        "logs)"
    )


def clear_run(run_dir: Path) -> None:
    """Delete what an earlier training run wrote into ``run_dir`` (``overwrite=true``)."""
    for name in RUN_OUTPUTS:
        p = run_dir / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def clean_stale_temp_files(ckpt_dir: Path) -> list[Path]:
    """Remove hidden ``.<name>.pt.*.tmp`` files a killed checkpoint write left behind."""
    stale = [p for p in ckpt_dir.glob(f".*.pt.*{TMP_SUFFIX}") if p.is_file()]
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


def check_checkpoint_dir(run_dir: Path) -> Path:
    """Create ``<run_dir>/checkpoints`` and check a file can be written there; return it.

    Raises:
        ConfigError: the run dir or its checkpoint dir cannot be written.
    """
    ckpt_dir = run_dir / CHECKPOINT_DIR
    check_dir_usable(run_dir)
    check_dir_usable(ckpt_dir, "checkpoint dir")
    try:
        ckpt_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"checkpoint dir {ckpt_dir} cannot be made ({e.strerror or e})") from None
    return ckpt_dir


@dataclass
class Counters:
    """Training progress saved in every checkpoint (``counters``).

    ``wall_time_s`` [s] sums the sessions, each from its process's start (demonstrations
    included) to its last checkpoint; the time a run lay stopped between sessions is not in it.
    ``quality``: the run's ``quality_reached`` record (:class:`truckrl.rl.progress.Quality`), or
    None until then; kept so a resumed run neither fires it again nor loses it.
    """

    iteration: int = 0
    frames: int = 0
    wall_time_s: float = 0.0
    quality: dict | None = None


#: Keys a resumed session always takes from its own command line: they say how to start it.
SESSION_KEYS = ("resume", "overwrite")


def override_paths(overrides: list[str]) -> tuple[str, ...]:
    """The dotted config paths a command line's ``KEY=VALUE`` overrides set (``+``, ``++`` and
    ``~`` prefixes dropped): ``["+log.backend_args.x=1"]`` -> ``("log.backend_args.x",)``."""
    return tuple(o.split("=", 1)[0].lstrip("+~") for o in overrides if "=" in o)


def resumed_config(
    saved: dict,
    current: dict,
    keep: tuple[str, ...],
    log: Any,
    given: tuple[str, ...] | None = None,
) -> dict:
    """The checkpoint's config with the keys ``keep`` taken from ``current`` (logs the others).

    ``given``: the dotted paths the command line set (:func:`override_paths`). With it, a key of
    ``keep`` comes from ``current`` only at the paths given there (and :data:`SESSION_KEYS`
    always), so a resume without ``total_frames`` keeps the run's frame budget and one with
    ``log.progress_bar=false`` keeps the run's other ``log`` values; None (a caller without a
    command line): every key of ``keep`` from ``current``.
    """
    current = _plain(current)
    ignored = sorted(
        k for k in set(current) | set(saved) if k not in keep and current.get(k) != saved.get(k)
    )
    if ignored:
        log.info(f"resume: keeping the checkpoint's {', '.join(ignored)} (command line differs)")
    if given is None:
        return {**saved, **{k: current[k] for k in keep if k in current}}
    out = {**saved, **{k: current[k] for k in SESSION_KEYS if k in current}}
    for path in given:
        *parents, leaf = path.split(".")
        if (parents or [leaf])[0] not in keep:
            continue  # logged above where it differs
        src, dst = current, out
        for name in parents:
            src = src.get(name) if isinstance(src, dict) else None
            dst[name] = dict(dst.get(name) or {})  # a copy: the saved config is not written to
            dst = dst[name]
        if isinstance(src, dict) and leaf in src:
            dst[leaf] = src[leaf]
    return out


def merged_config(
    state: dict,
    current: dict,
    schema: type,
    keep: tuple[str, ...],
    log: Any,
    given: tuple[str, ...] | None = None,
) -> Any:
    """The config a resumed session runs with (:func:`resumed_config`), built as ``schema``.

    Raises:
        CheckpointError: the checkpoint's part of it is not a valid config.
    """
    from truckrl.rl.policy import saved_config

    try:
        return build(schema, resumed_config(saved_config(state), current, keep, log, given))
    except ConfigError as e:
        raise CheckpointError(f"{state['path']}: its saved config is invalid ({e})") from None


def _plain(x: Any) -> Any:
    """Tuples as lists, recursively (a config as its saved YAML reads back)."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    return [_plain(v) for v in x] if isinstance(x, list | tuple) else x


@dataclass
class Plan:
    """Where a session writes and what it starts from.

    Attributes:
        run_dir: the run dir written to.
        state: the loaded checkpoint to start from (None: a new run).
        parent: for a branch, what it started from (``run_dir``, ``checkpoint``, ``iteration``).
    """

    run_dir: Path
    state: dict | None = None
    parent: dict | None = None


def plan_session(resume: str | None, overwrite: bool, job_dir: Path, explicit_dir: bool) -> Plan:
    """Decide the run dir and starting state (module doc), check the run dir, clean stale files.

    Args:
        resume: ``TrainConfig.resume`` (a checkpoint, a run dir, ``auto`` or None).
        overwrite: ``TrainConfig.overwrite``.
        job_dir: the dir Hydra made for this job.
        explicit_dir: the user named ``job_dir`` (``hydra.run.dir=...``).

    Raises:
        ConfigError, CheckpointError: one line each, before anything is written.
    """
    from truckrl.rl.checkpoint import load_training_state, resolve_checkpoint

    if resume == AUTO:
        resume = str(job_dir) if last_checkpoint(job_dir) else None
    plan = Plan(job_dir)
    if resume:
        ckpt = resolve_checkpoint(resume)
        source = run_dir_of(ckpt)
        state = load_training_state(ckpt)
        newest = is_newest(ckpt)
        if newest and (source.resolve() == job_dir.resolve() or not explicit_dir):
            plan = Plan(source, state)
        else:
            counters = state["counters"]
            why = "the checkpoint's run dir" if newest else "not its run's newest checkpoint"
            parent = {"run_dir": str(source), "checkpoint": str(ckpt), "reason": why}
            plan = Plan(job_dir, state, {**parent, "iteration": counters["iteration"]})
    continuing = plan.state is not None and plan.parent is None
    if not continuing and last_checkpoint(plan.run_dir):
        if not overwrite:
            raise reuse_refusal(plan.run_dir)
        clear_run(plan.run_dir)
    ckpt_dir = check_checkpoint_dir(plan.run_dir)
    clean_stale_temp_files(ckpt_dir)
    return plan


def write_parent(run_dir: Path, parent: dict) -> None:
    """Record a branched run's origin in ``<run_dir>/parent.json``."""
    (run_dir / PARENT_FILE).write_text(json.dumps(parent, indent=2) + "\n")


# ---------------------------------------------------------------------------------- argv
def _value(text: str) -> str:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    return text


def _quote(path: str) -> str:
    """``path`` as a Hydra override value (quoted when it holds grammar characters)."""
    if all(ch.isalnum() or ch in "/._-+@~:" for ch in path):
        return path
    return "'" + path.replace("\\", "\\\\").replace("'", "\\'") + "'"


SHOW_FLAGS = ("--cfg", "-c", "--info", "-i", "--shell-completion", "-sc", "--hydra-help")


def prepare_argv(argv: list[str]) -> list[str]:
    """Command-line checks that must happen before Hydra makes or writes a run dir.

    For a single run: ``resume`` of a run's newest checkpoint without ``hydra.run.dir`` runs
    Hydra in that run dir (``hydra.run.dir=<run>``, no second ``.hydra`` copy); a named run dir
    is checked to be writable, and refused when it holds a checkpoint and neither ``resume`` nor
    ``overwrite=true`` is given, so Hydra never writes into it. Sweeps are checked per job.

    Raises:
        ConfigError, CheckpointError: one line each.
    """
    from truckrl.rl.checkpoint import resolve_checkpoint

    if any(a.split("=")[0] in SHOW_FLAGS for a in argv) or {"-m", "--multirun"} & set(argv):
        return argv
    kv = {}
    for a in argv:
        if "=" in a and not a.startswith("-"):
            key, value = a.split("=", 1)
            kv[key.lstrip("+~")] = _value(value)
    resume = kv.get("resume") if kv.get("resume") not in (None, "", "null") else None
    run_dir = kv.get("hydra.run.dir")
    extra: list[str] = []
    continuing = resume == AUTO
    if resume and resume != AUTO:
        ckpt = resolve_checkpoint(resume)
        source = run_dir_of(ckpt)
        same = run_dir is None or Path(run_dir).resolve() == source.resolve()
        continuing = same and is_newest(ckpt)
        if continuing and run_dir is None:
            run_dir = str(source)
            extra.append(f"hydra.run.dir={_quote(run_dir)}")
    if run_dir is None:
        return argv
    path = Path(run_dir)
    check_dir_usable(path)
    if last_checkpoint(path):
        if continuing:
            extra.append("hydra.output_subdir=null")  # keep the run's own .hydra/ config
        elif kv.get("overwrite", "false").lower() != "true":
            raise reuse_refusal(path)
    return argv + extra
