"""What a training run shows while it runs and says when it ends.

The progress bar measures the stop criterion that binds: minutes when ``max_minutes`` will end
the run first, frames when ``total_frames`` will (with both set, whichever is further along;
the one further along ends the run first at a steady frame rate). The curriculum difficulty (and
``stop_difficulty``), the success EMA and one frames/s figure are labelled fields beside it.

:func:`stop_lines` are the last lines of a run: why it stopped, the run dir, and the commands to
evaluate, watch and plot it (and to continue it when time, frames or a signal stopped it).

:class:`Quality` watches the held-out checks for the run's headline learning figure: the first
one at or above ``log.quality_target`` at a curriculum difficulty >= ``log.quality_difficulty``
(``quality_reached``: minutes since the run's start, demonstrations included, and frames).
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
    "quality": "quality reached (stop_on_quality)",
}

#: Prefix of the ``quality_reached`` line and scalars.
QUALITY = "quality"
#: Slack [fraction] on the target: a held-out rate k/n is a float32 mean (190/200 reads
#: 0.94999999), so a rate that equals the target must not miss it by its rounding (2**-24 is
#: float32's relative step; 1e-6 is well above it and below any 1/n of a real evaluation).
QUALITY_SLACK = 1e-6


class Quality:
    """The run's first held-out check with success >= ``target`` at difficulty >=
    ``difficulty`` (``log.quality_target``, ``log.quality_difficulty``).

    Args:
        target: held-out success rate in [0, 1].
        difficulty: curriculum difficulty at or above which a check counts.
        reached: the record a resumed run's checkpoint holds (``Counters.quality``), or None.

    Attributes:
        reached: None until a check meets the target, then ``{"minutes", "frames",
            "iteration", "difficulty", "success_rate"}`` of that check, never changed again.
    """

    def __init__(self, target: float, difficulty: float, reached: dict | None = None) -> None:
        self.target, self.difficulty = target, difficulty
        self.reached = dict(reached) if reached else None

    def check(
        self, success_rate: float, difficulty: float, minutes: float, frames: int, iteration: int
    ) -> dict | None:
        """The record when this check is the first to meet the target, else None.

        Args:
            success_rate: the check's held-out success rate in [0, 1].
            difficulty: the curriculum difficulty it was run at.
            minutes: the run's wall clock [min] since its start, all sessions, demos included.
            frames: training frames so far (all sessions).
            iteration: training iterations so far.
        """
        if self.reached is not None or difficulty < self.difficulty:
            return None
        if success_rate < self.target - QUALITY_SLACK:
            return None
        self.reached = {"minutes": float(minutes), "frames": int(frames),
                        "iteration": int(iteration), "difficulty": float(difficulty),
                        "success_rate": float(success_rate)}  # fmt: skip
        return self.reached

    def line(self) -> str:
        """``quality_reached: ...`` for the log, or what was not reached (the run's last lines)."""
        goal = f"held-out success >= {self.target:g} at difficulty >= {self.difficulty:g}"
        q = self.reached
        if q is None:
            return f"{QUALITY}_reached: not yet ({goal})"
        return (f"{QUALITY}_reached: {q['minutes']:.1f} min, {q['frames']:,} frames, iteration "
                f"{q['iteration']}, difficulty {q['difficulty']:g}, held-out success "
                f"{q['success_rate']:.3f} ({goal}; minutes since the run's start, "
                "demonstrations included)")  # fmt: skip

    def scalars(self) -> dict[str, float]:
        """``quality/reached_minutes`` and ``quality/reached_frames`` of the record (empty
        before it)."""
        q = self.reached
        if q is None:
            return {}
        return {
            f"{QUALITY}/reached_minutes": q["minutes"],
            f"{QUALITY}/reached_frames": q["frames"],
        }


def stop_reason(
    frames: int,
    minutes: float,
    difficulty: float,
    total_frames: int | None,
    max_minutes: float | None,
    stop_difficulty: float | None,
    quality: bool = False,
) -> str | None:
    """``"quality"`` (``quality``: stop_on_quality is set and quality_reached has fired),
    ``"difficulty"``, ``"frames"``, ``"time"`` or None (keep going)."""
    if quality:
        return "quality"
    if stop_difficulty is not None and difficulty >= stop_difficulty:
        return "difficulty"
    if total_frames is not None and frames >= total_frames:
        return "frames"
    if max_minutes is not None and minutes >= max_minutes:
        return "time"
    return None


def sweep_objective(curriculum: dict, threshold: float, step: float) -> float:
    """What ``truckrl train`` returns to a sweeper (``+launch=optuna`` maximizes it): the
    curriculum's progress in difficulty units, ``difficulty + step * min(ema / threshold, 1)``.

    Args:
        curriculum: the run's final curriculum state (``difficulty``, ``ema``; a checkpoint's
            ``curriculum`` entry).
        threshold: ``curriculum.threshold``, the EMA that promotes.
        step: ``curriculum.step``, the difficulty a promotion adds.

    The EMA counts as the share of the next promotion it has earned, so of two runs at the same
    difficulty the one closer to its next promotion ranks higher, and a promotion never lowers
    the value (the EMA restarts below the threshold, the difficulty gains ``step``).
    """
    share = min(float(curriculum["ema"]) / threshold, 1.0)
    return float(curriculum["difficulty"]) + step * share


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
    reason: str,
    run_dir: Path,
    iteration: int,
    frames: int,
    minutes: float,
    difficulty: float,
    quality: str | None = None,
) -> list[str]:
    """The last lines of a run: one line after a signal, else why, where, what to run next and
    the ``quality`` line (:meth:`Quality.line`) when given."""
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
    return lines + ([quality] if quality else [])
