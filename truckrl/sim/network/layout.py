"""A road network from a list of blocks (a YAML file or a mapping): a known junction, a depot
yard, a user's own layout, built by the same generators and joining rules as random networks.

Format (lengths in metres, angles in degrees; ``docs/networks.md`` has the socket numbers)::

    road_width: 9.0          # one width for the whole network
    heading_deg: 0           # block 0 is entered along this heading, at the origin
    blocks:
      - {type: straight, length: 40}
      - {type: curve, radius: 30, angle_deg: -60}          # > 0 turns left, < 0 right
      - {type: crossing, angle_deg: 90, arm: 25, entry: 0, exit: 3}
      - {type: t_junction, arm: 25, entry: 0, exit: 2}
      - {type: roundabout, radius: 15, arms: 4, arm: 15, entry: 0, exit: 2}
      - {type: median, length: 60, width: 2}

Every value must lie in the range a random network draws it from (:class:`NetworkConfig`: the
slot counts and the chord-error bound hold for those ranges); ``entry`` and ``exit`` (default 0
and 1) are socket numbers of the block, different, below its socket count; the last block's
``exit`` is unused. A bad value, or a block that overlaps an earlier one, is a one-line
:class:`~truckrl.config.fields.ConfigError` naming the field (``blocks[2].radius``) and what is
allowed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from truckrl.config.fields import ConfigError, check_range
from truckrl.sim.network.compose import Network, compact, grow
from truckrl.sim.network.config import (
    BLOCK_NAMES,
    CURVE,
    ROUNDABOUT,
    SOCKETS,
    NetworkConfig,
)

#: Fields of each block type in a layout: ``(key, range field of NetworkConfig, is an angle)``
#: for the block's three parameters in order (``None``: the parameter is unused).
FIELDS: dict[str, tuple[tuple[str, str, bool] | None, ...]] = {
    "straight": (("length", "straight_length", False), None, None),
    "curve": (("radius", "curve_radius", False), ("angle_deg", "curve_angle", True), None),
    "crossing": (("angle_deg", "crossing_angle", True), ("arm", "junction_arm", False), None),
    "t_junction": (("arm", "junction_arm", False), None, None),
    "roundabout": (
        ("radius", "roundabout_radius", False),
        ("arms", "roundabout_arms", False),
        ("arm", "roundabout_arm", False),
    ),
    "median": (("length", "median_length", False), ("width", "median_width", False), None),
}
_TOP = ("road_width", "heading_deg", "blocks")


def _block_row(cfg: NetworkConfig, i: int, block: Any) -> tuple[int, list[float], int, int]:
    """``(type, params, entry, exit)`` of layout block ``i``, checked."""
    where = f"blocks[{i}]"
    if not isinstance(block, Mapping):
        raise ConfigError(f"{where} must be a mapping with a 'type', got {block!r}")
    name = block.get("type")
    if name not in FIELDS:
        raise ConfigError(f"{where}.type = {name!r} is not one of {list(FIELDS)}")
    spec = [f for f in FIELDS[name] if f is not None]
    known = {"type", "entry", "exit", *(key for key, _, _ in spec)}
    unknown = sorted(set(block) - known)
    if unknown:
        raise ConfigError(
            f"unknown field(s) {unknown} for {where} ({name}); known: {sorted(known)}"
        )
    kind = BLOCK_NAMES.index(name)
    params = [0.0, 0.0, 0.0]
    for slot, field in enumerate(FIELDS[name]):
        if field is None:
            continue
        key, bounds, angle = field
        if key not in block:
            raise ConfigError(
                f"{where}.{key} is missing ({name} blocks need {[k for k, _, _ in spec]})"
            )
        lo, hi = getattr(cfg, bounds)
        value = block[key]
        if angle:
            lo, hi = math.degrees(lo), math.degrees(hi)
            if kind == CURVE:  # either way round: the magnitude lies in the range
                v = check_range(f"{where}.{key}", value, -hi, hi)
                if abs(v) < lo:
                    raise ConfigError(
                        f"{where}.{key} = {value!r} is outside the allowed range "
                        f"[{-hi:g}, {-lo:g}] or [{lo:g}, {hi:g}] (> 0 turns left)"
                    )
            else:
                v = check_range(f"{where}.{key}", value, lo, hi)
            params[slot] = math.radians(v)
        else:
            params[slot] = check_range(f"{where}.{key}", value, lo, hi)
    if kind == ROUNDABOUT and not float(params[1]).is_integer():
        raise ConfigError(f"{where}.arms = {block['arms']!r} must be a whole number in [3, 4]")
    count = int(params[1]) if kind == ROUNDABOUT else SOCKETS[kind]
    entry, exit_ = block.get("entry", 0), block.get("exit", 1)
    for key, value in (("entry", entry), ("exit", exit_)):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < count:
            raise ConfigError(
                f"{where}.{key} = {value!r} must be a socket number in [0, {count - 1}]"
            )
    if entry == exit_:
        raise ConfigError(f"{where}.exit = {exit_} must differ from {where}.entry = {entry}")
    return kind, params, entry, exit_


def network_from_blocks(
    layout: Mapping[str, Any], cfg: NetworkConfig | None = None, device=None
) -> Network:
    """The network (one row) of ``layout``, a mapping in the module doc's format.

    Raises:
        ConfigError: a bad field (named, with its allowed range), or a block whose footprint
            overlaps an earlier block's (:func:`~truckrl.sim.network.compose.rects_overlap`).
    """
    cfg = cfg or NetworkConfig()
    if not isinstance(layout, Mapping):
        raise ConfigError(f"a network layout must be a mapping with {list(_TOP)}, got {layout!r}")
    unknown = sorted(set(layout) - set(_TOP))
    if unknown:
        raise ConfigError(f"unknown field(s) {unknown} in the network layout; known: {list(_TOP)}")
    width = check_range("road_width", layout.get("road_width", cfg.road_width[0]), *cfg.road_width)
    heading = math.radians(
        check_range("heading_deg", layout.get("heading_deg", 0.0), -360.0, 360.0)
    )
    blocks = layout.get("blocks")
    K = cfg.num_blocks[1]
    if not isinstance(blocks, list) or not 1 <= len(blocks) <= K:
        got = len(blocks) if isinstance(blocks, list) else repr(blocks)
        raise ConfigError(
            f"blocks must be a list of 1 to {K} blocks (network.num_blocks max), got {got}"
        )
    rows = [_block_row(cfg, i, b) for i, b in enumerate(blocks)]
    dev = torch.device(device or "cpu")
    pad = rows + [rows[-1]] * (K - len(rows))  # never placed: the target stops before them

    def draw(k: int, count: int):
        kind, params, entry, exit_ = pad[k]
        return (
            torch.full((count,), kind, device=dev),
            torch.tensor([params], device=dev).expand(count, 3),
            torch.full((count,), entry, device=dev),
            torch.full((count,), exit_, device=dev),
        )

    types = tuple(sorted({r[0] for r in rows}))
    network, overlapped = grow(
        cfg,
        types,
        torch.tensor([width], device=dev),
        torch.tensor([heading], device=dev),
        torch.tensor([len(rows)], device=dev),
        draw,
        rounds=1,
    )
    bad = overlapped[0].nonzero().flatten().tolist()
    if bad:
        i = bad[0]
        raise ConfigError(
            f"blocks[{i}] ({BLOCK_NAMES[rows[i][0]]}) overlaps an earlier block (roads of two "
            f"blocks keep network.clearance = {cfg.clearance} m apart)"
        )
    return compact(network)


def load_layout(path: str | Path, cfg: NetworkConfig | None = None, device=None) -> Network:
    """The network of the YAML file at ``path`` (:func:`network_from_blocks`)."""
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as e:
        raise ConfigError(f"network layout {str(path)!r} cannot be read: {e.strerror}") from None
    except yaml.YAMLError as e:
        raise ConfigError(
            f"network layout {str(path)!r} is not valid YAML: {str(e).splitlines()[0]}"
        ) from None
    return network_from_blocks(data, cfg, device)
