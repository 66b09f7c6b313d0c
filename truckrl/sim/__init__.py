"""Pure-torch simulator core: geometry, vehicle, control, scenes, collision, LiDAR.

Usable without TorchRL. Every function is batched over leading dimensions; see each module's
docstrings for shapes and units.
"""

from truckrl.sim.geometry import (
    point_segment_distance,
    polygon_segments,
    ray_segment_distance,
    rectangle_corners,
    rectangle_segments,
    segment_segment_distance,
    segments_intersect,
    to_local,
    wrap_angle,
)
from truckrl.sim.validation import ConfigError

__all__ = [
    "ConfigError",
    "point_segment_distance",
    "polygon_segments",
    "ray_segment_distance",
    "rectangle_corners",
    "rectangle_segments",
    "segment_segment_distance",
    "segments_intersect",
    "to_local",
    "wrap_angle",
]
