"""Env adapters over the task core: :class:`TruckEnv`, a batched TorchRL ``EnvBase``.

Keys, shapes and the observation table: :mod:`truckrl.env.spec`.
"""

from truckrl.env.spec import LIDAR_KEY, OBS_KEY
from truckrl.env.truck_env import TruckEnv

__all__ = ["LIDAR_KEY", "OBS_KEY", "TruckEnv"]
