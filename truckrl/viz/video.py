"""MP4 files and frame strips from RGB frames (OpenCV only; no moviepy, no window).

The one video writer of the project: the viewer streams frames into :class:`Mp4Writer` as they are
shown, and training videos write a whole episode with :func:`write_mp4`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np


class Mp4Writer:
    """Streams RGB frames ``[H, W, 3]`` uint8 to an mp4 file (codec mp4v).

    The file is opened at the first frame, whose size every later frame must have. Use as a
    context manager or call :meth:`close`.

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
        self._writer: cv2.VideoWriter | None = None

    def write(self, frame: np.ndarray) -> None:
        """Append one RGB frame ``[H, W, 3]`` uint8."""
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"expected an [H, W, 3] uint8 frame, got {frame.shape} {frame.dtype}")
        h, w = frame.shape[:2]
        if self._writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = cv2.VideoWriter(
                str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (w, h)
            )
            if not self._writer.isOpened():
                raise OSError(f"cannot open {self.path} for writing (OpenCV mp4v)")
            self._size = (w, h)
        elif (w, h) != self._size:
            raise ValueError(f"frame size {(w, h)} differs from the first frame's {self._size}")
        self._writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None

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


def frame_strip(frames, count: int = 5, height: int = 200, gap_px: int = 0) -> np.ndarray:
    """``count`` evenly spaced frames side by side, each resized to ``height`` px: ``[h, W, 3]``.

    Args:
        frames: ``[F, H, W, 3]`` uint8 array or a sequence of ``[H, W, 3]`` frames.
        gap_px: white gap between tiles [px].
    """
    if len(frames) == 0:
        raise ValueError("frame_strip needs at least one frame")
    idx = np.linspace(0, len(frames) - 1, num=min(count, len(frames))).round().astype(int)
    tiles = []
    for i in idx:
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
