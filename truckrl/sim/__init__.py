"""Pure-torch simulator core: geometry, vehicle, control, collision, LiDAR.

World physics and geometry that any task uses; the scene generators live in the task folders
(:mod:`truckrl.tasks`). Usable without TorchRL. Every function is batched over leading
dimensions; shapes and units are in each module's docstrings. A minimal loop::

    import torch
    from truckrl.sim import (VehicleConfig, beam_angles, kinematics_step, lidar_scan,
                             rectangle_segments, sample_vehicle_params)

    g = torch.Generator().manual_seed(0)
    params = sample_vehicle_params(VehicleConfig(), 8, g)          # {key: [8]}
    c = torch.full((8,), 20.0)                                     # a box 20 m ahead of each truck
    segments = rectangle_segments(c, 0 * c, 0 * c, 0 * c + 2, 0 * c + 2, 0 * c + 1)  # [8, 4, 4]
    pose = torch.zeros(8, 4)                                       # (x, y, theta, phi)
    pose, _ = kinematics_step(pose, torch.full((8,), 5.0), torch.zeros(8), params, dt=0.1)
    ranges = lidar_scan(pose[:, :2], pose[:, 2], segments, torch.ones(8, 4, dtype=torch.bool),
                        beam_angles(16), max_range=50.0)           # [8, 16] metres
"""

from truckrl.config.fields import ConfigError
from truckrl.sim.collision import contour_collides, truck_collides
from truckrl.sim.control import (
    CONTROL_KEYS,
    LATERAL_MODES,
    LONGITUDINAL_MODES,
    MODE_TABLE,
    Control,
    ControlConfig,
    commanded,
)
from truckrl.sim.geometry import (
    point_segment_distance,
    polygon_segments,
    ray_segment_distance,
    rectangle_corners,
    rectangle_segments,
    segment_box_overlap,
    segment_segment_distance,
    segments_intersect,
    to_local,
    wrap_angle,
)
from truckrl.sim.lidar import LidarConfig, SweepLidar, beam_angles, lidar_oracle, lidar_scan
from truckrl.sim.vehicle import (
    PARAM_KEYS,
    VehicleConfig,
    jackknifed,
    kinematics_step,
    sample_vehicle_params,
    steady_state_articulation,
    truck_boxes,
    truck_corners,
    truck_segments,
    vehicle_outline,
)

__all__ = [
    "CONTROL_KEYS",
    "LATERAL_MODES",
    "LONGITUDINAL_MODES",
    "MODE_TABLE",
    "PARAM_KEYS",
    "ConfigError",
    "Control",
    "ControlConfig",
    "LidarConfig",
    "SweepLidar",
    "VehicleConfig",
    "beam_angles",
    "commanded",
    "contour_collides",
    "jackknifed",
    "kinematics_step",
    "lidar_oracle",
    "lidar_scan",
    "point_segment_distance",
    "polygon_segments",
    "ray_segment_distance",
    "rectangle_corners",
    "rectangle_segments",
    "sample_vehicle_params",
    "segment_box_overlap",
    "segment_segment_distance",
    "segments_intersect",
    "steady_state_articulation",
    "to_local",
    "truck_boxes",
    "truck_collides",
    "truck_corners",
    "truck_segments",
    "vehicle_outline",
    "wrap_angle",
]
