"""Road networks built from blocks that emit segments (issue 42, item 1).

Blocks (:mod:`~truckrl.sim.network.blocks`: straight, curve, crossing, T-junction, roundabout,
median) emit curbs as segments, lane centre-lines as metadata, sockets (road ends) and a
footprint; :mod:`~truckrl.sim.network.compose` joins them socket to socket into networks of ``K``
blocks with overlap rejection, batched over networks, in the ``segments``/``mask``/``kind``
layout the env's collision and LiDAR read unchanged; :mod:`~truckrl.sim.network.layout` reads a
network from a YAML list of blocks; :mod:`~truckrl.sim.network.traffic` moves cars and trucks
along the lanes and appends their outlines to the scene. Pure torch: the geometry lives in the
sim layer because a folder under ``truckrl/tasks/`` is a task (found by
:func:`truckrl.tasks.task_names`); the task that drives routes through these networks is
:mod:`truckrl.tasks.network`.
"""

from truckrl.sim.network.blocks import GENERATORS, PARAM_NAMES, Block, place, slot_sizes
from truckrl.sim.network.compose import Network, compact, random_network, rects_overlap
from truckrl.sim.network.config import BLOCK_NAMES, NetworkConfig, arc_pieces
from truckrl.sim.network.traffic import (
    Traffic,
    TrafficConfig,
    ego_boxes,
    place_vehicles,
    spawn_traffic,
    step_traffic,
    traffic_segments,
    with_traffic,
)

__all__ = [
    "BLOCK_NAMES",
    "GENERATORS",
    "PARAM_NAMES",
    "Block",
    "Network",
    "NetworkConfig",
    "Traffic",
    "TrafficConfig",
    "arc_pieces",
    "compact",
    "ego_boxes",
    "place",
    "place_vehicles",
    "random_network",
    "rects_overlap",
    "slot_sizes",
    "spawn_traffic",
    "step_traffic",
    "traffic_segments",
    "with_traffic",
]
