"""Shared benchmark plumbing: timing a call, printing a table, writing the JSON record."""

from __future__ import annotations

import json
import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

#: Where benchmark records go, relative to the working directory (git-ignored).
DEFAULT_OUT_DIR = Path("outputs") / "bench"


def time_call(
    fn: Callable[[], Any],
    budget_s: float,
    max_repeats: int = 1000,
    min_repeats: int = 1,
    sync: Callable[[], None] | None = None,
) -> dict[str, float]:
    """Time ``fn()`` after one warm-up call, repeating until about ``budget_s`` seconds are spent.

    Args:
        fn: the call to time.
        budget_s: wall time [s] to spend on timed repeats (the warm-up call sets the count).
        max_repeats / min_repeats: bounds on the number of timed repeats.
        sync: called after each repeat before reading the clock (e.g. ``torch.cuda.synchronize``).

    Returns:
        ``{"median_s", "min_s", "repeats"}``: per-call wall times [s].
    """
    sync = sync or (lambda: None)
    t0 = time.perf_counter()
    fn()
    sync()
    first = time.perf_counter() - t0
    repeats = int(min(max_repeats, max(min_repeats, budget_s / max(first, 1e-9))))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    times.sort()
    return {"median_s": times[len(times) // 2], "min_s": times[0], "repeats": repeats}


def fill_unset(cfg: Any, argv: Sequence[str], values: dict[str, Any]) -> None:
    """Set the fields ``values`` on ``cfg`` where the ``KEY=VALUE`` arguments ``argv`` did not
    (a benchmark's ``quick=true`` defaults: what the user gives wins)."""
    given = {a.partition("=")[0] for a in argv}
    for k, v in values.items():
        if k not in given:
            setattr(cfg, k, v)


def format_table(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """Rows of ``{column: value}`` as a markdown table (floats to 4 significant digits)."""
    if not rows:
        return "(no rows)"
    columns = list(columns or rows[0].keys())

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:,.0f}" if abs(v) >= 1000 else f"{v:.4g}"
        return "" if v is None else str(v)

    body = [[cell(r.get(c)) for c in columns] for r in rows]
    widths = [max(len(c), *(len(b[i]) for b in body)) for i, c in enumerate(columns)]
    lines = [
        "| " + " | ".join(c.rjust(w) for c, w in zip(columns, widths, strict=True)) + " |",
        "|" + "|".join("-" * (w + 1) + ":" for w in widths) + "|",
    ]
    lines += [
        "| " + " | ".join(v.rjust(w) for v, w in zip(b, widths, strict=True)) + " |" for b in body
    ]
    return "\n".join(lines)


def print_table(
    title: str, rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None
) -> str:
    """Print ``title`` and the markdown table of ``rows``; return the table text."""
    text = format_table(rows, columns)
    print(f"\n## {title}\n\n{text}", flush=True)
    return text


def machine_info() -> dict[str, Any]:
    """What the numbers were measured on."""
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
        "load_avg": os.getloadavg() if hasattr(os, "getloadavg") else None,
    }


def write_json(name: str, payload: dict[str, Any], out: str | Path | None = None) -> Path:
    """Write ``payload`` plus machine info to ``out`` when it names a ``.json`` file, else to
    ``<out>/<name>-<timestamp>.json`` (``out`` None: :data:`DEFAULT_OUT_DIR`); return the path."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(out) if out is not None else DEFAULT_OUT_DIR
    path = out if out.suffix == ".json" else out / f"{name}-{stamp}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    from truckrl.cli import provenance

    # the device measured: the payload's own, or its command's (bench env keeps it in "args")
    device = str(payload.get("device") or payload.get("args", {}).get("device") or "cpu")
    record = {
        "benchmark": name,
        "time": stamp,
        "provenance": provenance(device),
        "machine": machine_info(),
        **payload,
    }
    path.write_text(json.dumps(record, indent=2, default=str))
    print(f"\nwrote {path}", flush=True)
    return path


#: RGB colours of the series of a log-log panel, in order.
SERIES_COLORS = ((70, 140, 255), (235, 145, 45), (60, 170, 90), (200, 70, 70))


def _decades(lo: float, hi: float) -> list[float]:
    """Powers of ten from below ``lo`` to above ``hi`` (grid lines of a log axis)."""
    a, b = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    return [10.0**k for k in range(a, b + 1)]


def _tick(v: float) -> str:
    """Short axis label: 3 -> "3", 1024 -> "1024", 16384 -> "16k", 2.5e6 -> "2.5M"."""
    if v >= 1e6:
        return f"{v / 1e6:.3g}M"
    if v >= 1e4:
        return f"{v / 1e3:.3g}k"
    return f"{v:g}"


def render_loglog_panels(
    panels: Sequence[tuple[str, str, dict[str, Sequence[tuple[float, float]]]]],
    panel_w: int = 420,
    height: int = 340,
) -> np.ndarray:
    """Panels side by side, each ``(title, x label, {series: [(x, y), ...]})`` on log-log axes
    (x and y > 0), drawn with OpenCV as :mod:`truckrl.viz.curves` does: ``[height, W, 3]`` RGB."""
    import cv2

    imgs = []
    left, top, bottom = 62, 34, height - 52
    right = panel_w - 14
    font, grey = cv2.FONT_HERSHEY_SIMPLEX, (60, 60, 60)
    for title, xlabel, series in panels:
        img = np.full((height, panel_w, 3), 255, np.uint8)
        pts = [p for s in series.values() for p in s if p[0] > 0 and p[1] > 0]
        if pts:
            xs, ys = [p[0] for p in pts], [p[1] for p in pts]
            x_lo, x_hi = min(xs), max(xs)
            x_lo, x_hi = (x_lo / 2, x_hi * 2) if x_lo == x_hi else (x_lo, x_hi)
            y_lo, y_hi = min(ys) / 1.5, max(ys) * 1.5
            lx0, lx1, ly0, ly1 = (math.log10(v) for v in (x_lo, x_hi, y_lo, y_hi))

            def px(x: float, y: float, lx0=lx0, lx1=lx1, ly0=ly0, ly1=ly1) -> tuple[int, int]:
                u = (math.log10(x) - lx0) / (lx1 - lx0)
                w = (math.log10(y) - ly0) / (ly1 - ly0)
                return int(round(left + u * (right - left))), int(
                    round(bottom - w * (bottom - top))
                )

            for d in _decades(y_lo, y_hi):
                if y_lo <= d <= y_hi:
                    _, yy = px(x_lo, d)
                    cv2.line(img, (left, yy), (right, yy), (225, 225, 225), 1)
                    cv2.putText(img, _tick(d), (6, yy + 4), font, 0.4, grey, 1, cv2.LINE_AA)
            for x in sorted(set(xs)):
                xx, _ = px(x, y_lo)
                cv2.line(img, (xx, bottom), (xx, bottom + 4), grey, 1)
                label = _tick(x)
                cv2.putText(
                    img, label, (xx - 4 * len(label), bottom + 17), font, 0.38, grey, 1, cv2.LINE_AA
                )
            legend_x = left + 6
            for (name, s), color in zip(series.items(), SERIES_COLORS, strict=False):
                line = np.array([px(x, y) for x, y in s if x > 0 and y > 0], np.int32)
                if len(line):
                    cv2.polylines(img, [line], False, color, 2, cv2.LINE_AA)
                    for p in line:
                        cv2.circle(img, (int(p[0]), int(p[1])), 3, color, -1, cv2.LINE_AA)
                cv2.putText(img, name, (legend_x, top + 16), font, 0.45, color, 1, cv2.LINE_AA)
                legend_x += 9 * len(name) + 18
        cv2.rectangle(img, (left, top), (right, bottom), (120, 120, 120), 1)
        cv2.putText(img, title, (left, 22), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, xlabel + " (log)", (right - 150, bottom + 36), font, 0.4, grey, 1)
        imgs.append(img)
    return np.concatenate(imgs, axis=1)


def draw_loglog_panels(
    panels: Sequence[tuple[str, str, dict[str, Sequence[tuple[float, float]]]]],
    path: str | Path,
) -> Path:
    """:func:`render_loglog_panels` written to ``path`` (PNG); returns the path."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    img = render_loglog_panels(panels)
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path
