"""Video files, animated GIFs and frame strips from RGB frames (no moviepy, no window).

The one video writer of the project: the viewer streams frames into :class:`Mp4Writer` as they are
shown, and training videos write a whole episode with :func:`write_mp4`. The one frame renderer
too: :func:`render_frame` draws a :class:`FrameState` (a snapshot of one truck's episode) as the
viewer shows it, for the viewer's runner and for training videos, which roll out the env
themselves and pass the snapshots here. Files are H.264 (High
profile, yuv420p) in an mp4 container with the index at the front (``+faststart``): what browsers,
VS Code and TensorBoard's neighbours play. The encoder is libx264 inside PyAV's wheels (``av``, a
dependency), so nothing outside Python is needed.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from truckrl.viz.config import ViewConfig
from truckrl.viz.draw import COLORS, draw_state
from truckrl.viz.keyboard import gear
from truckrl.viz.panel import Line, with_banner, with_panel

#: Encoder settings: constant quality 20 (visually lossless for flat drawings and text),
#: ``tune=animation`` (large flat areas, sharp edges).
H264_OPTIONS = {"crf": "20", "preset": "medium", "tune": "animation"}


def _import_av():
    try:
        import av
    except ImportError as e:  # a dependency; only a broken install lacks it
        raise ImportError(
            f"writing mp4 needs PyAV (pip install av): {e}; or record a frame strip instead"
        ) from None
    return av


def _even(frame: np.ndarray) -> np.ndarray:
    """Pad an odd height/width by one edge row/column (yuv420p needs even sizes)."""
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


class Mp4Writer:
    """Streams RGB frames ``[H, W, 3]`` uint8 to an H.264 mp4 file.

    The file is opened at the first frame, whose size every later frame must have; an odd width
    or height is padded by one edge pixel (H.264 in yuv420p needs even sizes). Use as a context
    manager or call :meth:`close`, which flushes the encoder: a file that is not closed is
    unplayable.

    Args:
        path: output file; parent folders are created.
        fps: frame rate [frames/s] stored in the file.
    """

    def __init__(self, path: str | os.PathLike, fps: float) -> None:
        if not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps!r}")
        self.path = Path(path)
        self.fps = float(fps)
        self.frames = 0
        self._size: tuple[int, int] | None = None
        self._container = None
        self._stream = None

    def write(self, frame: np.ndarray) -> None:
        """Append one RGB frame ``[H, W, 3]`` uint8."""
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"expected an [H, W, 3] uint8 frame, got {frame.shape} {frame.dtype}")
        h, w = frame.shape[:2]
        if self._container is None:
            av = _import_av()
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._container = av.open(
                str(self.path), "w", format="mp4", options={"movflags": "+faststart"}
            )
            stream = self._container.add_stream(
                "libx264", rate=Fraction(self.fps).limit_denominator(1001)
            )
            stream.width, stream.height = w + w % 2, h + h % 2
            stream.pix_fmt = "yuv420p"
            stream.options = dict(H264_OPTIONS)
            self._stream = stream
            self._size = (w, h)
        elif (w, h) != self._size:
            raise ValueError(f"frame size {(w, h)} differs from the first frame's {self._size}")
        av = _import_av()
        video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(_even(frame)), format="rgb24")
        self._container.mux(self._stream.encode(video_frame))
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file (idempotent)."""
        if self._container is not None:
            self._container.mux(self._stream.encode(None))
            self._container.close()
            self._container = self._stream = None

    def __enter__(self) -> Mp4Writer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_mp4(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float) -> Path:
    """Write RGB ``frames`` (``[F, H, W, 3]`` uint8, or an iterable of ``[H, W, 3]``) to an mp4."""
    with Mp4Writer(path, fps) as writer:
        for f in frames:
            writer.write(f)
    return writer.path


def probe_video(path: str | os.PathLike) -> dict:
    """Codec name, profile, pixel format, size, frame rate and decoded frame count of a file."""
    av = _import_av()
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        ctx = stream.codec_context
        info = {
            "codec": ctx.name,
            "profile": stream.profile,
            "pix_fmt": ctx.pix_fmt,
            "width": ctx.width,
            "height": ctx.height,
            "fps": float(stream.average_rate),
            "frames": sum(1 for _ in container.decode(stream)),
        }
    return info


def read_video(path: str | os.PathLike) -> np.ndarray:
    """Every frame of a video as ``[F, H, W, 3]`` uint8 RGB (decoded with PyAV)."""
    av = _import_av()
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def gif_bytes(
    frames: Sequence[np.ndarray], fps: float, scale: float = 1.0, colors: int = 64
) -> bytes:
    """An animated GIF (looping) of RGB ``frames``, each resized by ``scale``.

    TensorBoard's image dashboard plays animated GIFs; ``SummaryWriter.add_video`` makes the same
    kind of image but needs moviepy < 2. All frames share one palette of ``colors`` colours taken
    from the first, middle and last frame, so unchanged pixels stay unchanged between frames and
    the file stays small (~100 kB for 200 viewer frames at half size).
    """
    from PIL import Image

    if len(frames) == 0:
        raise ValueError("gif_bytes needs at least one frame")
    small = []
    for f in frames:
        if scale != 1.0:
            size = (max(1, round(f.shape[1] * scale)), max(1, round(f.shape[0] * scale)))
            f = cv2.resize(f, size, interpolation=cv2.INTER_AREA)
        small.append(np.ascontiguousarray(f))
    sample = np.concatenate([small[i] for i in spread_indices(3, len(small))], axis=0)
    palette = Image.fromarray(sample).quantize(colors=colors, dither=Image.Dither.NONE)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in small]
    buf = io.BytesIO()
    images[0].save(
        buf,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=max(20, round(1000.0 / fps)),  # [ms] per frame
        loop=0,
    )
    return buf.getvalue()


def spread_indices(count: int, length: int) -> np.ndarray:
    """``min(count, length)`` frame indices spread over ``[0, length)``, first and last included."""
    if length <= 0:
        raise ValueError("no frames")
    return np.linspace(0, length - 1, num=min(count, length)).round().astype(int)


def frame_strip(frames, count: int = 5, height: int = 200, gap_px: int = 0) -> np.ndarray:
    """``count`` evenly spaced frames side by side, each resized to ``height`` px: ``[h, W, 3]``.

    Args:
        frames: ``[F, H, W, 3]`` uint8 array or a sequence of ``[H, W, 3]`` frames.
        gap_px: white gap between tiles [px].
    """
    if len(frames) == 0:
        raise ValueError("frame_strip needs at least one frame")
    tiles = []
    for i in spread_indices(count, len(frames)):
        f = frames[i]
        w = max(1, round(f.shape[1] * height / f.shape[0]))
        if gap_px and tiles:
            tiles.append(np.full((height, gap_px, 3), 255, dtype=np.uint8))
        tiles.append(cv2.resize(f, (w, height), interpolation=cv2.INTER_AREA))
    return np.concatenate(tiles, axis=1)


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB image ``[H, W, 3]`` uint8 to a PNG (parent folders created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write {path}")
    return path


# ---------------------------------------------------------------------------------- frames
#: Banner and panel colours: a good outcome, a bad one, a note (waiting, paused).
OK_COLOR, BAD_COLOR = COLORS["goal"], (255, 95, 95)
NOTE_COLOR = COLORS["lidar"]


@dataclass
class FrameState:
    """What one viewer frame shows: a snapshot of one truck's episode, no env needed.

    The viewer's runner and the training videos' rollout both fill it after each step, so both
    draw the same frames (:func:`render_frame`).

    Attributes:
        state: the truck's state (one row of ``env.get_state()``: scalar entries).
        ranges: ``[R]`` LiDAR ranges [m] of the current observation.
        task: the task (beam angles, error quantities, reward terms, whether it reverses).
        config: the env config (``dt``, ``control``, ``max_steps``).
        tolerance: goal tolerance (position [m], heading [rad]) at the current difficulty.
        difficulty: the current difficulty.
        rewards: the last step's ``"reward"`` and reward terms (zeros before the first step).
        last_action: the last action ``(longitudinal, lateral)`` (None before the first step).
        episode_return: sum of the rewards so far.
        outcome: the finished episode's outcome label (None while driving).
        mode: the action source's name ("policy", "manual", ...).
        waiting: the episode waits for the first drive key (a banner says so).
        paused: the viewer is paused.
        episodes_done: finished episodes so far.
        done_hint: extra banner text for a finished episode (what a key does next).
        key_rows: key-help rows for the panel (empty: none).
        camera: fixed camera ``{"center", "view_half_extent"}`` (:func:`fixed_camera`); None
            follows the truck, north up, at :func:`follow_half_extent` (a scene too large to
            show whole).
    """

    state: Any
    ranges: Any
    task: Any
    config: Any
    tolerance: tuple[float, float]
    difficulty: float
    rewards: dict[str, float]
    last_action: Sequence[float] | None = None
    episode_return: float = 0.0
    outcome: str | None = None
    mode: str = "policy"
    waiting: bool = False
    paused: bool = False
    episodes_done: int = 0
    done_hint: str = ""
    key_rows: Sequence[tuple[str, str]] = ()
    camera: dict[str, Any] | None = None


def outcome_color(label: str | None) -> tuple[int, int, int]:
    """The colour of an outcome label (the HUD colour while driving or for an unknown one)."""
    from truckrl.tasks import OUTCOMES

    good = next((o.good for o in OUTCOMES if o.label == label), None)
    return COLORS["hud"] if good is None else OK_COLOR if good else BAD_COLOR


def fixed_camera(start: Any, view: ViewConfig) -> dict[str, Any] | None:
    """Centre and half extent [m] that show the whole start truck, the goal and the route (when
    the state keeps one, :data:`~truckrl.viz.draw.ROUTE_KEY`), with margin; ``None`` when that
    half extent exceeds ``view.follow_beyond``: a scene too large to show whole, where the camera
    follows the truck (:func:`render_frame`). ``start``: the episode's start state
    (``env.get_state()``, one truck)."""
    import torch

    from truckrl.sim.vehicle import truck_corners
    from truckrl.viz.draw import ROUTE_KEY

    tractor, trailer, _ = truck_corners(start["pose"], start["params"])
    parts = [tractor[0], trailer[0], start["goal"][0, None, :2]]
    if ROUTE_KEY in start.keys():
        parts.append(start[ROUTE_KEY][0].reshape(-1, 2))
    pts = torch.cat(parts).cpu()
    lo, hi = pts.min(0).values, pts.max(0).values
    half = 0.5 * float((hi - lo).max()) + view.margin
    if half > view.follow_beyond:
        return None
    return {"center": 0.5 * (lo + hi), "view_half_extent": max(view.half_extent, half)}


def follow_half_extent(view: ViewConfig, lidar_range: float) -> float:
    """Half extent [m] of the camera that follows the truck through a scene too large to show
    whole: the LiDAR's range plus ``view.margin`` (the beams' ends stay in view), at least
    ``view.half_extent``."""
    return max(view.half_extent, lidar_range + view.margin)


def render_frame(fs: FrameState, view: ViewConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(view_image, frame)``: the bird's-eye view with the waiting or outcome banner, and the
    frame the viewer shows and videos record (view + HUD panel), uint8 RGB.

    The camera: centred on the truck at ``view.half_extent`` with ``view.follow``; else the
    episode's fixed camera (``fs.camera``); or, for a scene too large to show whole
    (``fs.camera`` None), centred on the tractor's rear axle at :func:`follow_half_extent`,
    north up (world ``y`` up, as every view: the route and the map read the same way all
    episode)."""
    s = fs.state
    t = int(s["step_count"]) * fs.config.dt
    kwargs: dict[str, Any] = {"size_px": view.size_px}
    if view.follow:
        kwargs["view_half_extent"] = view.half_extent
    elif fs.camera is None:  # a scene larger than the view: follow the truck, north up
        kwargs["view_half_extent"] = follow_half_extent(view, fs.config.lidar.max_range)
    else:
        kwargs.update(fs.camera)
    caption = f"t {t:4.1f} s  v {float(s['speed']):4.1f} m/s"
    if fs.outcome:
        caption += f"  {fs.outcome}"
    image = draw_state(
        s, fs.ranges, fs.task.rel_angles, fs.tolerance, hud_lines=[caption], **kwargs
    )
    if fs.waiting:
        image = with_banner(
            image, "press W to drive", NOTE_COLOR, "the clock starts with the first key"
        )
    elif fs.outcome:
        hint = f"return {fs.episode_return:+.2f} after {t:.1f} s"
        hint += f"   {fs.done_hint}" if fs.done_hint else ""
        image = with_banner(image, fs.outcome, outcome_color(fs.outcome), hint)
    return image, with_panel(image, hud_lines(fs), view.panel_px)


def hud_lines(fs: FrameState) -> list[Line]:
    """HUD and key-help lines for the panel."""
    from truckrl.tasks import shown_float

    s, cfg = fs.state, fs.config
    tol_pos, tol_ang = fs.tolerance
    status = "WAITING" if fs.waiting else "PAUSED" if fs.paused else ""
    v = float(s["speed"])
    lines: list[Line] = [
        (f"mode {fs.mode.upper()}  {status}", NOTE_COLOR if status else COLORS["hud"]),
        f"control {cfg.control.longitudinal} / {cfg.control.lateral}",
        f"step {int(s['step_count'])}/{cfg.max_steps}   scenes {fs.episodes_done}",
        f"speed {v:6.2f} m/s  acc {float(s['accel']):+5.2f}  gear {gear(v)}",
        f"steer {math.degrees(s['steer']):+6.1f} deg  rate {math.degrees(s['steer_rate']):+5.1f}",
        f"articulation {math.degrees(s['pose'][3]):+6.1f} deg",
        "",
        *(
            f"{q.label:<16} {shown_float(q, float(s[q.key])):7.2f} {q.shown_unit}"
            for q in fs.task.error_quantities
        ),
        f"tolerance {tol_pos:.2f} m, {math.degrees(tol_ang):.1f} deg",
        f"difficulty {fs.difficulty:.1f}",
        "",
    ]
    keys = ("reward", *fs.task.reward_keys)
    r = {k: fs.rewards.get(k, 0.0) for k in keys}
    lines.append(f"return {fs.episode_return:+8.3f}  last {r['reward']:+.3f}")
    terms = [f"{k.removeprefix('r_')[:9]:<9} {r[k]:+.3f}" for k in keys[1:]]
    lines += [" " + "  ".join(terms[i : i + 2]) for i in range(0, len(terms), 2)]
    if fs.last_action is not None:
        a = list(fs.last_action)
        lines.append(f" action {a[0]:+.2f} {a[1]:+.2f}")
    else:  # same line count at step 0: the panel does not jump at the first step
        lines.append(" action   --    --")
    lines += [(f"outcome {fs.outcome or 'driving'}", outcome_color(fs.outcome)), ""]
    lines += [f"{k}\t{v}" for k, v in fs.key_rows]
    return lines
