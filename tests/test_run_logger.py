"""Training videos: when they are due, what they show (the viewer's frames) and what TensorBoard
gets (an animated GIF, a readable strip, the mp4's path); the ``log.backend`` loggers: a csv run
leaves TensorBoard's scalars, a resumed csv run drops what its killed session logged after the
checkpoint, W&B runs offline, and a missing backend or a wrong argument is one line first."""

from __future__ import annotations

import csv
import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import TINY_BATCH, TINY_TRAIN, compose_config
from truckrl.cli import to_config
from truckrl.config.fields import ConfigError
from truckrl.config.schemas import TrainConfig
from truckrl.env import TruckEnv
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.logger import STRIP_HEIGHT, RunLogger, VideoSchedule, purge_csv, record_episode
from truckrl.train import prepare_argv, run
from truckrl.viewer.runner import PolicySource, Runner, ViewConfig
from truckrl.viz.video import probe_video


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_first_video_at_once_then_by_iterations_or_wall_clock():
    clock = FakeClock()
    s = VideoSchedule(every_iterations=50, every_s=300.0, clock=clock)
    assert s.due(1)  # the first iteration
    clock.t = 299.0
    assert not s.due(2) and not s.due(50)
    assert s.due(51)  # 50 iterations since the last video
    clock.t = 598.0
    assert not s.due(52)
    clock.t = 599.0
    assert s.due(53)  # 300 s since the last video
    never = VideoSchedule(every_iterations=0, clock=clock)
    assert not never.due(1)


def test_episode_frames_are_the_viewers_frames(tiny_checkpoint):
    run, ac, tc = tiny_checkpoint
    view = ViewConfig(size_px=128, panel_px=96)
    frames, views = record_episode(ac.actor, tc.env, 1.0, 7, max_steps=6, view=view)
    assert frames.shape == (7, 128, 128 + 96, 3) and views.shape == (7, 128, 128, 3)
    env = TruckEnv(num_envs=1, seed=7, config=tc.env)
    env.set_difficulty(1.0)
    runner = Runner(env, {"policy": PolicySource(ac.actor)}, "policy", view)
    expected = [runner.frame]
    for _ in range(6):
        runner.step()
        expected.append(runner.frame)
    assert np.array_equal(frames, np.stack(expected))  # one renderer: the viewer's


def test_rollout_video_writes_h264_and_logs_gif_strip_and_path(tiny_checkpoint, tmp_path):
    run, ac, tc = tiny_checkpoint
    logger = RunLogger(tmp_path)
    assert logger.rollout_video(ac.actor, tc.env, 0.0, 3, 8, "cpu", 1, 1000, 10.0)
    logger.close()
    info = probe_video(tmp_path / "videos" / "iter_000001.mp4")
    assert info["codec"] == "h264" and (info["width"], info["height"]) == (980, 640)
    assert 10 < info["frames"] <= 9 + 10  # the episode (<= 8 steps) + 1 s on its last frame
    events = EventAccumulator(str(tmp_path / "tb"), size_guidance={"images": 0})
    events.Reload()
    gif = events.Images("video/rollout")[0]
    assert gif.step == 1000 and gif.encoded_image_string[:6] == b"GIF89a"
    strip = events.Images("video/strip")[0]
    assert strip.height == STRIP_HEIGHT and strip.width > 2 * STRIP_HEIGHT
    assert "video/file/text_summary" in events.Tags()["tensors"]


@pytest.mark.parametrize("every", [1, 3])
def test_logger_video_due_uses_the_schedule(tmp_path, every):
    logger = RunLogger(tmp_path, video_every_s=1e9)
    due = [i for i in range(1, 8) if logger.video_due(i, every)]
    logger.close()
    assert due == ([1, 2, 3, 4, 5, 6, 7] if every == 1 else [1, 4, 7])


# ------------------------------------------------------------------ log.backend
#: Two iterations with a held-out check after each and a quality target every check meets, so
#: eval/*, quality/* and hparam/* are logged as well as the iteration's scalars.
RUN = [*TINY_TRAIN, "seed=3", f"total_frames={2 * TINY_BATCH}", "env.max_steps=20",
       f"log.eval_interval_frames={TINY_BATCH}", "log.eval_episodes=4",
       "log.quality_target=0", "log.quality_difficulty=0"]  # fmt: skip
#: Scalars that measure the wall clock: their steps are compared, not their values.
WALL_CLOCK = ("perf/", "quality/reached_minutes")


def train_in(run_dir: Path, *overrides: str) -> None:
    """A training session in-process (``truckrl.train.run``: the entry point less Hydra)."""
    run(to_config(TrainConfig, compose_config("train", *RUN, *overrides)), run_dir)


def tensorboard_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    return {t: sorted((e.step, e.value) for e in acc.Scalars(t)) for t in acc.Tags()["scalars"]}


def csv_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """``{tag: sorted (step, value)}`` from ``csv/scalars/<tag>.csv``, values as float32 (what
    TensorBoard stores)."""
    root = run_dir / "csv" / "scalars"
    out = {}
    for f in root.rglob("*.csv"):
        with f.open(newline="") as fh:
            rows = [(int(r[0]), float(np.float32(r[1]))) for r in csv.reader(fh)]
        out[f.relative_to(root).with_suffix("").as_posix()] = sorted(rows)
    return out


@pytest.fixture(scope="module")
def backend_runs(tmp_path_factory) -> dict[str, Path]:
    """The same seeded tiny run with ``log.backend=tensorboard`` and with ``log.backend=csv``."""
    runs = {}
    for backend in ("tensorboard", "csv"):
        runs[backend] = tmp_path_factory.mktemp(backend)
        train_in(runs[backend], f"log.backend={backend}")
    return runs


def test_a_csv_run_leaves_the_scalars_of_a_tensorboard_run(backend_runs):
    tb, table = tensorboard_scalars(backend_runs["tensorboard"]), csv_scalars(backend_runs["csv"])
    assert {"loss/critic", "eval/success_rate", "quality/reached_frames", "hparam/difficulty",
            "curriculum/difficulty", "episode/success_ema"} <= set(tb)  # fmt: skip
    assert set(table) == set(tb)
    for tag, points in tb.items():
        if tag.startswith(WALL_CLOCK):
            assert [s for s, _ in table[tag]] == [s for s, _ in points], tag
        else:
            assert table[tag] == points, tag
    assert not (backend_runs["csv"] / "tb").exists()
    config = (backend_runs["csv"] / "csv" / "texts" / "config0.txt").read_text()
    assert "quality_target: 0.0" in config


def test_a_resumed_csv_run_drops_what_the_killed_session_logged(backend_runs):
    """A row past the checkpoint (2 batches) stands for a killed session's; the resume to 3
    batches drops it and appends its own."""
    run_dir = backend_runs["csv"]
    critic = run_dir / "csv" / "scalars" / "loss" / "critic.csv"
    with critic.open("a") as fh:
        fh.write(f"{2 * TINY_BATCH + 1},123.0\n")
    train_in(run_dir, "log.backend=csv", f"resume={run_dir}", f"total_frames={3 * TINY_BATCH}")
    assert load_checkpoint(run_dir)["counters"]["frames"] == 3 * TINY_BATCH
    steps = [s for s, _ in csv_scalars(run_dir)["loss/critic"]]
    assert steps == [TINY_BATCH, 2 * TINY_BATCH, 3 * TINY_BATCH]


def test_a_resume_to_another_backend_says_so(backend_runs, caplog):
    """``log`` comes from the resume's command line: without ``log.backend=csv`` a csv run
    goes on in TensorBoard, and the run says where its earlier sessions are."""
    run_dir = backend_runs["csv"]
    frames = load_checkpoint(run_dir)["counters"]["frames"]
    with caplog.at_level("INFO", logger="truckrl.train"):
        train_in(run_dir, f"resume={run_dir}", f"total_frames={frames + TINY_BATCH}")
    assert (
        "log.backend: tensorboard from here on; the earlier sessions logged to csv (resume "
        "with log.backend=csv to keep one log)"
    ) in caplog.messages


def test_purge_csv_keeps_the_rows_before_the_purge_step(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "b.csv").write_text("256,0.5\n512,0.25\n768,1.0\n")
    purge_csv(tmp_path, 512)  # the first step kept away: 512 itself goes
    assert (tmp_path / "a" / "b.csv").read_text() == "256,0.5\n"


@pytest.mark.skipif(importlib.util.find_spec("mlflow") is not None, reason="mlflow installed")
def test_a_backend_not_installed_is_one_line_before_any_work(tmp_path):
    with pytest.raises(ConfigError) as e:
        train_in(tmp_path / "run", "log.backend=mlflow")
    assert str(e.value) == (
        "log.backend = mlflow needs the mlflow package, which is not installed: "
        "pip install 'truckrl[mlflow]'"
    )
    assert not (tmp_path / "run").exists()


def test_an_argument_the_logger_does_not_take_is_one_line(tmp_path):
    with pytest.raises(ConfigError) as e:
        train_in(
            tmp_path / "run", "log.backend=csv", *prepare_argv(["log.backend_args.video_fsp=10"])
        )
    assert str(e.value) == (
        "log.backend_args: video_fsp is not an argument of the csv logger "
        "(allowed: video_format, video_fps)"
    )
    assert not (tmp_path / "run").exists()


def test_wandb_runs_offline_and_a_resume_continues_its_run(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path))
    run_dir = tmp_path / "run"
    train_in(run_dir, "log.backend=wandb", f"total_frames={TINY_BATCH}")
    ident = __import__("json").loads((run_dir / "logger.json").read_text())["id"]
    train_in(run_dir, "log.backend=wandb", f"resume={run_dir}", f"total_frames={2 * TINY_BATCH}")
    files = sorted(p.name for p in (run_dir / "wandb").glob("offline-run-*/run-*.wandb"))
    assert files == [f"run-{ident}.wandb"] * 2  # two sessions, one W&B run
    assert all(os.path.getsize(p) > 0 for p in (run_dir / "wandb").glob("offline-run-*/*.wandb"))


@pytest.mark.parametrize("backend", ["tensorboard", "csv"])
def test_a_continued_logger_drops_the_points_from_its_purge_step(tmp_path, backend):
    """A session logged steps 100, 200, 300 but its checkpoint was at 150: the next session
    (purge step 151) logs 200 again; the curve reads 100, then the new 200."""
    first = RunLogger(tmp_path, backend=backend)
    first.scalars({"a/b": 1.0}, 100)
    first.scalars({"a/b": 2.0}, 200)
    first.scalars({"a/b": 3.0}, 300)
    first.close()
    second = RunLogger(tmp_path, purge_step=151, backend=backend)
    second.scalars({"a/b": 5.0}, 200)
    second.close()
    read = tensorboard_scalars if backend == "tensorboard" else csv_scalars
    assert read(tmp_path)["a/b"] == [(100, 1.0), (200, 5.0)]
