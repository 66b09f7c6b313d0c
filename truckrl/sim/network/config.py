"""The one config of road networks (:class:`NetworkConfig`) and the slot counts it implies.

Every range here is what a random network draws from and what a block in a YAML layout
(:mod:`truckrl.sim.network.layout`) may hold: the slot counts (polyline pieces of curves and
rings, footprint rectangles) are derived from the ranges' upper ends, so any value inside them
keeps the chord error below ``chord_error``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from truckrl.config.fields import ConfigError, param, validate

#: Where a network config sits in the env config (the ``network`` task's ``env.task.network``),
#: the prefix of its fields in error messages.
WHERE = "env.task.network"
#: Block type names, indexed by the ``block_type`` values of a network.
BLOCK_NAMES: tuple[str, ...] = (
    "straight",
    "curve",
    "crossing",
    "t_junction",
    "roundabout",
    "median",
)
STRAIGHT, CURVE, CROSSING, T_JUNCTION, ROUNDABOUT, MEDIAN = range(len(BLOCK_NAMES))
#: Sockets (road ends) of each block type, the entry included (a roundabout's 4th is optional).
SOCKETS: tuple[int, ...] = (2, 2, 4, 3, 4, 2)
#: Most sockets of any block.
MAX_SOCKETS = max(SOCKETS)


def arc_pieces(angle: float, radius: float, chord_error: float) -> int:
    """Fewest equal pieces of a polyline inscribed in an arc of ``angle`` [rad] and ``radius``
    [m] whose chords stay within ``chord_error`` [m] of the arc: a chord spanning ``d`` rad lies
    ``radius * (1 - cos(d / 2))`` inside it at its middle."""
    if chord_error >= radius:
        return 1
    step = 2.0 * math.acos(1.0 - chord_error / radius)
    return max(1, math.ceil(angle / step - 1e-9))


@dataclass
class NetworkConfig:
    """Random road networks: which blocks, how many, and the ranges of their shapes.

    All lengths in metres, angles in radians, each value drawn uniformly from its ``[min, max]``
    per block (the road width per network). The defaults are two-lane roads the truck of the
    other tasks can follow (curves it can follow, junction arms longer than a rig) but not turn
    right on at a junction's sharp curb corner within its lane: the ``network`` task draws
    12-18 m roads instead (docs/networks.md, "A scripted driver"). The source paper names blocks
    but no dimensions. Bounds that depend on other fields are checked
    in ``__post_init__`` and named in each field's doc.
    """

    block_types: tuple[str, ...] = param(
        BLOCK_NAMES, choices=BLOCK_NAMES, unit="-", doc="block types a random network draws from"
    )
    num_blocks: tuple[int, int] = param(
        (3, 5), lo=1, hi=64, unit="-", doc="blocks per network K, drawn per network"
    )
    road_width: tuple[float, float] = param(
        (8.0, 10.0),
        lo=2.0,
        hi=40.0,
        unit="m",
        doc="road width, curb to curb (two lanes), one per network",
    )
    chord_error: float = param(
        0.05,
        lo=1e-4,
        hi=1.0,
        unit="m",
        doc="largest gap between an arc and its polyline (curves, ring, lanes)",
        source="issue 42 suggests 5 cm",
    )
    straight_length: tuple[float, float] = param(
        (20.0, 60.0), lo=1.0, hi=1e4, unit="m", doc="straight block length"
    )
    curve_radius: tuple[float, float] = param(
        (20.0, 60.0),
        lo=1.0,
        hi=1e4,
        unit="m",
        doc="curve centre-line radius (min > road_width max / 2 + 1)",
    )
    curve_angle: tuple[float, float] = param(
        (math.pi / 6, math.pi / 2),
        lo=0.01,
        hi=math.pi,
        unit="rad",
        doc="curve turn angle, left or right with equal odds",
    )
    crossing_angle: tuple[float, float] = param(
        (math.pi / 3, 2 * math.pi / 3),
        lo=0.2,
        hi=math.pi - 0.2,
        unit="rad",
        doc="angle between the two roads of a crossing",
    )
    junction_arm: tuple[float, float] = param(
        (20.0, 35.0),
        lo=1.0,
        hi=1e4,
        unit="m",
        doc="crossing / T-junction centre to road end (min clears the junction, see __post_init__)",
    )
    roundabout_radius: tuple[float, float] = param(
        (12.0, 20.0),
        lo=1.0,
        hi=1e4,
        unit="m",
        doc="ring centre-line radius (min - road_width max / 2 >= 2: the island)",
    )
    roundabout_arms: tuple[int, int] = param(
        (3, 4), lo=3, hi=4, unit="-", doc="roads into a roundabout, evenly spaced"
    )
    roundabout_arm: tuple[float, float] = param(
        (10.0, 20.0),
        lo=1.0,
        hi=1e4,
        unit="m",
        doc="ring's outer curb to road end (min > clearance / 2 + socket_slack)",
    )
    median_length: tuple[float, float] = param(
        (50.0, 90.0),
        lo=1.0,
        hi=1e4,
        unit="m",
        doc="median block length (min > 2 (median_lead + median_taper))",
    )
    median_width: tuple[float, float] = param(
        (1.0, 3.0), lo=0.1, hi=20.0, unit="m", doc="median island width; the road widens by it"
    )
    median_lead: float = param(
        5.0, lo=0.0, hi=1e3, unit="m", doc="plain road before and after a median's tapers"
    )
    median_taper: float = param(
        10.0, lo=0.1, hi=1e3, unit="m", doc="length over which the road widens round a median"
    )
    clearance: float = param(
        2.0,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="least gap between the roads of two blocks (the overlap test's padding)",
    )
    socket_slack: float = param(
        0.5,
        lo=0.01,
        hi=10.0,
        unit="m",
        doc="footprints end this short of their road ends, so joined blocks do not overlap",
    )
    rounds: int = param(
        8, lo=1, hi=256, unit="-", doc="draws per block before its chain ends (overlap rejection)"
    )

    def __post_init__(self) -> None:
        validate(self, WHERE)
        w_lo, w_hi = self.road_width
        if self.curve_radius[0] <= 0.5 * w_hi + 1.0:
            raise ConfigError(
                f"{WHERE}.curve_radius = {list(self.curve_radius)}: min must exceed "
                f"road_width max / 2 + 1 = {0.5 * w_hi + 1.0}"
            )
        if self.roundabout_radius[0] - 0.5 * w_hi < 2.0:
            raise ConfigError(
                f"{WHERE}.roundabout_radius = {list(self.roundabout_radius)}: min must be at "
                f"least road_width max / 2 + 2 = {0.5 * w_hi + 2.0} (an island of radius >= 2 m)"
            )
        need = self.junction_extent() + 0.5 * self.clearance + self.socket_slack
        if self.junction_arm[0] <= need:
            raise ConfigError(
                f"{WHERE}.junction_arm = {list(self.junction_arm)}: min must exceed {need:.3f} "
                "(the crossing's extent at the widest road and sharpest angle, plus "
                "clearance / 2 + socket_slack)"
            )
        need = 0.5 * self.clearance + self.socket_slack
        if self.roundabout_arm[0] <= need:
            raise ConfigError(
                f"{WHERE}.roundabout_arm = {list(self.roundabout_arm)}: min must exceed "
                f"clearance / 2 + socket_slack = {need}"
            )
        need = 2.0 * (self.median_lead + self.median_taper)
        if self.median_length[0] <= need:
            raise ConfigError(
                f"{WHERE}.median_length = {list(self.median_length)}: min must exceed "
                f"2 (median_lead + median_taper) = {need}"
            )

    def junction_extent(self) -> float:
        """Largest extent [m] of a crossing's parallelogram along either road from its centre:
        ``(w / 2) (1 + |cos a|) / sin a`` at the widest road and the sharpest angle."""
        a = min(self.crossing_angle[0], math.pi - self.crossing_angle[1])
        return 0.5 * self.road_width[1] * (1.0 + abs(math.cos(a))) / math.sin(a)

    # ---------------------------------------------------------------- slot counts (derived)
    def curve_pieces(self) -> int:
        """Polyline pieces of a curve (its outer curb: the largest radius has the largest error)."""
        rho = self.curve_radius[1] + 0.5 * self.road_width[1]
        return arc_pieces(self.curve_angle[1], rho, self.chord_error)

    def island_pieces(self) -> int:
        """Polyline pieces of a roundabout's island (a closed ring)."""
        rho = self.roundabout_radius[1] - 0.5 * self.road_width[0]
        return max(3, arc_pieces(2.0 * math.pi, rho, self.chord_error))

    def ring_pieces(self) -> int:
        """Polyline pieces of a roundabout's ring lane (its centre-line, closed)."""
        return max(3, arc_pieces(2.0 * math.pi, self.roundabout_radius[1], self.chord_error))

    def outer_arc_pieces(self) -> int:
        """Polyline pieces of each outer-curb arc between two roundabout arms (at most 2 pi / 3)."""
        rho = self.roundabout_radius[1] + 0.5 * self.road_width[1]
        return arc_pieces(2.0 * math.pi / self.roundabout_arms[0], rho, self.chord_error)

    def curve_footprints(self) -> int:
        """Footprint rectangles of a curve. Each is aligned with the chord of its piece of the
        centre-line (angle ``d``), ``w / 2 + sag + clearance / 2`` to each side; at a road end it
        starts ``socket_slack`` in, and its corner stays on its side of the end's line when
        ``tan(d / 2) <= 0.9 socket_slack / (w / 2 + sag + clearance / 2)`` (``sag`` the piece's
        sagitta), so joined blocks never overlap there."""
        count = 1
        while True:
            d = self.curve_angle[1] / count
            sag = self.curve_radius[1] * (1.0 - math.cos(0.5 * d))
            reach = 0.5 * (self.road_width[1] + self.clearance) + sag
            if math.tan(0.5 * d) <= 0.9 * self.socket_slack / reach:
                return count
            count += 1
