"""TensorBoard output of a training run: scalars, the config, hyper-parameters and videos.

This module sits beside the entry points (above ``agent``): it draws, and drawing reads states
only, through :mod:`truckrl.viz`.

Events go to ``<run_dir>/tb``; the global step is the number of environment frames. A resumed
run opens the same directory with ``purge_step`` = the checkpoint's frame count + 1, so TensorBoard
drops whatever the killed run logged after its last checkpoint and the curves continue seamlessly.

Videos: TensorBoard's ``add_video`` needs ``moviepy``, which is not a dependency. Each rollout is
written as ``<run_dir>/videos/iter_XXXXXX.mp4`` with OpenCV instead, and a strip of evenly spaced
frames is logged as the image ``video/rollout``.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict.nn import TensorDictModuleBase
from torch.utils.tensorboard import SummaryWriter
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.env import TruckEnv
from truckrl.task import EnvConfig
from truckrl.viz.draw import draw_state
from truckrl.viz.video import frame_strip, write_mp4


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


class RunLogger:
    """TensorBoard writer for one run directory.

    Args:
        run_dir: the run's output directory (events in ``run_dir/tb``).
        purge_step: first global step to keep when continuing a run (None for a new run).
    """

    def __init__(self, run_dir: str | Path, purge_step: int | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.writer = SummaryWriter(log_dir=str(self.run_dir / "tb"), purge_step=purge_step)

    def scalars(self, values: Mapping[str, float], step: int) -> None:
        for k, v in values.items():
            self.writer.add_scalar(k, v, global_step=step)

    def config(self, yaml_text: str, hparams: Mapping[str, Any], metrics: Mapping[str, float]):
        """Log the resolved config as text and the flattened config as an hparams table."""
        self.writer.add_text("config", "```yaml\n" + yaml_text + "\n```", global_step=0)
        self.writer.add_hparams(flatten(hparams), dict(metrics), run_name=".", global_step=0)

    def video(self, frames: np.ndarray, iteration: int, step: int, fps: float) -> Path:
        path = write_mp4(self.run_dir / "videos" / f"iter_{iteration:06d}.mp4", frames, fps)
        self.writer.add_image(
            "video/rollout", frame_strip(frames, count=6), step, dataformats="HWC"
        )
        return path

    def rollout_video(
        self, actor, env_cfg: EnvConfig, difficulty: float, seed: int, steps: int, device,
        iteration: int, step: int, fps: float,
    ) -> bool:  # fmt: skip
        """Record and log one deterministic episode; False (with a warning) if video is unusable."""
        try:
            frames = record_episode(actor, env_cfg, difficulty, seed, steps, device)
        except ImportError as e:
            warnings.warn(f"rollout videos disabled: {e}", stacklevel=2)
            return False
        self.video(frames, iteration, step, fps)
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
    max_frames: int,
    device: str | torch.device = "cpu",
) -> np.ndarray:
    """Frames ``[F, H, W, 3]`` uint8 RGB of one deterministic episode (stops at its end)."""
    env_cfg = dataclasses.replace(env_cfg, compile=False)  # one truck: compiling does not pay
    env = TruckEnv(num_envs=1, device=device, config=env_cfg, seed=seed)
    env.set_difficulty(difficulty)
    tol_pos, tol_ang = (float(x[0]) for x in env.tolerances())
    max_range = env_cfg.lidar.max_range

    def frame(td) -> np.ndarray:
        s = env.get_state()[0]
        return draw_state(s, td["lidar"][0] * max_range, env.task.rel_angles, (tol_pos, tol_ang))

    td = env.reset()
    frames = [frame(td)]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(max(0, max_frames - 1)):
            nxt = env.step(actor(td))["next"]
            frames.append(frame(nxt))
            if bool(nxt["done"].any()):
                break
            td = nxt
    env.close()
    return np.stack(frames)
