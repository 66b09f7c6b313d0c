"""What a training run logs (scalars, the config, hyper-parameters and videos), through TorchRL's
loggers (:mod:`torchrl.record.loggers`), chosen by ``log.backend``:

* ``tensorboard`` (default): events in ``<run_dir>/tb`` (``TensorboardLogger``); what
  ``truckrl tools curves`` and ``tools aggregate`` read;
* ``csv``: ``<run_dir>/csv/scalars/<tag>.csv``, one ``step,value`` row per point
  (``CSVLogger``), the same tags and values as TensorBoard's;
* ``wandb`` (extra ``truckrl[wandb]``): a W&B run in ``<run_dir>/wandb`` (``WandbLogger``;
  ``log.backend_args.offline=true`` or ``WANDB_MODE=offline`` keeps it local);
* ``mlflow`` (extra ``truckrl[mlflow]``): an MLflow run (``MLFlowLogger``), by default in
  ``sqlite:///<run_dir>/mlflow.db`` with artifacts in ``<run_dir>/mlartifacts``.

``log.backend_args`` are passed to that logger's constructor. The global step is the number of
environment frames. A resumed run continues its curves: TensorBoard opens the same directory
with ``purge_step`` = the checkpoint's frame count + 1, so it drops whatever the killed run
logged after its last checkpoint; csv drops those rows from its files; a W&B run continues the
same run id (``<run_dir>/logger.json``), where points logged after the checkpoint stay.

Drawing reads states only (:mod:`truckrl.viz`): this module steps the env for a video and hands
each snapshot to :func:`truckrl.viz.video.render_frame`, the viewer's own renderer.

Videos: one deterministic episode (the policy's mean action, the same seeded scene every time)
drawn by the viewer's renderer, so each frame is exactly what ``truckrl play
checkpoint=...`` shows: the whole scene
with the start truck and the goal in view, the HUD panel and the outcome banner. The first video
is recorded after the first iteration, then whenever ``log.video_interval`` iterations or
:data:`VIDEO_EVERY_S` seconds have passed since the last one (:class:`VideoSchedule`).

Each video is written as ``<run_dir>/videos/iter_XXXXXX.mp4`` (H.264: browsers play it) with
every backend, and logged to TensorBoard as

* ``video/rollout``: an animated GIF at 3/4 size (TensorBoard's image dashboard plays it;
  ``TensorboardLogger.log_video`` would make a video but needs moviepy < 2, not a dependency);
* ``video/strip``: four bird's-eye views spread over the episode (first, ..., last), 360 px high;
* ``video/file``: the mp4's path, as text;

to W&B and MLflow as ``video/rollout`` through the logger's ``log_video`` (W&B needs moviepy,
MLflow torchcodec; without them a warning says so once and the mp4 stays on disk); csv keeps
the mp4 file only.
"""

from __future__ import annotations

import csv
import dataclasses
import importlib.util
import inspect
import json
import os
import time
import uuid
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
from torchrl.record.loggers import CSVLogger, Logger, TensorboardLogger

from truckrl.config.fields import ConfigError
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
#: ``log.backend`` -> (the package it imports, the extra that installs it; None: a dependency).
BACKENDS: dict[str, tuple[str | None, str | None]] = {
    "tensorboard": ("tensorboard", None),
    "csv": (None, None),
    "wandb": ("wandb", "wandb"),
    "mlflow": ("mlflow", "mlflow"),
}
#: Logger arguments the run sets itself (not ``log.backend_args``).
SET_HERE = ("exp_name", "log_dir", "purge_step")
#: Where a run keeps its logger's identity (the W&B run id) for the next session.
LOGGER_FILE = "logger.json"


def check_backend(backend: str, args: Mapping[str, Any] | None = None) -> None:
    """Refuse a ``log.backend`` whose package is not installed, or ``args``
    (``log.backend_args``) that its logger does not take (W&B and MLflow pass theirs on to
    ``wandb.init`` / MLflow, which check them), before any training.

    Raises:
        ConfigError: one line naming the field, and the extra to install or the arguments
            allowed.
    """
    module, extra = BACKENDS[backend]
    if module is not None and importlib.util.find_spec(module) is None:
        raise ConfigError(
            f"log.backend = {backend} needs the {module} package, which is not installed: "
            f"pip install 'truckrl[{extra or module}]'"
        )
    own = {"tensorboard": PurgingTensorboardLogger, "csv": CSVLogger}.get(backend)
    if own is not None and args:
        allowed = set(inspect.signature(own.__init__).parameters) - {"self", *SET_HERE}
        bad = sorted(set(args) - allowed)
        if bad:
            raise ConfigError(
                f"log.backend_args: {', '.join(bad)} is not an argument of the {backend} "
                f"logger (allowed: {', '.join(sorted(allowed)) or 'none'})"
            )


class PurgingTensorboardLogger(TensorboardLogger):
    """TorchRL's ``TensorboardLogger`` whose ``SummaryWriter`` gets a ``purge_step``.

    Args:
        exp_name: the events' folder name under ``log_dir``.
        log_dir: the run dir.
        purge_step: first global step to keep when continuing a run (None: a new run);
            TensorBoard then drops the events a killed session logged at or after it.
    """

    def __init__(self, exp_name: str, log_dir: str, purge_step: int | None = None) -> None:
        self.purge_step = purge_step
        super().__init__(exp_name=exp_name, log_dir=log_dir)

    def _create_experiment(self) -> SummaryWriter:
        """The writer of ``<log_dir>/<exp_name>`` (the hook every TorchRL logger implements)."""
        path = os.path.join(self.log_dir, self.exp_name)
        return SummaryWriter(log_dir=path, purge_step=self.purge_step)


def purge_csv(scalars_dir: Path, purge_step: int) -> None:
    """Drop the rows at or after ``purge_step`` from every ``<tag>.csv`` under ``scalars_dir``
    (what TensorBoard's ``purge_step`` does to its events), each file rewritten atomically."""
    for f in sorted(scalars_dir.rglob("*.csv")):
        with f.open(newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and int(float(r[0])) < purge_step]
        tmp = f.with_name(f".{f.name}.tmp")
        with tmp.open("w", newline="") as fh:
            fh.writelines(f"{r[0]},{r[1]}\n" for r in rows)
        os.replace(tmp, f)


def open_backend(
    backend: str, run_dir: Path, purge_step: int | None, args: Mapping[str, Any]
) -> Logger:
    """The TorchRL logger of ``backend`` for ``run_dir`` (module doc); ``purge_step`` not None:
    the run continues from a checkpoint of that many frames (minus one).

    Raises:
        ConfigError: the backend is not installed, or ``args`` are not its logger's arguments.
    """
    check_backend(backend)
    try:
        return _open(backend, run_dir, purge_step, dict(args))
    except TypeError as e:  # an argument the logger's constructor does not take
        raise ConfigError(
            f"log.backend_args: not arguments of the {backend} logger ({e})"
        ) from None


def _open(backend: str, run_dir: Path, purge_step: int | None, args: dict[str, Any]) -> Logger:
    if backend == "tensorboard":
        return PurgingTensorboardLogger("tb", str(run_dir), purge_step, **args)
    if backend == "csv":
        if purge_step is not None and (run_dir / "csv" / "scalars").is_dir():
            purge_csv(run_dir / "csv" / "scalars", purge_step)
        return CSVLogger("csv", str(run_dir), **args)
    saved = run_dir / LOGGER_FILE
    known = json.loads(saved.read_text()) if saved.is_file() else {}
    if backend == "wandb":
        from torchrl.record.loggers import WandbLogger

        args.setdefault("id", known.get("id") or uuid.uuid4().hex[:16])
        args.setdefault("save_dir", str(run_dir))
        logger = WandbLogger(args.pop("exp_name", run_dir.name), **args)
        ident = getattr(logger.experiment, "id", None) or args["id"]
    else:
        from torchrl.record.loggers import MLFlowLogger

        args.setdefault("tracking_uri", f"sqlite:///{(run_dir / 'mlflow.db').resolve()}")
        args.setdefault("artifact_location", (run_dir / "mlartifacts").resolve().as_uri())
        logger = MLFlowLogger(args.pop("exp_name", "truckrl"), **args)
        ident = str(logger.id)
    saved.write_text(json.dumps({"backend": backend, "id": ident}) + "\n")
    return logger


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
    """One run directory's logger: a TorchRL logger of ``backend`` (module doc) plus the videos.

    Args:
        run_dir: the run's output directory.
        purge_step: first global step to keep when continuing a run (None for a new run).
        video_every_s: [s] wall clock after which a video is due (see :class:`VideoSchedule`).
        backend: ``log.backend``.
        backend_args: ``log.backend_args``, keyword arguments of that logger.

    Raises:
        ConfigError: the backend's package is not installed (:func:`check_backend`).
    """

    def __init__(
        self,
        run_dir: str | Path,
        purge_step: int | None = None,
        video_every_s: float = VIDEO_EVERY_S,
        backend: str = "tensorboard",
        backend_args: Mapping[str, Any] | None = None,
    ) -> None:
        self.run_dir = Path(run_dir)
        self.backend_name = backend
        self.backend = open_backend(backend, self.run_dir, purge_step, backend_args or {})
        self.video_every_s = video_every_s
        self._schedule: VideoSchedule | None = None
        self._video_warned = False

    @property
    def writer(self) -> SummaryWriter | None:
        """The TensorBoard ``SummaryWriter`` (None with another backend)."""
        return self.backend.experiment if self.backend_name == "tensorboard" else None

    def scalars(self, values: Mapping[str, float], step: int) -> None:
        self.backend.log_metrics(dict(values), step=step)

    def config(self, yaml_text: str, hparams: Mapping[str, Any], metrics: Mapping[str, float]):
        """Log the resolved config (as text where the backend has text) and the flattened config
        as hyper-parameters with ``metrics`` at step 0 (TensorBoard: an hparams table)."""
        text = "```yaml\n" + yaml_text + "\n```"
        if self.writer is not None:
            self.writer.add_text("config", text, global_step=0)
            self.writer.add_hparams(flatten(hparams), dict(metrics), run_name=".", global_step=0)
            return
        if self.backend_name == "csv":
            self.backend.experiment.add_text("config", text)
        self.backend.log_hparams(flatten(hparams))
        self.scalars(metrics, 0)

    def final(self, hparams: Mapping[str, Any], metrics: Mapping[str, float], step: int) -> None:
        """The hyper-parameters with the run's final ``metrics`` (``hparam/*`` scalars at
        ``step``; TensorBoard: the hparams table's values)."""
        if self.writer is not None:
            self.writer.add_hparams(flatten(hparams), dict(metrics), run_name=".",
                                    global_step=step)  # fmt: skip
        else:
            self.scalars(metrics, step)

    def video_due(self, iteration: int, every_iterations: int) -> bool:
        """Whether to record a video after ``iteration`` (first iteration, then by iterations or
        wall clock; ``every_iterations`` 0: never). A True answer restarts the clock."""
        if self._schedule is None:
            self._schedule = VideoSchedule(every_iterations, self.video_every_s)
        return self._schedule.due(iteration)

    def video(
        self, frames: np.ndarray, views: np.ndarray, iteration: int, step: int, fps: float
    ) -> Path:
        """Write ``frames`` (viewer frames) as an mp4 and log it (module doc): TensorBoard gets
        a GIF, a strip of ``views`` and the path; W&B and MLflow the video."""
        path = write_mp4(self.run_dir / "videos" / f"iter_{iteration:06d}.mp4", frames, fps)
        if self.writer is not None:
            self._gif("video/rollout", frames, fps, step)
            strip = frame_strip(views, STRIP_TILES, STRIP_HEIGHT, gap_px=6)
            self.writer.add_image("video/strip", strip, step, dataformats="HWC")
            self.writer.add_text("video/file", f"`{path}` (iteration {iteration})", step)
        elif self.backend_name in ("wandb", "mlflow"):
            video = torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2)[None]
            try:  # [1, T, 3, H, W] uint8
                self.backend.log_video("video/rollout", video, step=step, fps=round(fps))
            except ImportError as e:  # the backend's video encoder is an optional package
                if not self._video_warned:
                    warnings.warn(f"videos stay on disk only ({e})", stacklevel=2)
                    self._video_warned = True
        return path

    def _gif(self, tag: str, frames: np.ndarray, fps: float, step: int) -> None:
        """An animated GIF as an image summary, into the writer's own event file (its public
        ``file_writer``; ``add_image`` would encode a still PNG)."""
        from tensorboard.compat.proto.summary_pb2 import Summary

        data = gif_bytes(frames, fps, GIF_SCALE)
        h, w = (max(1, round(n * GIF_SCALE)) for n in frames.shape[1:3])
        image = Summary.Image(height=h, width=w, colorspace=3, encoded_image_string=data)
        summary = Summary(value=[Summary.Value(tag=tag, image=image)])
        self.writer.file_writer.add_summary(summary, step)

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
        self.backend.flush()

    def close(self) -> None:
        self.backend.close()


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
