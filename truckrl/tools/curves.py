"""``truckrl tools curves``: a training run's learning curves as a PNG, and the first time each
difficulty was reached as a table (:mod:`truckrl.viz.curves`).

    truckrl tools curves run=outputs/RUN_DIR out=curve.png

Bad input (no run dir, a run without TensorBoard scalars) prints one line and exits with code 2.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from truckrl.config.fields import ConfigError, param, validate

PROG = "truckrl tools curves"
ABOUT = "Draw a training run's learning curves (difficulty, success rate, final error) to a PNG."


@dataclass
class CurvesConfig:
    """Which run and where to draw."""

    run: str | None = param(None, doc="training run directory (holds tb/); required")
    out: str | None = param(None, doc="PNG file; null: <run>/learning_curve.png")

    def __post_init__(self) -> None:
        validate(self)
        if not self.run:
            raise ConfigError("run is required: run=<training run directory>")
        if self.out is not None and not self.out.lower().endswith(".png"):
            raise ConfigError(f"out = {self.out!r} must end in .png")


def run(cfg: CurvesConfig) -> None:
    from pathlib import Path

    import cv2

    from truckrl.viz.curves import load_scalars, milestones, render

    try:
        scalars = load_scalars(cfg.run)
    except (FileNotFoundError, ValueError) as e:
        raise ConfigError(f"run = {cfg.run!r}: {e}") from None
    out = Path(cfg.out or Path(cfg.run) / "learning_curve.png")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), cv2.cvtColor(render(scalars), cv2.COLOR_RGB2BGR)):
        raise ConfigError(f"out = {str(out)!r}: could not be written")
    print("| difficulty | wall minutes | frames |\n|---:|---:|---:|")
    for m in milestones(scalars):
        print(f"| {m['difficulty']:g} | {m['minutes']:.1f} | {m['frames']:,} |")
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    cfg = key_value_config(CurvesConfig, sys.argv[1:] if argv is None else argv, PROG, ABOUT)
    return run_or_fail(run, cfg)


if __name__ == "__main__":
    sys.exit(main())
