"""Evaluation results per scene category: bin episodes by route and geometry, summarise each bin.

A policy can look fine on average and still fail one kind of task (right turns, sharp left turns
at a crossing). :func:`episode_bins` sorts episodes along several dimensions (route, turn angle,
crossing angle, trailer length, road width, goal distance), :func:`summarize_by_category` gives
the outcome rates and p95 final errors of every non-empty bin, and
:func:`format_category_table` prints them. Other tasks declare their dimensions
(``Task.category_dims``, :func:`generic_bins`); :func:`task_bins` picks. Pure torch: no TorchRL
needed.

Bins (edges below, in the unit of their dimension) are ``[lo, hi)``, the last one ``[lo, hi]``.
The outermost edges of a dimension are widened by :data:`EDGE_TOL` (float32 round-off at the ends
of the sampled ranges), and a value beyond them lands in an extra ``"< lo"`` or ``"> hi"`` bin,
which exists only when it holds an episode (non-default configs): every episode that a dimension
applies to lands in exactly one of its bins.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from truckrl.sim.scene import (
    ROUTE_KEYS,
    ROUTE_LEFT,
    ROUTE_NAMES,
    ROUTE_RIGHT,
    ROUTE_STRAIGHT_ROAD,
    SceneBatch,
)
from truckrl.task import CategoryDim, Quantity, task_class

#: |turn angle| [deg] bins of left and right turns at a crossing (each split by side). The default
#: crossing angles (45-135 deg) give turns of 45-135 deg; 110-180 are the sharp turns.
TURN_EDGES_DEG: tuple[float, ...] = (20.0, 70.0, 110.0, 180.0)
#: Crossing angle [deg] bins, crossing scenes only (default ``scene.crossing_angle``: 45-135 deg).
CROSSING_EDGES_DEG: tuple[float, ...] = (45.0, 70.0, 110.0, 135.0)
#: Trailer length [m] bins (front overhang + wheelbase + rear overhang). The outer edges span the
#: default ``VehicleConfig`` range (0.9 + 6.0 + 1.0 = 7.9 to 1.6 + 11.0 + 3.5 = 16.1 m); the inner
#: ones are about its terciles (the sum of three uniform draws: 11.15 and 12.84 m measured).
TRAILER_LENGTH_EDGES_M: tuple[float, ...] = (7.9, 11.2, 12.8, 16.1)
#: Road width [m] bins of the narrower of the start's and the goal's road (default 10-18 m).
ROAD_WIDTH_EDGES_M: tuple[float, ...] = (10.0, 12.0, 14.0, 16.0, 18.0)
#: Start-goal distance [m] bins (default ``scene.goal_distance``: 25-70 m).
GOAL_DISTANCE_EDGES_M: tuple[float, ...] = (25.0, 40.0, 55.0, 70.0)
#: Slack [deg or m] on the outermost edges of a dimension: values sampled at the ends of a range
#: may miss them by float32 round-off.
EDGE_TOL = 1e-3

#: Dimension names (keys of :func:`episode_bins`), units in brackets.
ROUTE_DIM = "route"
TURN_DIM = "turn [deg]"
CROSSING_DIM = "crossing angle [deg]"
TRAILER_DIM = "trailer length [m]"
ROAD_WIDTH_DIM = "road width [m]"
GOAL_DISTANCE_DIM = "goal distance [m]"

#: Per-episode inputs of :func:`episode_bins` (plus the trailer length, see there).
INFO_KEYS = ROUTE_KEYS
#: Trailer parameters whose sum is the trailer length [m].
TRAILER_KEYS = ("trailer_front_overhang", "trailer_wheelbase", "trailer_rear_overhang")
#: Outcome flags of ``results`` (bool) and the name of their rate (``truncated`` = timeout).
OUTCOMES = {
    "success": "success",
    "collision": "collision",
    "jackknife": "jackknife",
    "truncated": "timeout",
}
#: Final errors of ``results`` and their units; rows report their p95.
ERRORS = {"pos_error": "m", "tractor_heading_error": "deg", "trailer_heading_error": "deg"}


def trailer_length(params: Mapping[str, Tensor]) -> Tensor:
    """Trailer body length [m] ``[E]``: front overhang + wheelbase + rear overhang."""
    return sum((params[k] for k in TRAILER_KEYS[1:]), params[TRAILER_KEYS[0]])


def scene_info(scenes: SceneBatch, params: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The per-episode inputs of :func:`episode_bins` from a scene batch and its vehicle params."""
    info = {k: getattr(scenes, k) for k in INFO_KEYS}
    info["trailer_length"] = trailer_length(params)
    return info


def _range_bins(x: Tensor, edges: Sequence[float], within: Tensor, prefix: str = ""):
    """Bins of ``x`` between consecutive ``edges`` among episodes ``within`` (see module doc)."""
    lo_all, hi_all = edges[0] - EDGE_TOL, edges[-1] + EDGE_TOL
    out: dict[str, Tensor] = {}
    under = within & (x < lo_all)
    if under.any():
        out[f"{prefix}< {edges[0]:g}"] = under
    last = len(edges) - 2
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        above = x >= (lo_all if i == 0 else lo)
        below = x <= hi_all if i == last else x < hi
        out[f"{prefix}{lo:g}-{hi:g}"] = within & above & below
    over = within & (x > hi_all)
    if over.any():
        out[f"{prefix}> {edges[-1]:g}"] = over
    return out


def episode_bins(info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]]:
    """Named bins ``{dimension: {bin: bool Tensor [E]}}`` of ``E`` episodes.

    Args:
        info: per-episode ``[E]`` tensors (the :class:`~truckrl.sim.scene.SceneBatch` fields of
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
        bins[TURN_DIM] |= _range_bins(turn, TURN_EDGES_DEG, route == r, f"{side} ")
    everyone = torch.ones_like(route, dtype=torch.bool)
    bins[CROSSING_DIM] = _range_bins(
        x["crossing_angle"] * (180.0 / math.pi), CROSSING_EDGES_DEG, route != ROUTE_STRAIGHT_ROAD
    )
    bins[TRAILER_DIM] = _range_bins(x["trailer_length"], TRAILER_LENGTH_EDGES_M, everyone)
    narrower = torch.minimum(x["start_road_width"], x["goal_road_width"])
    bins[ROAD_WIDTH_DIM] = _range_bins(narrower, ROAD_WIDTH_EDGES_M, everyone)
    bins[GOAL_DISTANCE_DIM] = _range_bins(x["goal_distance"], GOAL_DISTANCE_EDGES_M, everyone)
    return bins


def generic_bins(
    info: Mapping[str, Tensor], dims: Sequence[CategoryDim]
) -> dict[str, dict[str, Tensor]]:
    """Named bins ``{dimension: {bin: bool Tensor [E]}}`` along a task's ``category_dims``.

    A binned dimension gets the bins of its edges (plus ``"< lo"`` / ``"> hi"`` bins for values
    outside, when there are any, as :func:`episode_bins`); a categorical one a bin per name.

    Raises:
        KeyError: ``info`` lacks a dimension's key.
    """
    missing = [d.key for d in dims if d.key not in info]
    if missing:
        raise KeyError(f"generic_bins: info lacks {', '.join(missing)}")
    bins: dict[str, dict[str, Tensor]] = {}
    for d in dims:
        x = info[d.key]
        if d.names is not None:
            code = x.long()
            bins[d.label] = {name: code == i for i, name in enumerate(d.names)}
        else:
            v = x.to(torch.float64) * d.scale
            bins[d.label] = _range_bins(v, d.edges, torch.ones_like(v, dtype=torch.bool))
    return bins


def task_bins(task: str, info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]] | None:
    """The category bins of task ``task``'s episodes, or None where it declares none.

    Episodes that record the intersection scene's route (:data:`INFO_KEYS`) get
    :func:`episode_bins`; any other task its ``Task.category_dims`` (:func:`generic_bins`).
    """
    if all(k in info for k in INFO_KEYS):
        return episode_bins(info)
    dims = task_class(task).category_dims
    return generic_bins(info, dims) if dims else None


def summarize_by_category(
    results: Mapping[str, Tensor],
    bins: Mapping[str, Mapping[str, Tensor]],
    errors: Sequence[Quantity] | None = None,
) -> list[dict]:
    """Outcome rates and p95 final errors of every bin with at least one episode.

    Args:
        results: per-episode ``[E]`` tensors: bool "success", "collision", "jackknife",
            "truncated" (timeout); float "pos_error" [m], "tractor_heading_error" and
            "trailer_heading_error" [deg] at the episode's last step.
        bins: ``{dimension: {bin: bool [E]}}``, e.g. from :func:`episode_bins`.
        errors: the task's error quantities (``results`` holds them in their shown units);
            default the intersection task's three (:data:`ERRORS`).

    Returns:
        One dict per non-empty bin, in the order of ``bins``: "dimension", "bin", "count" (int),
        "success_rate", "collision_rate", "jackknife_rate", "timeout_rate" (fractions in [0, 1]),
        "pos_error_m_p95", "tractor_heading_error_deg_p95", "trailer_heading_error_deg_p95"
        (linear-interpolated 95th percentile, as :func:`torch.quantile`); with ``errors``,
        ``"<key>_<shown unit>_p95"`` for each.
    """
    units = ERRORS if errors is None else {q.key: q.shown_unit for q in errors}
    missing = [k for k in (*OUTCOMES, *units) if k not in results]
    if missing:
        raise KeyError(f"summarize_by_category: results lack {', '.join(missing)}")
    n = results["success"].shape
    dev = results["success"].device
    rows = []
    for dim, named in bins.items():
        for name, mask in named.items():
            if mask.shape != n:
                raise ValueError(
                    f"summarize_by_category: bin {dim!r}/{name!r} has shape {tuple(mask.shape)}, "
                    f"results {tuple(n)}"
                )
            mask = mask.to(dev, torch.bool)
            count = int(mask.sum())
            if count == 0:
                continue
            row: dict = {"dimension": dim, "bin": name, "count": count}
            for key, rate in OUTCOMES.items():
                row[f"{rate}_rate"] = results[key][mask].to(torch.float64).mean().item()
            for key, unit in units.items():
                v = results[key][mask].to(torch.float64)
                row[f"{key}_{unit}_p95"] = torch.quantile(v, 0.95).item()
            rows.append(row)
    return rows


#: Rate columns of :func:`format_category_table`: header, row key, width, format.
_COLUMNS = (
    ("n", "count", 6, "d"),
    ("success %", "success_rate", 10, "pct"),
    ("collision %", "collision_rate", 12, "pct"),
    ("jack-knife %", "jackknife_rate", 13, "pct"),
    ("timeout %", "timeout_rate", 10, "pct"),
)


def _error_columns(rows: Sequence[Mapping]) -> list[tuple[str, str, int, str]]:
    """One column per ``<key>_<unit>_p95`` entry of the rows: ``"p95 pos m"``, ..."""
    cols = []
    for key in rows[0] if rows else ():
        if key.endswith("_p95"):
            name, _, unit = key[: -len("_p95")].rpartition("_")
            title = f"p95 {name.removesuffix('_error').replace('_', ' ')} {unit}"
            cols.append((title, key, len(title) + 2, ".2f" if unit == "m" else ".1f"))
    return cols


def format_category_table(rows: Sequence[Mapping]) -> str:
    """Fixed-width text table of :func:`summarize_by_category` rows (rates in %, then the p95
    of every error; the dimension named on the first row of its group)."""
    columns = (*_COLUMNS, *_error_columns(rows))
    w_dim = max([len("dimension"), *(len(str(r["dimension"])) for r in rows)])
    w_bin = max([len("bin"), *(len(str(r["bin"])) for r in rows)])
    header = f"{'dimension':<{w_dim}}  {'bin':<{w_bin}}" + "".join(
        f"{title:>{width}}" for title, _, width, _ in columns
    )
    lines = [header, "-" * len(header)]
    previous = None
    for r in rows:
        dim = str(r["dimension"])
        line = f"{dim if dim != previous else '':<{w_dim}}  {r['bin']!s:<{w_bin}}"
        previous = dim
        for _, key, width, fmt in columns:
            v = r[key]
            line += f"{100.0 * v:>{width}.1f}" if fmt == "pct" else f"{v:>{width}{fmt}}"
        lines.append(line)
    if not rows:
        lines.append("(no episodes)")
    return "\n".join(lines)
