"""TensorBoard output of a training run: scalars, the config, hyper-parameters and videos.

Drawing reads states only (:mod:`truckrl.viz`): this module steps the env for a video and hands
each snapshot to :func:`truckrl.viz.video.render_frame`, the viewer's own renderer.

Events go to ``<run_dir>/tb``; the global step is the number of environment frames. A resumed
run opens the same directory with ``purge_step`` = the checkpoint's frame count + 1, so TensorBoard
drops whatever the killed run logged after its last checkpoint and the curves continue seamlessly.

Videos: one deterministic episode (the policy's mean action, the same seeded scene every time)
drawn by the viewer's renderer, so each frame is exactly what ``truckrl play
checkpoint=...`` shows: the whole scene
with the start truck and the goal in view, the HUD panel and the outcome banner. The first video
is recorded after the first iteration, then whenever ``log.video_interval`` iterations or
:data:`VIDEO_EVERY_S` seconds have passed since the last one (:class:`VideoSchedule`).

Each video is written as ``<run_dir>/videos/iter_XXXXXX.mp4`` (H.264: browsers play it) and logged
to TensorBoard as

* ``video/rollout``: an animated GIF at 3/4 size (TensorBoard's image dashboard plays it;
  ``SummaryWriter.add_video`` would make the same but needs moviepy < 2, not a dependency);
* ``video/strip``: four bird's-eye views spread over the episode (first, ..., last), 360 px high;
* ``video/file``: the mp4's path, as text.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch.utils.tensorboard import SummaryWriter
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.env import TruckEnv
from truckrl.tasks import OUTCOMES, EnvConfig
from truckrl.viz.config import ViewConfig
from truckrl.viz.video import (
    FrameState,
    fixed_camera,
    frame_strip,
    gif_bytes,
    render_frame,
    write_mp4,
)

#: [s] wall-clock time after which the next video is due, whatever the iteration count.
VIDEO_EVERY_S = 300.0
#: Tiles [count] and tile height [px] of the TensorBoard frame strip.
STRIP_TILES, STRIP_HEIGHT = 4, 360
#: Scale of the animated GIF logged to TensorBoard (the mp4 keeps full size).
GIF_SCALE = 0.75
#: [s] the last frame (with the outcome banner) is held this long at the end of a video.
END_HOLD_S = 1.0


def flatten(cfg: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}``; lists and None become strings (hparams types)."""
    out: dict[str, Any] = {}
    for k, v in cfg.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, f"{key}."))
        elif isinstance(v, bool | int | float | str):
            out[key] = v
        else:
            out[key] = str(v)
    return out


class VideoSchedule:
    """When the next training video is due: at the first call, then after ``every_iterations``
    iterations or ``every_s`` seconds of wall clock since the last video, whichever comes first.

    Args:
        every_iterations: iterations between videos (0: never any video).
        every_s: [s] wall clock between videos.
        clock: time source [s] (tests pass a fake one).
    """

    def __init__(
        self,
        every_iterations: int,
        every_s: float = VIDEO_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.every_iterations, self.every_s, self.clock = every_iterations, every_s, clock
        self.last_iteration: int | None = None
        self.last_time = 0.0

    def due(self, iteration: int) -> bool:
        """True if a video is due at ``iteration``; marks it recorded (the clock restarts)."""
        if self.every_iterations <= 0:
            return False
        now = self.clock()
        due = (
            self.last_iteration is None
            or iteration - self.last_iteration >= self.every_iterations
            or now - self.last_time >= self.every_s
        )
        if due:
            self.last_iteration, self.last_time = iteration, now
        return due


class RunLogger:
    """TensorBoard writer for one run directory.

    Args:
        run_dir: the run's output directory (events in ``run_dir/tb``).
        purge_step: first global step to keep when continuing a run (None for a new run).
        video_every_s: [s] wall clock after which a video is due (see :class:`VideoSchedule`).
    """

    def __init__(
        self,
        run_dir: str | Path,
        purge_step: int | None = None,
        video_every_s: float = VIDEO_EVERY_S,
    ) -> None:
        self.run_dir = Path(run_dir)
        self.writer = SummaryWriter(log_dir=str(self.run_dir / "tb"), purge_step=purge_step)
        self.video_every_s = video_every_s
        self._schedule: VideoSchedule | None = None

    def scalars(self, values: Mapping[str, float], step: int) -> None:
        for k, v in values.items():
            self.writer.add_scalar(k, v, global_step=step)

    def config(self, yaml_text: str, hparams: Mapping[str, Any], metrics: Mapping[str, float]):
        """Log the resolved config as text and the flattened config as an hparams table."""
        self.writer.add_text("config", "```yaml\n" + yaml_text + "\n```", global_step=0)
        self.writer.add_hparams(flatten(hparams), dict(metrics), run_name=".", global_step=0)

    def video_due(self, iteration: int, every_iterations: int) -> bool:
        """Whether to record a video after ``iteration`` (first iteration, then by iterations or
        wall clock; ``every_iterations`` 0: never). A True answer restarts the clock."""
        if self._schedule is None:
            self._schedule = VideoSchedule(every_iterations, self.video_every_s)
        return self._schedule.due(iteration)

    def video(
        self, frames: np.ndarray, views: np.ndarray, iteration: int, step: int, fps: float
    ) -> Path:
        """Write ``frames`` (viewer frames) as an mp4 and log it: GIF, strip of ``views``, path."""
        path = write_mp4(self.run_dir / "videos" / f"iter_{iteration:06d}.mp4", frames, fps)
        self._gif("video/rollout", frames, fps, step)
        strip = frame_strip(views, STRIP_TILES, STRIP_HEIGHT, gap_px=6)
        self.writer.add_image("video/strip", strip, step, dataformats="HWC")
        self.writer.add_text("video/file", f"`{path}` (iteration {iteration})", step)
        return path

    def _gif(self, tag: str, frames: np.ndarray, fps: float, step: int) -> None:
        from tensorboard.compat.proto.summary_pb2 import Summary

        data = gif_bytes(frames, fps, GIF_SCALE)
        h, w = (max(1, round(n * GIF_SCALE)) for n in frames.shape[1:3])
        image = Summary.Image(height=h, width=w, colorspace=3, encoded_image_string=data)
        summary = Summary(value=[Summary.Value(tag=tag, image=image)])
        self.writer._get_file_writer().add_summary(summary, step)

    def rollout_video(
        self, actor, env_cfg: EnvConfig, difficulty: float, seed: int, steps: int, device,
        iteration: int, step: int, fps: float,
    ) -> bool:  # fmt: skip
        """Record and log one deterministic episode; False (with a warning) if video is unusable."""
        try:
            frames, views = record_episode(actor, env_cfg, difficulty, seed, steps, device)
            hold = max(0, round(END_HOLD_S * fps))
            frames = np.concatenate((frames, np.repeat(frames[-1:], hold, axis=0)))
            self.video(frames, views, iteration, step, fps)
        except ImportError as e:
            warnings.warn(f"rollout videos disabled: {e}", stacklevel=2)
            return False
        return True

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


@torch.no_grad()
def record_episode(
    actor: TensorDictModuleBase,
    env_cfg: EnvConfig,
    difficulty: float,
    seed: int,
    max_steps: int,
    device: str | torch.device = "cpu",
    view: ViewConfig = ViewConfig(),  # noqa: B008 (frozen dataclass)
) -> tuple[np.ndarray, np.ndarray]:
    """One deterministic episode (the policy's mean action) as the viewer shows it, up to its end
    or ``max_steps`` steps: this function steps the env, :func:`~truckrl.viz.video.render_frame`
    draws each snapshot.

    Returns:
        ``(frames [F, H, W + panel, 3], views [F, H, W, 3])`` uint8 RGB, ``F <= max_steps + 1``
        (the start frame, then one per step): the viewer frames (view + HUD panel) and the
        bird's-eye views alone.
    """
    env_cfg = dataclasses.replace(env_cfg, compile=False)  # one truck: compiling does not pay
    env = TruckEnv(num_envs=1, device=device, config=env_cfg, seed=seed)
    try:
        env.set_difficulty(difficulty)
        td = env.reset()
        camera = fixed_camera(env.get_state(), view)
        keys = ("reward", *env.task.reward_keys)
        shot = {"rewards": {}, "last_action": None, "episode_return": 0.0, "outcome": None}

        def render(td: TensorDictBase) -> tuple[np.ndarray, np.ndarray]:
            fs = FrameState(
                state=env.get_state()[0], ranges=td["lidar"][0] * env_cfg.lidar.max_range,
                task=env.task, config=env.config, difficulty=env.get_difficulty(),
                tolerance=tuple(float(x[0]) for x in env.tolerances()), camera=camera,
                episodes_done=int(shot["outcome"] is not None), **shot,
            )  # fmt: skip
            return render_frame(fs, view)

        shown = [render(td)]
        while len(shown) <= max_steps and shot["outcome"] is None:
            obs = td.select("observation", "lidar")
            with set_exploration_type(ExplorationType.DETERMINISTIC):
                action = actor(obs)["action"]
            td = env.step(obs.set("action", action))["next"]
            shot["episode_return"] += float(td["reward"])
            shot["rewards"] = {k: float(td[k]) for k in keys}
            shot["last_action"] = action.reshape(-1).tolist()
            if bool(td["done"]):
                shot["outcome"] = next((o.label for o in OUTCOMES if bool(td[o.flag])), "DONE")
            shown.append(render(td))
    finally:
        env.close()
    return np.stack([f for _, f in shown]), np.stack([v for v, _ in shown])
