"""What a training run shows while it runs and says when it ends.

The progress bar measures the stop criterion that binds: minutes when ``max_minutes`` will end
the run first, frames when ``total_frames`` will (with both set, whichever is further along;
the one further along ends the run first at a steady frame rate). The curriculum difficulty (and
``stop_difficulty``), the success EMA and one frames/s figure are labelled fields beside it.

:func:`stop_lines` are the last lines of a run: why it stopped, the run dir, and the commands to
evaluate, watch and plot it (and to continue it when time, frames or a signal stopped it).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from tqdm import tqdm

#: Why a run stopped, as :func:`stop_reason` names it, and how the last line says it.
REASONS = {
    "time": "max_minutes reached",
    "frames": "total_frames reached",
    "difficulty": "stop_difficulty reached",
}


def stop_reason(
    frames: int,
    minutes: float,
    difficulty: float,
    total_frames: int | None,
    max_minutes: float | None,
    stop_difficulty: float | None,
) -> str | None:
    """``"difficulty"``, ``"frames"``, ``"time"`` or None (keep going)."""
    if stop_difficulty is not None and difficulty >= stop_difficulty:
        return "difficulty"
    if total_frames is not None and frames >= total_frames:
        return "frames"
    if max_minutes is not None and minutes >= max_minutes:
        return "time"
    return None


def _count(x: float) -> str:
    """``1234`` -> ``1.2k``, ``35_000_000`` -> ``35.0M``."""
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.1f}{unit}"
    return f"{x:.0f}"


def shown_path(p: Path) -> str:
    """``p`` relative to the working dir when inside it (as a user would type it), quoted."""
    try:
        p = p.resolve().relative_to(Path.cwd().resolve())
    except ValueError:
        p = p.resolve()
    return shlex.quote(str(p))


class Progress:
    """tqdm bar against the binding stop criterion (see the module doc)."""

    def __init__(
        self,
        total_frames: int | None,
        max_minutes: float | None,
        stop_difficulty: float | None,
        enabled: bool,
    ) -> None:
        self.total_frames, self.max_minutes = total_frames, max_minutes
        self.stop_difficulty = stop_difficulty
        first = "first batch and update (torch.compile first with env / policy / ppo compile)"
        self.bar = tqdm(total=1000, dynamic_ncols=True, disable=not enabled, file=sys.stderr,
                        bar_format=f"starting |{{bar}}| {first}")  # fmt: skip

    def update(
        self, frames: int, minutes: float, difficulty: float, ema: float, fps: float
    ) -> None:
        time_part = minutes / self.max_minutes if self.max_minutes else -1.0
        frame_part = frames / self.total_frames if self.total_frames else -1.0
        if time_part >= frame_part:
            measure = f"{minutes:.1f}/{self.max_minutes:g} min"
        else:
            measure = f"{_count(frames)}/{_count(self.total_frames)} frames"
        goal = f"/{self.stop_difficulty:g}" if self.stop_difficulty is not None else ""
        fields = f"difficulty {difficulty:g}{goal}, success EMA {ema:.2f}, {_count(fps)} frames/s"
        self.bar.bar_format = f"{measure} |{{bar}}| {fields}"
        self.bar.n = int(1000 * min(1.0, max(time_part, frame_part, 0.0)))
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def stop_lines(
    reason: str, run_dir: Path, iteration: int, frames: int, minutes: float, difficulty: float
) -> list[str]:
    """The last lines of a run: one line after a signal, else why, where, and what to run next."""
    run = shown_path(run_dir)
    where = (
        f"iteration {iteration}, {frames:,} frames, {minutes:.1f} min, difficulty {difficulty:g}"
    )
    checkpoint = shown_path(run_dir / "checkpoints" / "last.pt")
    resume = f"truckrl train resume={run}"
    if reason.startswith("SIG"):
        return [f"stopped by {reason} at {where}; checkpoint {checkpoint}; resume: {resume}"]
    lines = [
        f"stopped: {REASONS.get(reason, reason)} at {where}",
        f"run dir: {run} (checkpoint {checkpoint})",
        f"evaluate: truckrl eval checkpoint={run}",
        f"play: truckrl play checkpoint={run}",
        f"tensorboard: tensorboard --logdir {shown_path(run_dir / 'tb')}",
    ]
    if reason == "time":  # max_minutes counts each session
        lines.append(f"continue: {resume}")
    elif reason == "frames":  # total_frames counts all sessions together
        lines.append(f"continue: {resume} total_frames={2 * frames}")
    return lines
