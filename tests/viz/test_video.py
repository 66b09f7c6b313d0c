"""Video output: H.264 mp4 files that decode frame-exact, GIFs for TensorBoard, frame strips."""

from __future__ import annotations

import io

import numpy as np
import pytest

from truckrl.viz.video import (
    Mp4Writer,
    frame_strip,
    gif_bytes,
    probe_video,
    read_video,
    spread_indices,
    write_mp4,
)


def numbered_frames(n: int, h: int = 97, w: int = 161) -> np.ndarray:
    """Frame i: dark background with a bright 8-px bar at column 8 i (identifies the frame)."""
    frames = np.full((n, h, w, 3), (34, 38, 44), dtype=np.uint8)
    for i in range(n):
        frames[i, :, 8 * i : 8 * i + 8] = (245, 245, 245)
    return frames


def test_mp4_is_h264_and_decodes_frame_exact(tmp_path):
    frames = numbered_frames(17)  # odd size: padded to even by one edge pixel
    path = write_mp4(tmp_path / "sub" / "v.mp4", frames, fps=10.0)
    info = probe_video(path)
    assert info["codec"] == "h264" and info["pix_fmt"] == "yuv420p"  # what browsers play
    assert (info["width"], info["height"]) == (162, 98)
    assert info["fps"] == pytest.approx(10.0)
    assert info["frames"] == 17
    decoded = read_video(path)[:, :97, :161].astype(int)
    assert decoded.shape == frames.shape
    for i, f in enumerate(decoded):  # each decoded frame is the one written at its index
        bar = f[:, :, 0].mean(axis=0) > 140
        assert np.flatnonzero(bar).tolist() == list(range(8 * i, 8 * i + 8)), i
    assert np.abs(decoded - frames).mean() < 2.0


def test_cv2_reads_the_mp4_too(tmp_path):
    import cv2  # a dependency of the package (opencv-python-headless): never skipped

    path = write_mp4(tmp_path / "v.mp4", numbered_frames(6, 64, 96), fps=25.0)
    cap = cv2.VideoCapture(str(path))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == 6 and cap.get(cv2.CAP_PROP_FPS) == 25.0
    count = 0
    while cap.read()[0]:
        count += 1
    assert count == 6


def test_writer_checks_frames_and_fps(tmp_path):
    with pytest.raises(ValueError, match="fps"):
        Mp4Writer(tmp_path / "a.mp4", 0)
    with Mp4Writer(tmp_path / "b.mp4", 10) as w:
        w.write(np.zeros((32, 32, 3), np.uint8))
        with pytest.raises(ValueError, match="differs"):
            w.write(np.zeros((32, 34, 3), np.uint8))
        with pytest.raises(ValueError, match="uint8"):
            w.write(np.zeros((32, 32, 3), np.float32))
    assert probe_video(tmp_path / "b.mp4")["frames"] == 1


def test_gif_has_every_frame_at_the_frame_rate():
    from PIL import Image

    data = gif_bytes(numbered_frames(9), fps=10.0, scale=0.5)
    assert data[:6] == b"GIF89a"
    im = Image.open(io.BytesIO(data))
    assert im.n_frames == 9 and im.size == (80, 48)  # round(161 / 2), round(97 / 2)
    assert im.info["duration"] == 100 and im.info["loop"] == 0


def test_strip_spreads_tiles_over_the_episode():
    assert spread_indices(4, 200).tolist() == [0, 66, 133, 199]
    assert spread_indices(4, 2).tolist() == [0, 1]
    strip = frame_strip(numbered_frames(10, 40, 80), count=4, height=20, gap_px=3)
    assert strip.shape == (20, 4 * 40 + 3 * 3, 3)
