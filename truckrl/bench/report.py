"""Shared benchmark plumbing: timing a call, printing a table, writing the JSON record."""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

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


def write_json(
    name: str,
    payload: dict[str, Any],
    out_dir: str | Path = DEFAULT_OUT_DIR,
    path: str | Path | None = None,
) -> Path:
    """Write ``payload`` plus machine info to ``<out_dir>/<name>-<timestamp>.json`` (or to
    ``path`` when given); return the path."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    path = Path(path) if path is not None else Path(out_dir) / f"{name}-{stamp}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"benchmark": name, "time": stamp, "machine": machine_info(), **payload}
    path.write_text(json.dumps(record, indent=2, default=str))
    print(f"\nwrote {path}", flush=True)
    return path
