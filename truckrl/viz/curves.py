"""Learning curves of a training run as an image, drawn with OpenCV (no plotting library needed).

``truckrl tools curves run=outputs/RUN_DIR out=curve.png``
(:mod:`truckrl.tools.curves`) reads the run's TensorBoard events (``<run_dir>/tb``) and draws, against wall-clock minutes,
the curriculum difficulty, the success rate with its EMA, and the final position error. The same
data is printed as a table of the first time each difficulty was reached.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

PANELS = (
    ("difficulty", ("curriculum/difficulty",), (0.0, None)),
    ("success rate", ("episode/success_rate", "episode/success_ema"), (0.0, 1.0)),
    ("final position error [m]", ("episode/final_pos_error_m",), (0.0, None)),
)
LINE_COLORS = ((70, 140, 255), (235, 145, 45))  # RGB, first and second series of a panel


def load_scalars(run_dir: str | Path) -> dict[str, np.ndarray]:
    """``{tag: [K, 3] array of (wall minutes since start, frames, value)}`` from ``run_dir/tb``.

    Minutes count training sessions only: a resumed run writes one event file per session, and
    each later file's clock is shifted to start where the previous file's last event was, so the
    time a run lay stopped between sessions is not counted (the time before a session's first
    event, e.g. compiling, is not either).
    """
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tb = Path(run_dir) / "tb"
    if not tb.is_dir():
        raise FileNotFoundError(f"no TensorBoard directory at {tb}")
    # events.out.tfevents.<start time>.<host>.<pid>.<n>: a session's writers share its pid
    groups: dict[str, list[Path]] = {}
    for f in sorted(tb.glob("events.out.tfevents.*"), key=lambda f: int(f.name.split(".")[3])):
        groups.setdefault(f.name.rsplit(".", 2)[-2], []).append(f)
    sessions: list[dict[str, np.ndarray]] = []
    for group in groups.values() or [[tb]]:
        got: dict[str, list] = {}
        for f in group:
            acc = EventAccumulator(str(f), size_guidance={"scalars": 0})
            acc.Reload()
            for tag in acc.Tags()["scalars"]:
                got.setdefault(tag, []).extend(
                    (e.wall_time, e.step, e.value) for e in acc.Scalars(tag)
                )
        if got:
            sessions.append({t: np.array(sorted(v), dtype=np.float64) for t, v in got.items()})
    if not sessions:
        raise ValueError(f"no scalars in {tb}")
    end = 0.0  # [s] training time at the end of the sessions so far
    for got in sessions:
        t0 = min(v[0, 0] for v in got.values())
        t1 = max(v[-1, 0] for v in got.values())
        for v in got.values():
            v[:, 0] = (v[:, 0] - t0 + end) / 60.0
        end += t1 - t0
    out = {}
    for tag in {t for got in sessions for t in got}:
        out[tag] = np.concatenate([got[tag] for got in sessions if tag in got])
    return out


def milestones(scalars: dict[str, np.ndarray]) -> list[dict]:
    """First wall time [min] and frame count at which each difficulty level was reached."""
    d = scalars.get("curriculum/difficulty")
    if d is None:
        return []
    rows, seen = [], set()
    for minutes, frames, value in d:
        if value not in seen:
            seen.add(value)
            rows.append({"difficulty": value, "minutes": minutes, "frames": int(frames)})
    return rows


def smooth(y: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average (edges use the available samples)."""
    if window <= 1 or len(y) < 3:
        return y
    kernel = np.ones(window)
    num = np.convolve(y, kernel, mode="same")
    den = np.convolve(np.ones_like(y), kernel, mode="same")
    return num / den


def render(scalars: dict[str, np.ndarray], width: int = 900, panel_h: int = 220) -> np.ndarray:
    """The curve panels stacked vertically: ``[3 * panel_h, width, 3]`` uint8 RGB."""
    t_max = max(v[-1, 0] for v in scalars.values()) or 1.0
    panels = []
    left, right, top, bottom = 70, width - 20, 30, panel_h - 35  # plot box [px]
    for title, tags, (lo, hi) in PANELS:
        img = np.full((panel_h, width, 3), 255, np.uint8)
        series = [scalars[t] for t in tags if t in scalars]
        if series:
            y_hi = hi if hi is not None else max(1e-6, max(float(s[:, 2].max()) for s in series))
            y_lo = lo if lo is not None else min(float(s[:, 2].min()) for s in series)
            span = (y_hi - y_lo) or 1.0

            def px(t, y, y_lo=y_lo, span=span):
                x = left + (right - left) * t / t_max
                return x, bottom - (bottom - top) * (y - y_lo) / span

            for frac in (0.0, 0.5, 1.0):
                y = y_lo + frac * span
                _, yy = px(0.0, y)
                cv2.line(img, (left, int(yy)), (right, int(yy)), (225, 225, 225), 1)
                cv2.putText(
                    img, f"{y:.3g}", (5, int(yy) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (60,) * 3, 1
                )
            for s, color, tag in zip(series, LINE_COLORS, tags, strict=False):
                ys = s[:, 2] if "difficulty" in tag else smooth(s[:, 2], 5)
                pts = np.array([px(t, y) for t, y in zip(s[:, 0], ys, strict=True)], np.float64)
                cv2.polylines(img, [np.round(pts).astype(np.int32)], False, color, 2, cv2.LINE_AA)
            x = left + 5
            for tag, color in zip(tags, LINE_COLORS, strict=False):
                if tag in scalars:
                    name = tag.split("/")[1]
                    cv2.putText(img, name, (x, top + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1)
                    x += 10 * len(name) + 20
        cv2.rectangle(img, (left, top), (right, bottom), (120, 120, 120), 1)
        cv2.putText(
            img, title, (left, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA
        )
        for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
            x = int(left + (right - left) * frac)
            cv2.putText(
                img,
                f"{t_max * frac:.0f}",
                (x - 8, bottom + 16),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.4,
                (60,) * 3,
                1,
            )
        cv2.putText(
            img,
            "wall-clock minutes",
            (right - 150, bottom + 30),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            (60,) * 3,
            1,
        )
        panels.append(img)
    return np.concatenate(panels, axis=0)
