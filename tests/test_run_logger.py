"""Training videos: when they are due, what they show (the viewer's frames) and what TensorBoard
gets (an animated GIF, a readable strip, the mp4's path)."""

from __future__ import annotations

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from truckrl.env import TruckEnv
from truckrl.rl.logger import STRIP_HEIGHT, RunLogger, VideoSchedule, record_episode
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
