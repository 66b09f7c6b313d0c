"""``quality_reached``: the first held-out check at or above ``log.quality_target`` at a
curriculum difficulty >= ``log.quality_difficulty`` (minutes since the run's start, sessions
joined, and frames), kept in the checkpoint counters; ``stop_on_quality`` ends the run there.

The unit tests feed hand-made held-out results to :class:`~truckrl.rl.progress.Quality`; the
run tests train tiny in-process sessions (``truckrl.train.run``, the entry point less Hydra) with
a target every check meets (0 at difficulty >= 0) or none can (difficulty >= 30).
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import TINY_BATCH, TINY_TRAIN, compose_config
from truckrl.cli import to_config
from truckrl.config.schemas import TrainConfig
from truckrl.rl import checkpoint as ckpt
from truckrl.rl.progress import Quality, stop_reason
from truckrl.train import run

BATCH = TINY_BATCH
#: A held-out check after every iteration, on 4 short scenes.
EVALS = [f"log.eval_interval_frames={BATCH}", "log.eval_episodes=4", "env.max_steps=20"]
#: A target every check meets, and one no check can (the curriculum never passes 30).
ALWAYS = ["log.quality_target=0", "log.quality_difficulty=0"]
NEVER = ["log.quality_difficulty=30"]


# ------------------------------------------------------------------ hand-made held-out results
def test_the_first_check_at_target_and_difficulty_fires_once():
    q = Quality(0.95, 6.0)
    assert q.check(0.99, 5.5, 3.0, 1000, 1) is None  # above target, below the difficulty
    assert q.check(0.94, 6.0, 4.0, 2000, 2) is None  # at the difficulty, below target
    assert q.check(0.945, 7.0, 5.0, 3000, 3) is None  # 189/200: below target
    rec = q.check(0.96, 6.5, 6.25, 4000, 4)
    assert rec == {"minutes": 6.25, "frames": 4000, "iteration": 4, "difficulty": 6.5,
                   "success_rate": 0.96}  # fmt: skip
    assert q.check(1.0, 8.0, 7.0, 5000, 5) is None  # a second time: never again
    assert q.reached == rec
    assert q.scalars() == {"quality/reached_minutes": 6.25, "quality/reached_frames": 4000}
    assert q.line().startswith("quality_reached: 6.2 min, 4,000 frames, iteration 4, difficulty")


def test_a_rate_equal_to_the_target_fires_despite_float32_rounding():
    """190/200 as a float32 mean (what ``summarize`` logs) reads 0.94999999 < 0.95."""
    rate = torch.tensor([True] * 190 + [False] * 10).float().mean().item()
    assert rate < 0.95
    assert Quality(0.95, 6.0).check(rate, 6.0, 1.0, 10, 1) is not None
    assert Quality(0.95, 6.0).check(6.0, 5.999, 1.0, 10, 1) is None  # difficulty: no slack


def test_a_resumed_record_does_not_fire_again():
    before = {"minutes": 12.0, "frames": 8, "iteration": 2, "difficulty": 6.0, "success_rate": 1.0}
    q = Quality(0.95, 6.0, before)
    assert q.check(1.0, 6.0, 20.0, 16, 4) is None and q.reached == before
    assert Quality(0.95, 6.0).line() == (
        "quality_reached: not yet (held-out success >= 0.95 at difficulty >= 6)"
    )


def test_stop_on_quality_comes_first():
    assert stop_reason(10, 1.0, 0.0, 100, 60.0, 6.0, quality=True) == "quality"
    assert stop_reason(10, 1.0, 0.0, 100, 60.0, 6.0, quality=False) is None


@pytest.mark.parametrize(
    "quality",
    [{"minutes": -1.0, "frames": 1, "iteration": 1, "difficulty": 0, "success_rate": 1},
     {"minutes": 1.0, "frames": 1, "iteration": 1, "difficulty": 0},
     {"minutes": math.nan, "frames": 1, "iteration": 1, "difficulty": 0, "success_rate": 1},
     "reached"],
)  # fmt: skip
def test_a_bad_quality_record_is_a_bad_checkpoint(tiny_checkpoint, quality, tmp_path):
    state = ckpt.load_checkpoint(tiny_checkpoint[0])
    ckpt.check_training_state(state, "x.pt")  # no record (older checkpoints): fine
    state["counters"]["quality"] = quality
    with pytest.raises(ckpt.CheckpointError, match=r"x.pt: bad counters \(counters.quality"):
        ckpt.check_training_state(state, "x.pt")


# ------------------------------------------------------------------ training sessions
def session(
    run_dir: Path, *overrides: str, caplog, earlier_s: float = 0.0
) -> tuple[dict, list[str], float]:
    """One in-process training session in ``run_dir`` that the entry point started
    ``earlier_s`` seconds before; returns its last.pt counters, the ``truckrl.train`` log
    lines and its wall clock [min] (``earlier_s`` included)."""
    tc = to_config(TrainConfig, compose_config("train", *TINY_TRAIN, *EVALS, *overrides))
    caplog.clear()
    t0 = time.monotonic() - earlier_s
    with caplog.at_level(logging.INFO, logger="truckrl.train"):
        run(tc, run_dir, started=t0)
    minutes = (time.monotonic() - t0) / 60.0
    lines = [r.getMessage() for r in caplog.records if r.name == "truckrl.train"]
    return ckpt.load_checkpoint(run_dir)["counters"], lines, minutes


def quality_events(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    acc = EventAccumulator(str(run_dir / "tb"), purge_orphaned_data=True)
    acc.Reload()
    tags = ("quality/reached_minutes", "quality/reached_frames")
    return {
        t: [(e.step, e.value) for e in acc.Scalars(t)] for t in tags if t in acc.Tags()["scalars"]
    }


def test_a_resumed_run_joins_sessions_fires_once_and_keeps_it(tmp_path, caplog):
    """Session 1 cannot reach the target; its checkpoint is told 10 min passed. Session 2 (a
    reachable target: ``log`` is taken from the resume's command line) fires at its first
    check with 10 min + its own minutes, not again at its second; session 3 keeps the record."""
    counters, lines, _ = session(tmp_path, f"total_frames={BATCH}", *NEVER, caplog=caplog)
    assert counters["quality"] is None
    assert any(x.startswith("quality_reached: not yet (held-out success >= 0.95") for x in lines)
    state = torch.load(tmp_path / "checkpoints" / "last.pt", weights_only=True)
    state["counters"]["wall_time_s"] = 600.0
    ckpt.save_checkpoint(tmp_path / "checkpoints" / "last.pt", state)

    resume = [f"resume={tmp_path}", *ALWAYS]
    counters, lines, minutes = session(tmp_path, *resume, f"total_frames={3 * BATCH}",
                                       caplog=caplog)  # fmt: skip
    rec = counters["quality"]
    assert {k: rec[k] for k in ("frames", "iteration", "difficulty")} == {
        "frames": 2 * BATCH, "iteration": 2, "difficulty": 0.0}  # fmt: skip
    assert 10.0 < rec["minutes"] < 10.0 + minutes
    fired = [x for x in lines if x.startswith("quality_reached:")]
    assert len(fired) == 2 and fired[0] == fired[1]  # at the check, and in the last lines
    assert fired[0].startswith(f"quality_reached: {rec['minutes']:.1f} min, {2 * BATCH:,} frames")
    events = quality_events(tmp_path)
    assert events["quality/reached_frames"] == [(2 * BATCH, 2 * BATCH)]
    assert events["quality/reached_minutes"] == [(2 * BATCH, pytest.approx(rec["minutes"]))]

    counters, lines, _ = session(tmp_path, *resume, f"total_frames={4 * BATCH}", caplog=caplog)
    assert counters["iteration"] == 4 and counters["quality"] == rec
    assert [x for x in lines if x.startswith("quality_reached:")] == fired[:1]  # last lines only
    assert quality_events(tmp_path) == events


def test_stop_on_quality_ends_the_run_at_the_check(tmp_path, caplog):
    """The session began 3 min before training (as start-up and demonstrations would take):
    those minutes count."""
    args = ["stop_on_quality=true", *ALWAYS, f"total_frames={3 * BATCH}"]
    counters, lines, minutes = session(tmp_path, *args, caplog=caplog, earlier_s=180.0)
    assert counters["iteration"] == 1 and counters["quality"]["frames"] == BATCH
    assert 3.0 < counters["quality"]["minutes"] < minutes
    assert any(x.startswith("stopped: quality reached (stop_on_quality) at iteration 1,")
               for x in lines)  # fmt: skip
