"""Video files, animated GIFs and frame strips from RGB frames (no moviepy, no window).

The one video writer of the project: the viewer streams frames into :class:`Mp4Writer` as they are
shown, and training videos write a whole episode with :func:`write_mp4`. Files are H.264 (High
profile, yuv420p) in an mp4 container with the index at the front (``+faststart``): what browsers,
VS Code and TensorBoard's neighbours play. The encoder is libx264 inside PyAV's wheels (``av``, a
dependency), so nothing outside Python is needed.
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterable, Sequence
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

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
