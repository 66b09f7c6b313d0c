"""Pure-torch simulator core: geometry, vehicle, control, scenes, collision, LiDAR.

Usable without TorchRL. Every function is batched over leading dimensions; shapes and units are
in each module's docstrings. A minimal loop::

    import torch
    from truckrl.sim import (Control, ControlConfig, SceneConfig, VehicleConfig, beam_angles,
                             generate_scenes, kinematics_step, lidar_scan, sample_vehicle_params)

    g = torch.Generator().manual_seed(0)
    params = sample_vehicle_params(VehicleConfig(), 8, g)          # {key: [8]}
    scenes = generate_scenes(SceneConfig(), params, g)             # segments [8, E, 4], start [8, 3]
    pose = torch.cat((scenes.start, torch.zeros(8, 1)), -1)        # (x, y, theta, phi)
    pose, _ = kinematics_step(pose, torch.full((8,), 5.0), torch.zeros(8), params, dt=0.1)
    ranges = lidar_scan(pose[:, :2], pose[:, 2], scenes.segments, scenes.mask,
                        beam_angles(16), max_range=50.0)           # [8, 16] metres
"""

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
from truckrl.sim.scene import SceneBatch, SceneConfig, generate_scenes
from truckrl.sim.validation import ConfigError
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
    "SceneBatch",
    "SceneConfig",
    "SweepLidar",
    "VehicleConfig",
    "beam_angles",
    "commanded",
    "contour_collides",
    "generate_scenes",
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
