"""The viewer's camera and frame layout config (``view.*``), importable without torch."""

from __future__ import annotations

from dataclasses import dataclass

from truckrl.config.fields import param, validate


@dataclass(frozen=True)
class ViewConfig:
    """Camera and frame layout (``view.*``)."""

    follow: bool = param(
        False, doc="false: fixed camera on the start truck and the goal; true: follow the truck"
    )
    size_px: int = param(640, lo=64, hi=4096, unit="px", doc="side of the bird's-eye view")
    half_extent: float = param(
        40.0, lo=1.0, hi=1e4, unit="m", doc="half the view side (at least half start-goal + margin)"
    )
    margin: float = param(15.0, lo=0.0, hi=1e4, unit="m", doc="space around start and goal")
    follow_beyond: float = param(
        80.0,
        lo=1.0,
        hi=1e4,
        unit="m",
        doc="a scene whose start, goal and route need a larger half view is followed, north up, "
        "at the LiDAR's range + margin",
    )
    panel_px: int = param(340, lo=0, hi=4096, unit="px", doc="width of the HUD panel (0: none)")

    def __post_init__(self) -> None:
        validate(self, "view")
