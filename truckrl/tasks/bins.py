"""Binning episodes along a task's scene dimensions, for evaluation tables (pure torch).

Bins are ``[lo, hi)``, the last one ``[lo, hi]``. The outermost edges of a dimension are widened
by :data:`EDGE_TOL` (float32 round-off at the ends of the sampled ranges), and a value beyond
them lands in an extra ``"< lo"`` or ``"> hi"`` bin, which exists only when it holds an episode
(non-default configs): every episode that a dimension applies to lands in exactly one of its bins.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from truckrl.tasks.schema import CategoryDim

#: Slack [deg or m] on the outermost edges of a dimension: values sampled at the ends of a range
#: may miss them by float32 round-off.
EDGE_TOL = 1e-3


def range_bins(x: Tensor, edges: Sequence[float], within: Tensor, prefix: str = ""):
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
            bins[d.label] = range_bins(v, d.edges, torch.ones_like(v, dtype=torch.bool))
    return bins
