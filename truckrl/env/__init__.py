"""Env adapters over the task core: :class:`TruckEnv`, a batched TorchRL ``EnvBase``."""

from truckrl.env.truck_env import TruckEnv

#: Observation keys of the specs: the numeric features and the LiDAR ranges.
OBS_KEY = "observation"
LIDAR_KEY = "lidar"

__all__ = ["LIDAR_KEY", "OBS_KEY", "TruckEnv"]
