"""Stopping by signal: SIGINT / SIGTERM at random moments (inside collection, the PPO update, the
curriculum, a checkpoint write, logging) always end with a consistent checkpoint and exit 0; a
kill-and-resume loop loses nothing; a second signal exits at once with the last checkpoint intact;
ParallelEnv workers are closed quietly.

Signals are sent by this process to itself from inside the phase's own function (the handler runs
before that function's body), so "inside the update" is exactly that, and reproducible: the
random moments come from a seeded generator.
"""

from __future__ import annotations

import logging
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import ROOT
from tests.reliability.harness import (
    BATCH,
    ENV,
    PHASES,
    SIGNALS,
    TINY,
    assert_consistent,
    run_session,
    signal_at,
)
from truckrl.rl.checkpoint import load_checkpoint

#: Seeded "random moments": (signal, phase, occurrence of the phase's function).
RNG = random.Random(12)
MOMENTS = [
    (RNG.choice(list(SIGNALS)), phase, RNG.randint(1, max(1, 3 * calls)))
    for phase, calls in [("start", 0), ("collect", 16), ("update", 4), ("update", 4),
                         ("curriculum", 1), ("save", 1), ("log", 1)]
]  # fmt: skip


@pytest.mark.parametrize(("sig", "phase", "occurrence"), MOMENTS)
def test_signal_at_a_random_moment_saves_a_consistent_checkpoint(
    sig, phase, occurrence, tmp_path, monkeypatch, caplog
):
    sent = signal_at(monkeypatch, phase, occurrence, SIGNALS[sig])
    before = signal.getsignal(signal.SIGINT)
    caplog.set_level(logging.INFO, logger="truckrl.train")
    counters = run_session(tmp_path, "total_frames=1000000", "checkpoint.interval=1")
    assert sent["sent"], f"{phase} #{occurrence} never happened"
    s = assert_consistent(tmp_path)
    assert s["iteration"] == counters.iteration
    stop = [r.getMessage() for r in caplog.records if r.getMessage().startswith("stopped")]
    assert len(stop) == 1 and stop[0].startswith(f"stopped by {sig}"), stop
    assert f"resume: truckrl train resume={tmp_path}" in stop[0]
    assert str(tmp_path / "checkpoints" / "last.pt") in stop[0]
    assert signal.getsignal(signal.SIGINT) is before  # handlers restored


def test_kill_and_resume_loop_loses_nothing(tmp_path, monkeypatch):
    rng = random.Random(3)
    last = 0
    for round_ in range(4):
        with monkeypatch.context() as m:
            phase = rng.choice(sorted(PHASES))
            sent = signal_at(m, phase, rng.randint(1, 6), rng.choice(list(SIGNALS.values())))
            resume = [f"resume={tmp_path}"] if round_ else []
            run_session(tmp_path, "total_frames=1000000", "checkpoint.interval=2", *resume)
        s = assert_consistent(tmp_path)
        assert s["iteration"] >= last, (round_, phase, sent, s)
        last = s["iteration"]
    run_session(tmp_path, f"total_frames={(last + 2) * BATCH}", f"resume={tmp_path}")
    s = assert_consistent(tmp_path)
    assert s["iteration"] == last + 2
    acc = EventAccumulator(str(tmp_path / "tb"), purge_orphaned_data=True)
    acc.Reload()
    steps = [e.step for e in acc.Scalars("perf/fps")]
    assert steps == [BATCH * i for i in range(1, last + 3)]  # one value per iteration, no gaps


WRAPPER = """
import os, signal, sys, runpy, multiprocessing, time
import torch
calls = [0]
original = torch.optim.Adam.step
def step(self, *a, **k):
    calls[0] += 1
    if calls[0] == {fire_at}:
        print("workers:", ",".join(str(p.pid) for p in multiprocessing.active_children()), flush=True)
        print("signal at", time.time(), flush=True)
        {send}(signal.{sig})
        {second}
    return original(self, *a, **k)
torch.optim.Adam.step = step
sys.argv = ["truckrl/train.py"] + sys.argv[1:]
runpy.run_module("truckrl.train", run_name="__main__", alter_sys=True)
"""


def run_wrapped(tmp_path: Path, sig: str, fire_at: int, second: bool, *args: str, group=False):
    """Run training under WRAPPER: ``sig`` at the ``fire_at``-th optimizer step (inside an
    update), to the whole process group like a Ctrl-C with ``group``, twice with ``second``."""
    send = "lambda s: os.killpg(os.getpgrp(), s)" if group else "lambda s: os.kill(os.getpid(), s)"
    code = WRAPPER.format(
        fire_at=fire_at,
        sig=sig,
        send=f"({send})",
        second=f"os.kill(os.getpid(), signal.{sig})" if second else "",
    )
    cmd = [sys.executable, "-c", code, *TINY, "total_frames=1000000", "checkpoint.interval=1"]
    cmd += [f"hydra.run.dir={tmp_path}", *args]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=ENV,
                          start_new_session=True)  # its own process group  # fmt: skip
    end = time.time()
    sent = [float(ln.split()[-1]) for ln in proc.stdout.splitlines() if ln.startswith("signal at")]
    return proc, end - sent[0] if sent else float("nan")


def workers_of(stdout: str) -> list[int]:
    line = next(ln for ln in stdout.splitlines() if ln.startswith("workers:"))
    return [int(p) for p in line.split(":")[1].strip().split(",") if p]


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    with open(f"/proc/{pid}/stat") as f:  # a zombie awaiting its reaper is gone too
        return f.read().split(")")[1].split()[0] == "Z"


@pytest.mark.e2e
def test_second_signal_exits_at_once_and_keeps_the_last_checkpoint(tmp_path):
    proc, _ = run_wrapped(tmp_path, "SIGINT", 4 * 2 + 1, True)
    assert proc.returncode == 128 + signal.SIGINT, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr + proc.stdout
    assert "second signal (SIGINT): exiting now; last checkpoint:" in proc.stderr
    s = assert_consistent(tmp_path)  # written after iteration 2, before the signals
    assert s["iteration"] == 2


@pytest.mark.e2e
def test_ctrl_c_with_parallel_workers_stops_cleanly_and_quickly(tmp_path):
    """Ctrl-C reaches the whole process group: the workers ignore it, the trainer closes them."""
    proc, after = run_wrapped(tmp_path, "SIGINT", 4 + 2, False, "collector.workers=2", group=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr + proc.stdout
    stop = [ln for ln in proc.stdout.splitlines() if ln.startswith("stopped")]
    assert len(stop) == 1 and stop[0].startswith("stopped by SIGINT at iteration 2"), stop
    assert_consistent(tmp_path, 2 * BATCH)
    time.sleep(0.5)
    assert all(gone(pid) for pid in workers_of(proc.stdout))
    print(f"\nCtrl-C with 2 workers: exited {after:.1f} s after the signal")
    assert after < 20


def test_sigusr2_hands_over_to_the_launchers_handler_after_saving(tmp_path, monkeypatch, caplog):
    """What submitit does on SLURM: its SIGUSR2 handler requeues the job; ours saves first."""
    calls = []
    previous = signal.signal(signal.SIGUSR2, lambda s, f: calls.append(load_checkpoint(tmp_path)))
    try:
        signal_at(monkeypatch, "update", 3, signal.SIGUSR2)
        caplog.set_level(logging.INFO, logger="truckrl.train")
        run_session(tmp_path, "total_frames=1000000")
    finally:
        signal.signal(signal.SIGUSR2, previous)
    assert len(calls) == 1  # the launcher's handler ran once, after the checkpoint was written
    assert calls[0]["counters"]["iteration"] == 1
    assert any(r.getMessage().startswith("stopped by SIGUSR2") for r in caplog.records)
    assert_consistent(tmp_path)
