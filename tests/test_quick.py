"""``experiment=quick``: the README's one-minute training run.

The preset check composes the config only (default suite); the run itself is ``slow``
(``python -m pytest -m slow tests/test_quick.py``, a minute or two on a 2-core CPU).
"""

from __future__ import annotations

import pytest

from tests.conftest import run_cli
from truckrl import cli
from truckrl.config.schemas import TrainConfig
from truckrl.rl.checkpoint import load_training_state

#: Frames at which ``truckrl train experiment=quick seed=S`` (1 torch thread) was promoted to
#: difficulty 2, as its train.log says: seed 0 245,760, seed 1 212,992, seed 2 176,128. The
#: preset's budget, 327,680 frames, is 80 iterations of 4,096.
QUICK_FRAMES = 327_680


def test_quick_composes_and_stops_by_frames():
    tc = cli.compose_config("train", TrainConfig, ["experiment=quick"])
    assert tc.total_frames == QUICK_FRAMES
    assert tc.max_minutes is None and tc.stop_difficulty is None  # frames alone end it
    assert tc.total_frames % (tc.collector.num_envs * tc.collector.steps_per_env) == 0
    assert tc.demos.episodes == 0  # from scratch: no planning before PPO
    assert tc.threads == 1  # the same seed and threads give the same run
    # nothing compiled: compilation would outlast the run
    assert not (tc.env.compile or tc.collector.compile_policy or tc.ppo.compile)
    assert tc.env.task.name == "intersection" and tc.env.task.scene.crossing_prob == 0.0
    assert tc.log.video_interval == 0 and tc.log.eval_interval_min == 0


@pytest.mark.slow
def test_quick_reaches_difficulty_2(tmp_path):
    run = tmp_path / "run"
    proc = run_cli("train", "experiment=quick", "seed=0", f"hydra.run.dir={run}", timeout=1200)
    assert proc.returncode == 0, proc.stderr[-2000:]
    state = load_training_state(run)
    assert state["counters"]["frames"] == QUICK_FRAMES
    assert state["curriculum"]["difficulty"] >= 2.0, state["counters"]
