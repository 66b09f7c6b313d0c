"""LiDAR: first-hit ranges from a sensor to scene segments, in three implementations.

All three return, for each beam, the distance [m] from the sensor to the first segment the beam
meets, or exactly ``max_range`` when it meets none within range. They share one piece of math,
:func:`truckrl.sim.geometry.ray_segment_distance`, and differ only in which (ray, segment) pairs
they hand to it:

1. :func:`lidar_oracle`: every ray against every in-range segment, one ray at a time. ``O(R*E)``,
   small enough to trust; the reference the other two are tested against.
2. :class:`SweepLidar`: the paper's event-ordered angular sweep (Sec. "LiDAR Algorithms") on one
   scene, on the CPU, with the sorted event order kept between calls. Near ``O(R + E)``.
3. :func:`lidar_scan`: the batched tensor version the environment calls for all N envs at once
   (CPU or CUDA, no per-env loop, no host sync): every ray against every segment, as tensor ops
   that ``torch.compile`` fuses.

Beam layout (:func:`beam_angles`): angles are relative to the sensor heading, counter-clockwise
positive, ascending in ``[-pi, pi)``. For the full circle, beam ``k`` points at ``-pi + k * 2pi/R``:
beam 0 looks straight back, beam ``R/2`` (even ``R``) straight ahead, and the last beam is one
spacing before beam 0 again, so the layout is uniform across the seam and beams at ``-pi`` and
``+pi`` are neighbours. For a partial field of view the beams are spread evenly over
``[-fov/2, fov/2]``, both ends included.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import (
    RAY_TOLERANCE_ULPS,
    point_segment_distance,
    ray_distance_from_origin,
    ray_segment_distance,
    ray_tolerance,
    segments_to_local,
    unit_vectors,
)

#: Angular padding [rad] added to both ends of a segment's interval before deciding which beams
#: may hit it. Extra candidates cost a little work; a missing one costs a wrong range, so the
#: padding is generous compared to the float64 (sweep) and float32 (batched) angle round-off.
#: On top of it comes twice the angle that ray_segment_distance's beam half-width subtends
#: (:func:`~truckrl.sim.geometry.ray_tolerance`): a beam that close to a segment end touches it.
_SWEEP_PAD = 1e-6
#: A sensor closer than this [m] to a segment may hit it from every direction at ~0 m.
_ON_SEGMENT = 1e-9


@dataclass
class LidarConfig:
    """LiDAR layout and range (``env.lidar.*``).

    ``num_beams``: the paper's 1-D CNN (4 channels after two stride-2 layers feeding a 64-wide
    layer, ~17.3k parameters) implies 16. ``fov = 2*pi`` is the full circle (paper: beams at -pi
    and +pi are neighbours, circular padding in the CNN).
    """

    num_beams: int = param(
        16, lo=1, hi=4096, unit="-", doc="number of beams R", source="paper's CNN size"
    )
    fov: float = param(
        2.0 * math.pi,
        lo=0.0,
        lo_open=True,
        hi=2.0 * math.pi + 1e-9,
        unit="rad",
        doc="field of view; 2*pi = full circle",
        source="paper",
    )
    max_range: float = param(
        50.0,
        lo=0.0,
        lo_open=True,
        hi=1000.0,
        unit="m",
        doc="range returned when nothing is hit",
        source="paper",
    )

    def __post_init__(self) -> None:
        validate(self, "env.lidar")

    def angles(self, dtype: torch.dtype = torch.float32, device=None) -> Tensor:
        """This layout's :func:`beam_angles` ``[R]`` [rad]."""
        return beam_angles(self.num_beams, self.fov, dtype=dtype, device=device)


def beam_angles(
    num_beams: int, fov: float = 2.0 * math.pi, dtype: torch.dtype = torch.float32, device=None
) -> Tensor:
    """Beam directions ``[R]`` [rad] relative to the heading, ascending in ``[-pi, pi)``.

    Full circle (``fov >= 2*pi``): ``-pi + k * 2*pi / R``, uniform across the seam. Otherwise
    ``R`` beams spread evenly over ``[-fov/2, fov/2]`` (one beam: straight ahead).
    """
    if num_beams < 1:
        raise ConfigError(f"lidar.num_beams = {num_beams} is outside the allowed range [1, 4096]")
    k = torch.arange(num_beams, dtype=torch.float64, device=device)
    if fov >= 2.0 * math.pi - 1e-9:
        angles = -math.pi + k * (2.0 * math.pi / num_beams)
    elif num_beams == 1:
        angles = torch.zeros(1, dtype=torch.float64, device=device)
    else:
        angles = -0.5 * fov + k * (fov / (num_beams - 1))
    return angles.to(dtype)


def _beam_angle(eps: float) -> float:
    """Twice the angle [rad] ray_segment_distance's beam half-width subtends, for ``eps``."""
    return 2.0 * math.sqrt(2.0) * RAY_TOLERANCE_ULPS * eps


def lidar_oracle(
    origin: Tensor,
    heading: float,
    segments: Tensor,
    mask: Tensor | None,
    rel_angles: Tensor,
    max_range: float,
) -> Tensor:
    """Reference LiDAR: each ray against every in-range segment (the paper's simple loop).

    Computed in float64 whatever the input dtype, with the beam half-width of the input dtype
    (:func:`~truckrl.sim.geometry.ray_segment_distance`'s ``eps``): a float32 scene is judged to
    float32 precision, so a beam running along a segment to within float32 round-off grazes it,
    as the float32 scan says, although it may miss it by a micrometre in exact arithmetic.

    Args:
        origin: ``[2]`` sensor position [m].
        heading: sensor heading [rad].
        segments: ``[E, 4]`` world metres.
        mask: ``[E]`` validity (``False`` = padding) or ``None``.
        rel_angles: ``[R]`` beam directions relative to ``heading`` [rad].
        max_range: [m].

    Returns:
        ``[R]`` first-hit distances [m] in ``segments.dtype``, exactly ``max_range`` for no hit.
    """
    eps = torch.finfo(segments.dtype).eps
    o = origin.detach().to(torch.float64).cpu()
    seg = segments.detach().to(torch.float64).cpu()
    keep = point_segment_distance(o.view(1, 2), seg).view(-1) <= max_range  # range pre-filter
    if mask is not None:
        keep &= mask.detach().cpu().view(-1)
    seg = seg[keep]
    angles = float(heading) + rel_angles.detach().to(torch.float64).cpu()
    out = torch.full((angles.numel(),), float(max_range), dtype=torch.float64)
    for r in range(angles.numel()):
        d = ray_segment_distance(o, angles[r : r + 1], seg, eps=eps)  # [1, E']
        if d.numel():
            out[r] = d.min().clamp_max(max_range)
    return out.to(segments.dtype)


class SweepLidar:
    """The paper's event-ordered angular sweep for one sensor and one scene, on the CPU.

    Events are the ray directions and, for each in-range segment, the two ends of its angular
    interval as seen from the sensor (its two vertices, padded by a small angle). Sweeping from
    the seam at ``-pi``, a segment is *open* between its interval's ends; segments whose interval
    crosses the seam start open; the open set answers each ray. Segments beyond ``max_range``
    (range pre-filter) never enter the sweep.

    **Kept event order.** The sorted event order is kept from one call to the next and re-sorted
    with Python's ``list.sort`` (Timsort detects the long sorted runs), so a slowly moving pose costs
    near-linear sorting, as in the paper. Pass the same ``scene_id`` while the scene's segments are
    unchanged; a different ``scene_id`` (or ``None``, or a different segment count) starts afresh.

    **Open set and crossing segments.** The paper keeps the open set sorted by distance and answers
    a ray with its head; that order is only valid when segments do not cross (two crossing
    segments swap order with no vertex event in between). Here every ray is tested against all
    of its (few, ``k <= ~10``) open segments, in one batched call to
    :func:`~truckrl.sim.geometry.ray_segment_distance` for the whole scan, so the result equals
    the oracle's even where segments cross, and the sorted-insert bookkeeping disappears.

    Degenerate cases: rays exactly through a vertex or along a radial (collinear) segment are
    inside the padded interval, so the exact test decides them, like the oracle; a zero-length
    segment is a point; a sensor within ``1e-9`` m of a segment keeps it open for every ray.

    Args:
        rel_angles: ``[R]`` beam directions relative to the heading [rad].
        max_range: [m].
    """

    def __init__(self, rel_angles: Tensor, max_range: float) -> None:
        self.rel_angles = rel_angles.detach().to(torch.float64).cpu()
        self.max_range = float(max_range)
        self.num_rays = self.rel_angles.numel()
        self._scene_id: object = None
        self._seg: Tensor | None = None  # [E, 4] float64 scene, cached per scene_id
        self._seg_np: np.ndarray | None = None
        self._num_seg = -1
        self._order: list[int] | None = None  # event ids in last sorted order

    def reset(self) -> None:
        """Forget the cached scene and event order."""
        self._scene_id = None
        self._seg = self._seg_np = self._order = None
        self._num_seg = -1

    # Long on purpose: the paper's sweep (events, open-edge list, ray hits) is one stateful
    # loop; pieces of it would share every local.
    def __call__(
        self,
        origin: Tensor,
        heading: float,
        segments: Tensor,
        mask: Tensor | None = None,
        scene_id: object = None,
    ) -> Tensor:
        """Scan one pose.

        Args:
            origin: ``[2]`` sensor position [m].
            heading: sensor heading [rad].
            segments: ``[E, 4]`` world metres.
            mask: ``[E]`` validity or ``None``.
            scene_id: any hashable naming the scene version; equal to the previous call's ->
                the cached segments and event order are reused. ``None`` always starts afresh.

        Returns:
            ``[R]`` first-hit distances [m] in ``segments.dtype``.
        """
        num_seg = segments.shape[0]
        if scene_id is None or scene_id != self._scene_id or num_seg != self._num_seg:
            seg = segments.detach().to(torch.float64).cpu()
            if mask is not None:
                seg = seg[mask.detach().cpu().view(-1)]
            self._seg, self._seg_np, self._num_seg = seg, seg.numpy(), num_seg
            self._order = None
            self._scene_id = scene_id
        seg, seg_np = self._seg, self._seg_np
        eps = torch.finfo(segments.dtype).eps  # beam half-width of the input precision
        num_rays, num_e = self.num_rays, seg.shape[0]
        heading = float(heading)
        o = origin.detach().to(torch.float64).cpu()
        ox, oy = float(o[0]), float(o[1])
        rel = self.rel_angles
        angles = heading + rel  # world ray directions, exactly as the oracle builds them
        ray_keys = np.remainder(angles.numpy() - heading + math.pi, 2.0 * math.pi) - math.pi

        # Range pre-filter and each segment's padded angular interval, vectorized over segments.
        dist = point_segment_distance(o.view(1, 2), seg).view(-1).numpy()
        active = dist <= self.max_range
        vx = seg_np[:, 0::2] - ox  # [E, 2] vertex offsets
        vy = seg_np[:, 1::2] - oy
        ang = np.arctan2(vy, vx) - heading
        ccw = np.remainder(ang[:, 1] - ang[:, 0], 2.0 * math.pi)
        flip = ccw > math.pi
        start = np.where(flip, ang[:, 1], ang[:, 0])
        span = np.where(flip, 2.0 * math.pi - ccw, ccw)
        pad = _SWEEP_PAD + _beam_angle(eps)
        lo = start - pad
        hi = start + span + pad
        full = active & ((hi - lo >= 2.0 * math.pi) | (dist <= _ON_SEGMENT))
        swept = active & ~full
        lo_w = np.remainder(lo + math.pi, 2.0 * math.pi) - math.pi
        hi_w = np.remainder(hi + math.pi, 2.0 * math.pi) - math.pi
        # Inactive and always-open segments sort to the tail and are never swept.
        lo_w = np.where(swept, lo_w, math.inf)
        hi_w = np.where(swept, hi_w, math.inf)

        # Event ids: 0..R-1 rays; R + 2e opens segment e, R + 2e + 1 closes it.
        keys = ray_keys.tolist() + np.stack((lo_w, hi_w), axis=1).ravel().tolist()
        order = self._order
        if order is None or len(order) != len(keys):
            order = list(range(len(keys)))
        order.sort(key=keys.__getitem__)  # nearly sorted when the pose moved a little
        self._order = order

        open_set = set(np.flatnonzero(full | (swept & (lo_w > hi_w))).tolist())
        cand_r: list[int] = []
        cand_e: list[int] = []
        for ev in order[: num_rays + 2 * int(swept.sum())]:
            if ev < num_rays:
                if open_set:
                    cand_r.extend([ev] * len(open_set))
                    cand_e.extend(open_set)
            else:
                e, closing = divmod(ev - num_rays, 2)
                if closing:
                    open_set.discard(e)
                else:
                    open_set.add(e)

        out = torch.full((num_rays,), self.max_range, dtype=torch.float64)
        if cand_r and num_e:
            ri = torch.tensor(cand_r)
            d = ray_segment_distance(
                o, angles[ri].unsqueeze(-1), seg[torch.tensor(cand_e)][:, None], eps=eps
            )
            out.scatter_reduce_(0, ri, d.view(-1).clamp_max(self.max_range), reduce="amin")
        return out.to(segments.dtype)


def lidar_scan(
    origin: Tensor,
    heading: Tensor,
    segments: Tensor,
    mask: Tensor | None,
    rel_angles: Tensor,
    max_range: float,
) -> Tensor:
    """Batched LiDAR for all envs at once: one set of tensor ops, CPU or CUDA, no host sync.

    Args:
        origin: ``[..., 2]`` sensor positions [m].
        heading: ``[...]`` sensor headings [rad].
        segments: ``[..., E, 4]`` world metres (padded to a common ``E``).
        mask: ``[..., E]`` validity (``False`` = padding) or ``None``.
        rel_angles: ``[R]`` beam directions relative to the heading [rad], ascending in
            ``[-pi, pi)`` as :func:`beam_angles` makes them.
        max_range: [m].

    Returns:
        ``[..., R]`` first-hit distances [m], exactly ``max_range`` where nothing is hit.
    """
    # Segments in the sensor frame: rays then share their [R] directions across envs and the
    # float32 subtraction of large world coordinates happens once per vertex, not per pair.
    ends = segments_to_local(segments, origin, heading)  # 4 x [..., E]
    rel = rel_angles.to(ends[0])
    if ends[0].shape[-1] == 0:
        shape = (*ends[0].shape[:-1], rel.shape[-1])
        return torch.full(shape, float(max_range), dtype=rel.dtype, device=rel.device)
    if torch.compiler.is_compiling() or ends[0].requires_grad:
        return _fused_scan(ends, mask, rel, max_range)
    local = torch.stack(ends, -1)  # [..., E, 4]
    chunk = _dense_chunk(local, rel.shape[-1])
    if chunk is None:
        return _dense_scan(local, mask, rel, max_range)
    # Eager: the [..., R, E] temporaries of a big batch are MBs each, and allocating and
    # faulting them in costs more than the arithmetic. Rows in chunks keep them in cache;
    # every row's ops are the same, so the result is bit-identical.
    flat = local.reshape(-1, *local.shape[-2:])
    fmask = None if mask is None else mask.reshape(-1, mask.shape[-1])
    parts = [
        _dense_scan(
            flat[i : i + chunk], None if fmask is None else fmask[i : i + chunk], rel, max_range
        )
        for i in range(0, flat.shape[0], chunk)
    ]
    return torch.cat(parts).reshape(*local.shape[:-2], rel.shape[-1])


#: Pairs (rows x beams x segments) per chunk of the eager dense scan: ~256 KiB float32 temporaries.
DENSE_CHUNK_PAIRS = 1 << 16


def _dense_chunk(local: Tensor, num_beams: int) -> int | None:
    """Rows per chunk of the eager dense scan on the CPU, or ``None`` for one pass (small, or on
    an accelerator, where each chunk would cost its own kernel launches)."""
    if local.dim() < 3 or local.device.type != "cpu":
        return None
    rows = local.shape[:-2].numel()
    chunk = max(1, DENSE_CHUNK_PAIRS // max(1, num_beams * local.shape[-2]))
    return None if chunk >= rows else chunk


def _fused_scan(
    ends: tuple[Tensor, Tensor, Tensor, Tensor], mask: Tensor | None, rel: Tensor, max_range: float
) -> Tensor:
    """Dense form of :func:`lidar_scan` for ``torch.compile`` (and autograd), where inductor
    fuses the pair tests: :func:`ray_distance_from_origin` on the sensor-frame ends
    ``4 x [..., E]`` (E > 0), then the minimum over segments. Eagerly, the same bits as
    :func:`_dense_scan`.

    Two layouts decide the kernels inductor writes:

    * the beam directions are materialised first (:func:`unit_vectors`). Inlined, the pair
      kernel would compute a cosine and sine of the beam angles for every segment;
    * the four coordinates are stacked coordinate-major, ``[4, ..., E]``: the rotated ends are
      written with contiguous stores and the pair test loads each coordinate as a vector.
    """
    d = unit_vectors(rel)  # [R, 2]
    local = torch.stack(ends).unsqueeze(-2)  # [4, ..., 1, E]
    dist = ray_distance_from_origin(
        d[:, 0:1], d[:, 1:2], tuple(local.unbind(0)), mask, torch.finfo(rel.dtype).eps
    )  # [..., R, E]
    return dist.amin(-1).clamp_max(max_range)


def _dense_scan(local: Tensor, mask: Tensor | None, rel: Tensor, max_range: float) -> Tensor:
    """Eager dense form of :func:`lidar_scan` on sensor-frame segments ``local [..., E, 4]``
    (E > 0).

    The arithmetic of :func:`ray_segment_distance` written for the origin at ``(0, 0)`` (``x - 0``
    is ``x``, bit for bit) with in-place passes and the padding folded into the hit test: every
    value that can reach the minimum is computed by the same float operations, so the ranges are
    identical (tests/sim/test_lidar.py checks it against ray_segment_distance on adversarial
    scenes).
    """
    eps = torch.finfo(local.dtype).eps
    dx = torch.cos(rel).unsqueeze(-1)  # [R, 1]
    dy = torch.sin(rel).unsqueeze(-1)
    p0x, p0y, p1x, p1y = local.unsqueeze(-3).unbind(-1)  # [..., 1, E], ends relative to origin
    tol0, tol1 = ray_tolerance(p0x, p0y, eps), ray_tolerance(p1x, p1y, eps)
    s0 = (dx * p0y).sub_(dy * p0x)  # [..., R, E] signed distances to the beam's line
    s1 = (dx * p1y).sub_(dy * p1x)
    t0 = (dx * p0x).add_(dy * p0y)  # ranges along the beam
    t1 = (dx * p1x).add_(dy * p1y)
    in0, in1 = s0.abs() <= tol0, s1.abs() <= tol1
    crosses = (s0 * s1) <= 0.0
    u = torch.where(crosses, (s0 / (s0 - s1)).clamp_(0.0, 1.0), (~in0).to(s0.dtype))
    t = (t1 - t0).mul_(u).add_(t0)  # t0 + u * (t1 - t0)
    along = in0 & in1
    t_near = torch.where(along, torch.minimum(t0, t1), t)
    t_far = torch.where(along, torch.maximum(t0, t1), t)
    hit = (crosses | in0).logical_or_(in1).logical_and_(t_far >= -torch.maximum(tol0, tol1))
    if mask is not None:
        hit.logical_and_(mask.unsqueeze(-2))
    dist = t_near.clamp_min_(0.0).masked_fill_(~hit, math.inf)
    return dist.amin(-1).clamp_max(max_range)
