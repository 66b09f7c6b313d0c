"""How evaluation splits the intersection task's episodes: route, turn angle, crossing angle,
trailer length, road width and goal distance (:func:`episode_bins`)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor

from truckrl.sim.vehicle import TRAILER_KEYS, trailer_length
from truckrl.tasks.bins import range_bins
from truckrl.tasks.intersection.scene import (
    ROUTE_KEYS,
    ROUTE_LEFT,
    ROUTE_NAMES,
    ROUTE_RIGHT,
    ROUTE_STRAIGHT_ROAD,
    SceneBatch,
)

#: Per-episode inputs of :func:`episode_bins` (plus the trailer length, see there).
INFO_KEYS = ROUTE_KEYS

#: |turn angle| [deg] bins of left and right turns at a crossing (each split by side). The default
#: crossing angles (45-135 deg) give turns of 45-135 deg; 110-180 are the sharp turns.
TURN_EDGES_DEG: tuple[float, ...] = (20.0, 70.0, 110.0, 180.0)
#: Crossing angle [deg] bins, crossing scenes only (default ``scene.crossing_angle``: 45-135 deg).
CROSSING_EDGES_DEG: tuple[float, ...] = (45.0, 70.0, 110.0, 135.0)
#: Trailer length [m] bins (front overhang + wheelbase + rear overhang). The outer edges span the
#: default ``VehicleConfig`` range (0.9 + 6.0 + 1.0 = 7.9 to 1.6 + 11.0 + 3.5 = 16.1 m); the inner
#: ones are about the terciles of that sum of three uniform draws (11.15 and 12.84 m).
TRAILER_LENGTH_EDGES_M: tuple[float, ...] = (7.9, 11.2, 12.8, 16.1)
#: Road width [m] bins of the narrower of the start's and the goal's road (default 10-18 m).
ROAD_WIDTH_EDGES_M: tuple[float, ...] = (10.0, 12.0, 14.0, 16.0, 18.0)
#: Start-goal distance [m] bins (default ``scene.goal_distance``: 25-70 m).
GOAL_DISTANCE_EDGES_M: tuple[float, ...] = (25.0, 40.0, 55.0, 70.0)
#: Dimension names (keys of :func:`episode_bins`), units in brackets.
ROUTE_DIM = "route"
TURN_DIM = "turn [deg]"
CROSSING_DIM = "crossing angle [deg]"
TRAILER_DIM = "trailer length [m]"
ROAD_WIDTH_DIM = "road width [m]"
GOAL_DISTANCE_DIM = "goal distance [m]"


def scene_info(scenes: SceneBatch, params: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The per-episode inputs of :func:`episode_bins` from a scene batch and its vehicle params."""
    info = {k: getattr(scenes, k) for k in INFO_KEYS}
    info["trailer_length"] = trailer_length(params)
    return info


def episode_bins(info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]]:
    """Named bins ``{dimension: {bin: bool Tensor [E]}}`` of ``E`` episodes.

    Args:
        info: per-episode ``[E]`` tensors (the :class:`~truckrl.tasks.intersection.scene.SceneBatch` fields of
            the same names): "route" (``ROUTE_*`` values), "turn_angle" and "crossing_angle"
            [rad], "start_road_width" and "goal_road_width" [m], "goal_distance" [m], and
            "trailer_length" [m] or the three :data:`TRAILER_KEYS` vehicle params [m] it sums.

    Returns:
        Dimensions in this order, bins in order of their values:

        * ``"route"``: "straight road", "straight on", "left", "right" (all episodes);
        * ``"turn [deg]"``: ``|turn_angle|`` by :data:`TURN_EDGES_DEG`, left turns ("left 20-70",
          ...) then right turns ("right 20-70", ...); turns only;
        * ``"crossing angle [deg]"``: by :data:`CROSSING_EDGES_DEG`; crossing scenes only;
        * ``"trailer length [m]"``: by :data:`TRAILER_LENGTH_EDGES_M`;
        * ``"road width [m]"``: the narrower of the two road widths, by :data:`ROAD_WIDTH_EDGES_M`;
        * ``"goal distance [m]"``: by :data:`GOAL_DISTANCE_EDGES_M`.

        Bins may be empty; out-of-range bins appear only when not (see module doc).
    """
    missing = [k for k in INFO_KEYS if k not in info]
    if "trailer_length" in info:
        length = info["trailer_length"]
    elif all(k in info for k in TRAILER_KEYS):
        length = trailer_length(info)
    else:
        missing.append(f"trailer_length (or {', '.join(TRAILER_KEYS)})")
    if missing:
        raise KeyError(f"episode_bins: info lacks {', '.join(missing)}")
    route = info["route"]
    if route.dim() != 1:
        raise ValueError(f"episode_bins: info['route'] must be 1-D [E], got {tuple(route.shape)}")
    values = {k: info[k] for k in INFO_KEYS[1:]} | {"trailer_length": length}
    for k, v in values.items():
        if v.shape != route.shape:
            raise ValueError(
                f"episode_bins: info[{k!r}] has shape {tuple(v.shape)}, route {tuple(route.shape)}"
            )
    x = {k: v.to(route.device, torch.float64) for k, v in values.items()}
    route = route.long()

    bins: dict[str, dict[str, Tensor]] = {
        ROUTE_DIM: {name: route == r for r, name in enumerate(ROUTE_NAMES)}
    }
    turn = x["turn_angle"].abs() * (180.0 / math.pi)
    bins[TURN_DIM] = {}
    for r in (ROUTE_LEFT, ROUTE_RIGHT):
        side = ROUTE_NAMES[r]
        bins[TURN_DIM] |= range_bins(turn, TURN_EDGES_DEG, route == r, f"{side} ")
    everyone = torch.ones_like(route, dtype=torch.bool)
    bins[CROSSING_DIM] = range_bins(
        x["crossing_angle"] * (180.0 / math.pi), CROSSING_EDGES_DEG, route != ROUTE_STRAIGHT_ROAD
    )
    bins[TRAILER_DIM] = range_bins(x["trailer_length"], TRAILER_LENGTH_EDGES_M, everyone)
    narrower = torch.minimum(x["start_road_width"], x["goal_road_width"])
    bins[ROAD_WIDTH_DIM] = range_bins(narrower, ROAD_WIDTH_EDGES_M, everyone)
    bins[GOAL_DISTANCE_DIM] = range_bins(x["goal_distance"], GOAL_DISTANCE_EDGES_M, everyone)
    return bins
