"""CompactScene: the step's scene with padding segments cut, valid segments first in each row.

The step reads a row's segments only as a set (LiDAR: the minimum over segments of each beam's
range; collision: any segment touching a body), and a padding segment (mask ``False``)
contributes nothing to either (``+inf`` range, no contact). So each row's valid segments are
moved to the front (stable sort on the mask) and the batch is cut to ``W`` = the largest valid
count rounded up to a multiple of 8 (few distinct shapes for ``torch.compile``): every valid
segment is kept and only padding is dropped, so the step's outputs are bit-identical while its
segment-pair tests shrink from ``E`` to ``W`` per row.

The segments are stored coordinate-major (``[N, 4, E]`` in memory, seen as ``[N, E, 4]``): each
coordinate of a row's segments is contiguous, so the compiled body clip and the LiDAR's rotation
vectorise over segments, and the eager step's elementwise passes read them as vectors too.
"""

from __future__ import annotations

import torch


class CompactScene:
    """The compacted scene of a batch of ``N`` rows, updated on (partial) resets.

    Args:
        grow_only: keep the width a high-water mark (under ``env.compile``: each new width is a
            new graph, so a small batch whose largest scene varies compiles a few, not one per
            width).
    """

    def __init__(self, grow_only: bool) -> None:
        self.grow_only = grow_only
        #: ``([N, W, 4]`` segments, ``[N, W]`` mask``)``, valid first; ``None`` before an update.
        self.view: tuple[torch.Tensor, torch.Tensor] | None = None
        self._width = 0

    def update(
        self, segments: torch.Tensor, mask: torch.Tensor, index: torch.Tensor | None = None
    ) -> None:
        """Recompute the rows ``index`` (``[m]`` int64; default all, which also allocates).

        ``segments`` ``[N, E, 4]`` and ``mask`` ``[N, E]`` are the full state's. The one host
        read (``W``) happens on a reset, which syncs anyway.
        """
        if index is None:
            n, e = mask.shape
            self._seg = segments.new_empty(n, 4, e).transpose(1, 2)
            self._mask = torch.empty_like(mask)
            self._counts = torch.empty(n, dtype=torch.int64, device=mask.device)
            index = slice(None)
        rows_mask = mask[index]
        order = torch.argsort((~rows_mask).to(torch.uint8), dim=-1, stable=True)
        self._seg[index] = segments[index].gather(-2, order.unsqueeze(-1).expand(*order.shape, 4))
        self._mask[index] = rows_mask.gather(-1, order)
        self._counts[index] = rows_mask.sum(-1)
        e = mask.shape[-1]
        width = min(e, max(8, -(-int(self._counts.max()) // 8) * 8)) if e else 0
        if self.grow_only:
            width = self._width = max(width, self._width)
        self.view = (self._seg[:, :width], self._mask[:, :width])
