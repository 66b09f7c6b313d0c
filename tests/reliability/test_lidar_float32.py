"""float32 LiDAR against an independent float64 oracle: grazing beams and partial fields of view.

The oracle here is written from scratch in numpy float64 and calls nothing from
``truckrl.sim.geometry``. For a beam from ``o`` along the unit vector ``d`` and a segment with ends
``p0, p1`` (taken relative to ``o``), each point ``p(u) = p0 + u (p1 - p0)``, ``u in [0, 1]``, has

* a signed distance ``s(u) = d x p(u)`` [m] from the beam's line, and
* a range ``t(u) = d . p(u)`` [m] along the beam.

Both are linear in ``u``. The *contact interval* of the segment for a beam thickened to a
half-width ``w(u)`` (linear in ``u`` too) is ``{t(u) >= 0 : |s(u)| <= w(u)}``: a closed form (clip
``u`` to two half-lines), exact for ``w = 0``.

**Acceptance rule (why a range can be ambiguous).** The inputs are float32 coordinates of
~100 m; the scan forms sensor-relative coordinates, rotations, beam directions and cross products
in float32, each with a relative round-off of a few ``eps32 = 1.19e-7``. So a segment point's
distance from the beam is only known to ~``eps32 * scale`` (``scale = |x| + |y|`` of the point
relative to the sensor; measured up to 2.1 eps32 * scale), and a segment lying that close to a
beam along its whole length (a beam *along* a wall) may be reported hit anywhere on it, or missed.
A float32 range ``r`` is accepted when, with ``W = 32 * eps32 * scale`` (3.8e-6 * scale, ~4e-5 m at
10 m, well above the round-off) and ``TOL`` on ranges:

1. *no phantom*: ``r`` is ``max_range`` or lies (within ``TOL``) in some segment's contact
   interval for half-width ``W``, i.e. the reported point is on a segment to round-off;
2. *not early*: ``r`` is not below the first contact of the beam thickened to ``W``;
3. *not late*: ``r`` is not beyond the ``W``-contact interval of any segment the exact (``w = 0``)
   beam meets.

For a beam crossing a segment at an angle ``a`` these say ``|r - exact| <= TOL + W / tan(a)``:
the float32 error itself. ``TOL = 1e-4 m`` covers the round-off of ranges <= 50 m (~1e-5 m).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from truckrl.sim.lidar import SweepLidar, lidar_oracle, lidar_scan

EPS32 = float(np.finfo(np.float32).eps)
W_ULPS = 32.0  # acceptance half-width, in eps32 * scale
TOL = 1e-4  # [m] on ranges
MAX_RANGE = 50.0


# --- the oracle -----------------------------------------------------------------------------


def beam_layout(num_beams: int, fov: float) -> np.ndarray:
    """Relative beam angles ``[R]`` as float32 values (the documented layout, rebuilt here)."""
    k = np.arange(num_beams, dtype=np.float64)
    if fov >= 2 * math.pi - 1e-9:
        a = -math.pi + k * (2 * math.pi / num_beams)
    elif num_beams == 1:
        a = np.zeros(1)
    else:
        a = -0.5 * fov + k * (fov / (num_beams - 1))
    return a.astype(np.float32)


def _frame(origin, angles, segs):
    """Signed distances and ranges of both ends ``[N, R, E]``, and their scales ``[N, 1, E]``."""
    o = origin[:, None, None, :]
    p0 = segs[:, None, :, 0:2] - o  # [N, 1, E, 2]
    p1 = segs[:, None, :, 2:4] - o
    dx, dy = np.cos(angles)[..., None], np.sin(angles)[..., None]  # [N, R, 1]
    s0 = dx * p0[..., 1] - dy * p0[..., 0]
    s1 = dx * p1[..., 1] - dy * p1[..., 0]
    t0 = dx * p0[..., 0] + dy * p0[..., 1]
    t1 = dx * p1[..., 0] + dy * p1[..., 1]
    return s0, s1, t0, t1, np.abs(p0).sum(-1), np.abs(p1).sum(-1)


def _half_line(a, b):
    """``{u : a u <= b}`` as ``(lo, hi)``, empty as ``(inf, -inf)``."""
    safe = np.where(a == 0.0, 1.0, a)
    lo = np.where(a < 0.0, b / safe, -np.inf)
    hi = np.where(a > 0.0, b / safe, np.inf)
    empty = (a == 0.0) & (b < 0.0)
    return np.where(empty, np.inf, lo), np.where(empty, -np.inf, hi)


def contact(s0, s1, t0, t1, w0, w1, mask=None):
    """Contact interval ``[a, b]`` ``[N, R, E]`` of each segment for half-widths ``w0, w1`` at its
    ends (``a = inf`` where empty)."""
    ds, dw = s1 - s0, w1 - w0
    lo1, hi1 = _half_line(ds - dw, w0 - s0)  # s(u) <= w(u)
    lo2, hi2 = _half_line(-(ds + dw), w0 + s0)  # s(u) >= -w(u)
    lo = np.maximum(np.maximum(lo1, lo2), 0.0)
    hi = np.minimum(np.minimum(hi1, hi2), 1.0)
    ok = lo <= hi
    w = np.maximum(w0, w1)
    lo, hi = np.where(ok, lo, 0.0), np.where(ok, hi, 0.0)
    ta, tb = t0 + lo * (t1 - t0), t0 + hi * (t1 - t0)
    a, b = np.minimum(ta, tb), np.maximum(ta, tb)
    ok &= b >= -w  # some of it ahead of the sensor
    if mask is not None:
        ok &= mask[:, None, :]
    return np.where(ok, np.maximum(a, 0.0), np.inf), np.where(ok, b, -np.inf)


def oracle_bounds(origin, heading, segs, mask, rel, max_range=MAX_RANGE):
    """float64 oracle for float32 inputs: per beam ``[N, R]`` the exact range and the bounds.

    Returns ``(exact, first, late, a_w, b_w)``: the exact first hit (``w = 0``), the first contact
    for half-width ``W``, the late bound of rule 3, and the ``W``-contact intervals ``[N, R, E]``.
    """
    origin = np.asarray(origin, np.float64)
    segs = np.asarray(segs, np.float64)
    angles = np.asarray(heading, np.float64)[:, None] + np.asarray(rel, np.float64)[None]
    s0, s1, t0, t1, scale0, scale1 = _frame(origin, angles, segs)
    a0, _ = contact(s0, s1, t0, t1, 0.0, 0.0, mask)
    aw, bw = contact(s0, s1, t0, t1, W_ULPS * EPS32 * scale0, W_ULPS * EPS32 * scale1, mask)
    clip = lambda x: np.minimum(x, max_range)  # noqa: E731
    exact = clip(a0.min(-1, initial=np.inf))
    first = clip(aw.min(-1, initial=np.inf))
    late = clip(np.where(np.isfinite(a0), bw, np.inf).min(-1, initial=np.inf))
    return exact, first, late, aw, bw


def rules(ranges, bounds, max_range=MAX_RANGE, tol=TOL):
    """The three rules of the module doc, ``[N, R]`` bool each: no phantom, not early, not late."""
    r = np.asarray(ranges, np.float64)
    _, first, late, aw, bw = bounds
    on_segment = ((aw - tol <= r[..., None]) & (r[..., None] <= bw + tol)).any(-1)
    return (r >= max_range - tol) | on_segment, r >= first - tol, r <= late + tol


def accepted(ranges, bounds, max_range=MAX_RANGE, tol=TOL) -> np.ndarray:
    """``[N, R]`` bool: the ranges obey the three rules of the module doc."""
    no_phantom, not_early, not_late = rules(ranges, bounds, max_range, tol)
    return no_phantom & not_early & not_late


# --- scenes -----------------------------------------------------------------------------------


def near_parallel_cases(n: int, seed: int, num_beams: int = 16):
    """``n`` single-segment scenes at ~100 m coordinates, one beam aimed along each segment.

    The sensor sits on the segment's line 0.2-35 m before its near end (float64), then every input
    is rounded to float32, as in the environment. A third of the segments are left collinear, a
    third are shifted sideways by 1e-7 - 1e-4 m, and a third are turned by 1e-8 - 1e-3 rad about a
    random point of theirs (shallow crossings). Returns float32 ``origin [n, 2]``, ``heading [n]``,
    ``segs [n, 1, 4]``, ``rel [R]``, the index ``[n]`` of the aimed beam and the kind ``[n]``
    (0 collinear, 1 shifted, 2 turned).
    """
    rng = np.random.default_rng(seed)
    rel = beam_layout(num_beams, 2 * math.pi)
    origin = rng.uniform(-140.0, 140.0, (n, 2))
    phi = rng.uniform(-math.pi, math.pi, n)
    d = np.stack((np.cos(phi), np.sin(phi)), -1)
    nrm = np.stack((-d[:, 1], d[:, 0]), -1)
    gap = rng.uniform(0.2, 35.0, n)[:, None]
    length = rng.uniform(1.0, 15.0, n)[:, None]
    p0, p1 = origin + gap * d, origin + (gap + length) * d
    kind = rng.integers(0, 3, n)[:, None]
    sign = rng.choice([-1.0, 1.0], (n, 1))
    shift = sign * 10.0 ** rng.uniform(-7.0, -4.0, (n, 1))
    p0, p1 = np.where(kind == 1, p0 + shift * nrm, p0), np.where(kind == 1, p1 + shift * nrm, p1)
    turn = sign[:, 0] * 10.0 ** rng.uniform(-8.0, -3.0, n)
    pivot = p0 + rng.uniform(0.0, 1.0, (n, 1)) * (p1 - p0)
    c, s = np.cos(turn)[:, None], np.sin(turn)[:, None]

    def rot(p):
        q = p - pivot
        return pivot + np.concatenate((c * q[:, :1] - s * q[:, 1:], s * q[:, :1] + c * q[:, 1:]), 1)

    p0, p1 = np.where(kind == 2, rot(p0), p0), np.where(kind == 2, rot(p1), p1)
    flip = rng.random((n, 1)) < 0.5  # either end first
    segs = np.concatenate((np.where(flip, p1, p0), np.where(flip, p0, p1)), -1)[:, None]
    beam = rng.integers(0, num_beams, n)
    heading = np.remainder(phi - rel[beam] + math.pi, 2 * math.pi) - math.pi
    f32 = np.float32
    return origin.astype(f32), heading.astype(f32), segs.astype(f32), rel, beam, kind[:, 0]


def random_segment_scenes(n: int, e: int, seed: int):
    """``n`` scenes of ``e`` random segments (0.5-20 m) within ~45 m of a sensor at ~100 m."""
    rng = np.random.default_rng(seed)
    origin = rng.uniform(-140.0, 140.0, (n, 2))
    centre = origin[:, None] + rng.uniform(-45.0, 45.0, (n, e, 2))
    ang = rng.uniform(-math.pi, math.pi, (n, e))
    half = rng.uniform(0.25, 10.0, (n, e))[..., None]
    d = np.stack((np.cos(ang), np.sin(ang)), -1)
    segs = np.concatenate((centre - half * d, centre + half * d), -1)
    heading = rng.uniform(-math.pi, math.pi, n)
    mask = rng.random((n, e)) > 0.1
    f32 = np.float32
    return origin.astype(f32), heading.astype(f32), segs.astype(f32), mask


def scan(origin, heading, segs, mask, rel, dtype=torch.float32) -> np.ndarray:
    t = lambda x: torch.as_tensor(np.asarray(x)).to(dtype)  # noqa: E731
    m = None if mask is None else torch.as_tensor(mask)
    out = lidar_scan(t(origin), t(heading), t(segs), m, t(rel), MAX_RANGE)
    return out.double().numpy()


# --- tests ------------------------------------------------------------------------------------

EXAMPLE = dict(
    seg=[[-22.215715, -72.980698, -19.528841, -66.713226]],
    origin=[-24.847519, -79.119713],
    heading=-1.5830988,
)


def test_issue_example_grazing_beam():
    seg = np.array([EXAMPLE["seg"]], np.float32)
    origin = np.array([EXAMPLE["origin"]], np.float32)
    heading = np.array([EXAMPLE["heading"]], np.float32)
    rel = beam_layout(16, 2 * math.pi)
    bounds = oracle_bounds(origin, heading, seg, None, rel)
    exact, first, late, aw, bw = bounds
    # the beam runs along the segment, 0.4-0.9 um beside it: it grazes it from 6.679 m on
    assert exact[0, 15] == MAX_RANGE and late[0, 15] == MAX_RANGE
    assert abs(first[0, 15] - 6.67936) < 1e-4 and abs(bw[0, 15, 0] - 13.49849) < 1e-4
    got = scan(origin, heading, seg, None, rel)
    assert accepted(got, bounds).all()
    assert abs(got[0, 15] - 6.67936) <= 1e-3, got[0, 15]
    ref = lidar_oracle(
        torch.tensor(origin[0]),
        float(heading[0]),
        torch.tensor(seg[0]),
        None,
        torch.tensor(rel),
        MAX_RANGE,
    )
    assert abs(ref[15].item() - 6.67936) <= 1e-3  # the oracle judges float32 inputs alike


def test_near_parallel_beams_float32():
    origin, heading, segs, rel, beam, _ = near_parallel_cases(20_000, seed=1)
    bounds = oracle_bounds(origin, heading, segs, None, rel)
    got = scan(origin, heading, segs, None, rel)
    ok = accepted(got, bounds)
    bad = np.flatnonzero(~ok.all(-1))
    assert bad.size == 0, f"{bad.size} scenes, e.g. scene {bad[:5]}: {got[bad[:1]]}"
    aimed = got[np.arange(got.shape[0]), beam]
    assert (aimed < MAX_RANGE).mean() > 0.5  # the aimed beams do see their segments


def test_near_parallel_beams_oracle_and_sweep():
    # lidar_oracle and SweepLidar compute in float64 but judge float32 inputs to float32 precision
    origin, heading, segs, rel, _, _ = near_parallel_cases(300, seed=2)
    bounds = oracle_bounds(origin, heading, segs, None, rel)
    t = torch.tensor
    for name, fn in [
        ("lidar_oracle", lambda o, h, s: lidar_oracle(o, h, s, None, t(rel), MAX_RANGE)),
        ("sweep", lambda o, h, s: SweepLidar(t(rel), MAX_RANGE)(o, h, s)),
    ]:
        got = np.stack(
            [fn(t(origin[i]), float(heading[i]), t(segs[i])).double().numpy() for i in range(300)]
        )
        assert accepted(got, bounds).all(), name


def test_general_beams_float32():
    origin, heading, segs, mask = random_segment_scenes(1500, 24, seed=3)
    rel = beam_layout(16, 2 * math.pi)
    bounds = oracle_bounds(origin, heading, segs, mask, rel)
    got = scan(origin, heading, segs, mask, rel)
    assert accepted(got, bounds).all()
    exact = bounds[0]
    assert (exact < MAX_RANGE).mean() > 0.5
    # away from grazing, float32 is the exact range to round-off
    assert (np.abs(got - exact) <= TOL).mean() > 0.999


def test_wall_three_radian_seven_beams():
    # a wall at x = 1 seen over a 3 rad field of view: beams at 0, +-0.5, +-1, +-1.5 rad
    rel = beam_layout(7, 3.0)
    wall = np.array([[[1.0, -20.0, 1.0, 20.0]]], np.float32)
    zero = np.zeros((1, 2), np.float32)
    want = 1.0 / np.cos(rel.astype(np.float64))  # 14.14, 1.85, 1.14, 1, 1.14, 1.85, 14.14
    for dtype in (torch.float32, torch.float64):
        got = scan(zero, np.zeros(1, np.float32), wall, None, rel, dtype)[0]
        np.testing.assert_allclose(got, want, atol=1e-4, err_msg=str(dtype))
