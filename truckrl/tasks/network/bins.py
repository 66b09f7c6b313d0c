"""How evaluation splits the network task's episodes: block types on the route, junctions on it,
traffic density and the turns at its junctions (:func:`network_bins`).

The block-type and turn dimensions are **multi-label**: a route with a roundabout and a crossing
counts in both bins, so each bin's success rate is that of the routes holding such a block (or
such a turn); the junctions and traffic dimensions put every episode in exactly one bin.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from truckrl.sim.network.config import BLOCK_NAMES
from truckrl.tasks.bins import range_bins

#: Dimension names (keys of :func:`network_bins`), units in brackets.
BLOCK_DIM = "block types on the route"
JUNCTION_DIM = "junctions"
TRAFFIC_DIM = "traffic [vehicles / 100 m of lane]"
TURN_DIM = "turns at junctions"
#: Traffic density bin edges [vehicles per 100 m of lane] of the routes with traffic (those
#: without have a bin ``"0"`` of their own); the default ``traffic.density`` is 0.5-2 before
#: the curriculum's share, ``traffic.density`` allows up to 20.
TRAFFIC_EDGES: tuple[float, ...] = (0.0, 1.0, 2.0, 20.0)
#: Turn kinds, the info keys that count them (``turns_<kind>``).
TURN_KINDS: tuple[str, ...] = ("straight", "left", "right")


def network_bins(info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]]:
    """Named bins ``{dimension: {bin: bool [E]}}`` of ``E`` episodes from their metadata
    (:data:`~truckrl.tasks.network.scene.INFO_KEYS`, each ``[E]``).

    * ``block types on the route``: one bin per block type, the routes holding one;
    * ``junctions``: ``"0"``, ``"1"``, ... up to the most any episode has;
    * ``traffic [vehicles / 100 m of lane]``: ``"0"`` (no vehicle), then by
      :data:`TRAFFIC_EDGES`;
    * ``turns at junctions``: ``"straight on"``, ``"left"``, ``"right"``, the routes with
      such a turn at one of their junctions.

    Raises:
        KeyError: ``info`` lacks a key.
    """
    keys = [f"has_{name}" for name in BLOCK_NAMES] + ["junctions", "traffic_density"]
    keys += [f"turns_{kind}" for kind in TURN_KINDS]
    missing = [k for k in keys if k not in info]
    if missing:
        raise KeyError(f"network_bins: info lacks {', '.join(missing)}")
    bins: dict[str, dict[str, Tensor]] = {
        BLOCK_DIM: {name: info[f"has_{name}"] > 0.5 for name in BLOCK_NAMES}
    }
    count = info["junctions"].round().long()
    top = int(count.max()) if count.numel() else 0
    bins[JUNCTION_DIM] = {str(j): count == j for j in range(top + 1)}
    density = info["traffic_density"].to(torch.float64)
    bins[TRAFFIC_DIM] = {"0": density <= 0.0} | range_bins(density, TRAFFIC_EDGES, density > 0.0)
    names = {"straight": "straight on", "left": "left", "right": "right"}
    bins[TURN_DIM] = {names[k]: info[f"turns_{k}"] > 0.5 for k in TURN_KINDS}
    return bins
