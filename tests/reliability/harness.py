"""Shared helpers of the reliability tests: tiny in-process training sessions, signals sent at
chosen moments, entry points run in-process with their exit code and output, checkpoint checks.

In-process runs share one interpreter (torch and TorchRL load once), so a whole table of cases
costs seconds; the few things only a real process shows (a second signal's hard exit, worker
processes, start-up time) run as subprocesses in the tests that need them.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from tests.conftest import TINY_TRAIN, compose_config
from truckrl.cli import to_config
from truckrl.config.schemas import TrainConfig
from truckrl.rl.checkpoint import load_checkpoint

SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}

#: TINY_TRAIN with two epochs, so that a PPO update spans several optimizer steps.
EPOCHS, MINIBATCHES = 2, 2
TINY = [*TINY_TRAIN, f"ppo.num_epochs={EPOCHS}", f"ppo.num_minibatches={MINIBATCHES}"]
BATCH = 16 * 16


def tiny_config(*overrides: str) -> TrainConfig:
    return to_config(TrainConfig, compose_config("train", *TINY, *overrides))


def run_session(run_dir: Path, *overrides: str):
    """One in-process training session (``truckrl.train.run``) in ``run_dir``."""
    from truckrl.train import run

    return run(tiny_config(*overrides), run_dir, explicit_dir=True)


def checkpoint_summary(run_dir: Path) -> dict:
    """Counters of ``last.pt`` and the optimizer steps every parameter took."""
    state = load_checkpoint(run_dir)
    steps = {int(v["step"]) for v in state["ppo"]["optimizer"]["state"].values()}
    return {**state["counters"], "adam_steps": steps or {0}, "curriculum": state["curriculum"]}


def assert_consistent(run_dir: Path, batch: int = BATCH) -> dict:
    """The saved counters match the optimizer: Adam step == iterations x epochs x minibatches."""
    s = checkpoint_summary(run_dir)
    assert s["adam_steps"] == {s["iteration"] * EPOCHS * MINIBATCHES}, s
    assert s["frames"] == s["iteration"] * batch, s
    assert not list((run_dir / "checkpoints").glob(".*.tmp")), "temp file left behind"
    return s


#: Where a signal can be sent from inside a session, and the function patched to send it.
PHASES = {
    "start": ("truckrl.rl.collection", "make_env"),
    "collect": ("truckrl.env.TruckEnv", "_step"),
    "update": ("torch.optim.Adam", "step"),
    "curriculum": ("truckrl.rl.curriculum.Curriculum", "update"),
    "save": ("truckrl.rl.checkpoint", "save_checkpoint"),
    "log": ("truckrl.rl.logger.RunLogger", "scalars"),
}


def signal_at(monkeypatch, phase: str, occurrence: int, signum: int) -> dict:
    """Send ``signum`` to this process at the ``occurrence``-th call of the phase's function
    (before it runs its body). Returns a dict whose "sent" says whether it fired."""
    import importlib

    where, name = PHASES[phase]
    module_name, _, cls_name = where.rpartition(".")
    try:
        owner = getattr(importlib.import_module(module_name), cls_name)
    except (ImportError, AttributeError):
        owner = importlib.import_module(where)
    original = getattr(owner, name)
    state = {"calls": 0, "sent": False}

    def wrapper(*args, **kwargs):
        state["calls"] += 1
        if state["calls"] == occurrence and not state["sent"]:
            state["sent"] = True
            os.kill(os.getpid(), signum)  # the handler runs before the next line
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, wrapper)
    return state


@dataclass
class Result:
    code: int
    out: str
    err: str

    @property
    def err_lines(self) -> list[str]:
        return [ln for ln in self.err.splitlines() if ln.strip()]


def run_main(capsys, module: str, *args: str) -> Result:
    """``python -m truckrl.<module> args...`` in this process: exit code, stdout, stderr."""
    import importlib

    mod = importlib.import_module(f"truckrl.{module}")
    argv, threads = sys.argv, torch.get_num_threads()  # play sets the thread count
    handlers = {s: signal.getsignal(s) for s in SIGNALS.values()}  # train ignores them at exit
    # Hydra points the root logger at this test's captured streams; a later test logging
    # through those handlers would write to closed files
    root = logging.getLogger()
    log_handlers, log_level = root.handlers[:], root.level
    sys.argv = [f"truckrl/{module}.py", *args]
    capsys.readouterr()
    code = 0
    try:
        mod.main()
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    finally:
        sys.argv = argv
        torch.set_num_threads(threads)
        for s, h in handlers.items():
            signal.signal(s, h)
        for h in root.handlers:
            if h not in log_handlers:
                h.close()
        root.handlers[:] = log_handlers
        root.setLevel(log_level)
        with contextlib.suppress(Exception):
            from hydra.core.global_hydra import GlobalHydra

            GlobalHydra.instance().clear()
    captured = capsys.readouterr()
    return Result(code, captured.out, captured.err)


def assert_one_line_error(r: Result, *fragments: str) -> str:
    """Exit 2, exactly one non-empty stderr line ``error: ...`` holding every fragment."""
    assert r.code == 2, (r.code, r.out[-2000:], r.err[-2000:])
    assert "Traceback" not in r.err + r.out, r.err
    assert len(r.err_lines) == 1, r.err
    line = r.err_lines[0]
    assert line.startswith("error: "), line
    assert "weights_only=False" not in line
    for f in fragments:
        assert f in line, (f, line)
    return line


#: Environment of subprocess runs: one torch thread (see conftest.py).
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
