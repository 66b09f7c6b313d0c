"""Body collision: the box clip against independent answers (contour test, dense sampling)."""

import math

import numpy as np
import torch

from truckrl.sim.collision import contour_collides, truck_collides, truck_collides_sparse
from truckrl.sim.geometry import (
    polygon_segments,
    rectangle_corners,
    segment_box_overlap,
    segments_intersect,
    to_local,
)
from truckrl.sim.vehicle import (
    VehicleConfig,
    sample_vehicle_params,
    truck_boxes,
    vehicle_outline,
)


def _random_boxes(n, gen):
    u = torch.rand(6, n, generator=gen)
    return (
        u[0] * 10 - 5,
        u[1] * 10 - 5,
        u[2] * 6.3 - 3.15,
        0.5 + 4 * u[3],
        0.5 + 3 * u[4],
        0.3 + 2 * u[5],
    )


def test_box_overlap_matches_contour_test_plus_inside_points():
    gen = torch.Generator().manual_seed(0)
    n, e = 2000, 6
    box = _random_boxes(n, gen)
    segs = torch.rand(n, e, 4, generator=gen) * 16 - 8
    got = segment_box_overlap(segs, *box)
    edges = polygon_segments(rectangle_corners(*box))
    crosses = segments_intersect(segs, edges).any(-1)
    # independent "inside" answer: the first endpoint in the box frame, compared with the extents
    local = to_local(segs[..., :2], torch.stack(box[:2], -1), box[2])
    cx, cy = local[..., 0], local[..., 1]
    inside = (cx >= -box[4][:, None]) & (cx <= box[3][:, None]) & (cy.abs() <= box[5][:, None])
    expected = crosses | inside
    assert expected.float().mean() > 0.2 and (~expected).float().mean() > 0.2  # both cases occur
    assert torch.equal(got, expected)


def test_box_overlap_hand_cases():
    one = torch.ones(1)
    box = (0 * one, 0 * one, 0 * one, 2 * one, 1 * one, 0.5 * one)  # x in [-1, 2], y in [-.5, .5]
    segs = torch.tensor(
        [
            [
                [-0.5, 0.0, 0.5, 0.1],  # wholly inside
                [-3.0, 0.0, 3.0, 0.0],  # passes through
                [2.0, -3.0, 2.0, 3.0],  # touches the front face (closed set)
                [2.1, -3.0, 2.1, 3.0],  # just misses
                [-3.0, 0.6, 3.0, 0.6],  # parallel, outside
                [3.0, 3.0, 3.0, 3.0],  # zero-length, outside
                [0.0, 0.0, 0.0, 0.0],  # zero-length, inside
            ]
        ]
    )
    mask = torch.tensor([[True, True, True, True, True, True, False]])
    got = segment_box_overlap(segs, *box, mask=mask)
    assert got[0].tolist() == [True, True, True, False, False, False, False]


def _rect_by_hand(ref, heading, ahead, behind, half):
    """Corners ``[..., 4, 2]`` of a rectangle reaching ``ahead`` / ``behind`` metres from
    ``ref [..., 2]`` along ``heading`` [rad] and ``half`` to each side (numpy, float64)."""
    u = np.stack((np.cos(heading), np.sin(heading)), -1)
    v = np.stack((-u[..., 1], u[..., 0]), -1)
    along = np.stack((ahead, ahead, -behind, -behind), -1)[..., None]
    across = np.stack((-half, half, half, -half), -1)[..., None]
    return ref[..., None, :] + along * u[..., None, :] + across * v[..., None, :]


def _truck_by_hand(pose, p, grow=0.0):
    """Tractor and trailer corners ``[N, 4, 2]`` from the documented dimensions
    (``truckrl/sim/vehicle.py`` module doc), every side moved out by ``grow`` [m]: the tractor
    spans ``wheelbase + front_overhang`` ahead of its rear axle and ``rear_overhang`` behind; the
    kingpin is ``kingpin_offset`` behind the rear axle; the trailer, heading ``theta + phi``,
    spans ``trailer_front_overhang`` ahead of the kingpin and ``trailer_wheelbase +
    trailer_rear_overhang`` behind."""
    p = {k: v.double().numpy() for k, v in p.items()}
    x, y, th, phi = pose.double().numpy().T
    axle = np.stack((x, y), -1)
    tractor = _rect_by_hand(
        axle,
        th,
        p["wheelbase"] + p["front_overhang"] + grow,
        p["rear_overhang"] + grow,
        0.5 * p["tractor_width"] + grow,
    )
    kingpin = axle - p["kingpin_offset"][:, None] * np.stack((np.cos(th), np.sin(th)), -1)
    trailer = _rect_by_hand(
        kingpin,
        th + phi,
        p["trailer_front_overhang"] + grow,
        p["trailer_wheelbase"] + p["trailer_rear_overhang"] + grow,
        0.5 * p["trailer_width"] + grow,
    )
    return tractor, trailer


def _sat_overlap(seg, corners):
    """Whether segments ``[N, E, 4]`` share a point with filled rectangles ``[N, 4, 2]``
    (separating-axis test: disjoint iff the projections on a rectangle axis or on the segment
    normal are disjoint)."""
    ends = seg.reshape(*seg.shape[:-1], 2, 2)  # [N, E, 2, 2]
    edge1 = corners[:, 1] - corners[:, 0]  # across the rectangle
    edge2 = corners[:, 0] - corners[:, 3]  # along it
    d = ends[..., 1, :] - ends[..., 0, :]
    axes = [
        np.broadcast_to(edge1[:, None], d.shape),
        np.broadcast_to(edge2[:, None], d.shape),
        np.stack((-d[..., 1], d[..., 0]), -1),
    ]
    separated = np.zeros(seg.shape[:-1], dtype=bool)
    for a in axes:
        pc = np.einsum("nkc,nec->nek", corners, a)  # [N, E, 4]
        ps = np.einsum("nejc,nec->nej", ends, a)  # [N, E, 2]
        separated |= (ps.max(-1) < pc.min(-1)) | (ps.min(-1) > pc.max(-1))
    return ~separated


def _inside(points, corners):
    """Whether points ``[N, E, 2]`` lie in the filled rectangles ``[N, 4, 2]``."""
    inside = np.ones(points.shape[:-1], dtype=bool)
    for i in range(4):
        a = corners[:, i, None]
        edge, rel = corners[:, (i + 1) % 4, None] - a, points - a
        cross = edge[..., 0] * rel[..., 1] - edge[..., 1] * rel[..., 0]
        inside &= cross >= 0  # counter-clockwise corners: the inside is on the left of each edge
    return inside


def test_truck_collides_matches_a_separating_axis_oracle_of_the_documented_bodies():
    gen = torch.Generator().manual_seed(1)
    n, e, mm = 400, 16, 1e-3
    params = sample_vehicle_params(VehicleConfig(), n, gen)
    pose = torch.zeros(n, 4)
    pose[:, :2] = torch.rand(n, 2, generator=gen) * 20 - 10
    pose[:, 2] = (torch.rand(n, generator=gen) * 2 - 1) * math.pi
    pose[:, 3] = (torch.rand(n, generator=gen) * 2 - 1) * 1.2
    # segment centres near the truck (3 in 4 within +-12 m of its axle) or anywhere in +-45 m;
    # half of them short (< 1 m, some wholly inside a body), half up to 24 m long
    spread = torch.where(torch.arange(e) < 3 * e // 4, 12.0, 45.0)
    mid = pose[:, None, :2] + (torch.rand(n, e, 2, generator=gen) * 2 - 1) * spread[:, None]
    length = torch.rand(n, e, generator=gen) * torch.where(torch.arange(e) % 2 == 0, 1.0, 24.0)
    ang = torch.rand(n, e, generator=gen) * 2 * math.pi
    half = 0.5 * length[..., None] * torch.stack((ang.cos(), ang.sin()), -1)
    segs = torch.cat((mid - half, mid + half), -1)
    mask = torch.rand(n, e, generator=gen) > 0.2
    # one truck per (truck, segment) pair, so each pair gets its own answer
    rep = {k: v.repeat_interleave(e) for k, v in params.items()}
    got = truck_collides(pose.repeat_interleave(e, 0), rep, segs.reshape(-1, 1, 4))
    got = got.reshape(n, e).numpy()
    masked = truck_collides(pose, params, segs, mask).numpy()

    s = segs.double().numpy()
    grown, shrunk = _truck_by_hand(pose, params, mm), _truck_by_hand(pose, params, -mm)
    hit = _sat_overlap(s, shrunk[0]) | _sat_overlap(s, shrunk[1])  # overlaps by > 1 mm
    miss = ~(_sat_overlap(s, grown[0]) | _sat_overlap(s, grown[1]))  # clear by > 1 mm
    assert (hit | miss).mean() > 0.999  # pairs within 1 mm of touching are left out
    assert got[hit].all() and not got[miss].any()
    # with the padding mask: a truck collides iff a valid segment overlaps it
    valid = mask.numpy()
    assert masked[(hit & valid).any(-1)].all() and not masked[(miss | ~valid).all(-1)].any()
    # the data holds every case: hits on each body, segments wholly inside a body (no edge
    # crossed), and segments beyond the truck's reach (> 16 m from its rear axle: the trailer
    # rear is at most 0.3 + 11 + 3.5 = 14.8 m behind it, 1.3 m to the side)
    a, b = s[..., :2] - pose[:, None, :2].numpy(), s[..., 2:] - pose[:, None, :2].numpy()
    t = np.clip(-(a * (b - a)).sum(-1) / np.maximum(((b - a) ** 2).sum(-1), 1e-12), 0, 1)
    far = np.linalg.norm(a + t[..., None] * (b - a), axis=-1) > 16.0
    assert far.sum() > 1000 and miss[far].all() and not got[far].any()
    assert _sat_overlap(s, shrunk[0]).sum() > 100 and _sat_overlap(s, shrunk[1]).sum() > 100
    assert 0.1 < hit.mean() < 0.5
    # the contour test sees a body when the segment crosses its boundary (overlaps the shrunk
    # body, an end outside the grown one), not when the segment lies wholly inside (both ends in
    # the shrunk, convex body) or misses it
    crosses, clear = [], []
    for big, small in zip(grown, shrunk, strict=True):
        ends_in_big = _inside(s[..., :2], big), _inside(s[..., 2:], big)
        wholly_inside = _inside(s[..., :2], small) & _inside(s[..., 2:], small)
        crosses.append(_sat_overlap(s, small) & ~(ends_in_big[0] & ends_in_big[1]))
        clear.append(~_sat_overlap(s, big) | wholly_inside)
    contour_hit, contour_miss = crosses[0] | crosses[1], clear[0] & clear[1]
    assert (contour_hit | contour_miss).mean() > 0.999
    assert (hit & contour_miss).sum() > 20  # segments wholly inside a body occur
    contour = contour_collides(
        vehicle_outline(pose.repeat_interleave(e, 0), rep), segs.reshape(-1, 1, 4)
    )
    contour = contour.reshape(n, e).numpy()
    assert contour[contour_hit].all() and not contour[contour_miss].any()


def _reference_box_overlap(segments, cx, cy, heading, front, rear, half_width, mask=None):
    """The Liang-Barsky clip as first written (where against scalars), for the bit check."""
    import math

    ends = to_local(
        segments.unflatten(-1, (2, 2)).flatten(-3, -2), torch.stack((cx, cy), -1), heading
    )
    x0, y0 = ends[..., 0::2, 0], ends[..., 0::2, 1]
    dx, dy = ends[..., 1::2, 0] - x0, ends[..., 1::2, 1] - y0
    eps = 1e-6

    def slab(p0, d, lo, hi):
        lo, hi = lo.unsqueeze(-1) - eps, hi.unsqueeze(-1) + eps
        flat = d.abs() <= 1e-9
        safe = torch.where(flat, torch.ones_like(d), d)
        t1, t2 = (lo - p0) / safe, (hi - p0) / safe
        inside = (p0 >= lo) & (p0 <= hi)
        t_in = torch.where(flat, torch.where(inside, -math.inf, math.inf), torch.minimum(t1, t2))
        t_out = torch.where(flat, torch.where(inside, math.inf, -math.inf), torch.maximum(t1, t2))
        return t_in, t_out

    tx_in, tx_out = slab(x0, dx, -rear, front)
    ty_in, ty_out = slab(y0, dy, -half_width, half_width)
    t_in = torch.maximum(torch.maximum(tx_in, ty_in), torch.zeros_like(tx_in))
    t_out = torch.minimum(torch.minimum(tx_out, ty_out), torch.ones_like(tx_out))
    hit = t_in <= t_out
    return hit if mask is None else hit & mask


def test_box_overlap_same_booleans_as_the_where_form():
    # coordinates on a 0.5 m grid and axis-aligned boxes: many segments parallel to a face
    # (the flat branch), touching it exactly, or ending on it
    gen = torch.Generator().manual_seed(4)
    n, e = 4000, 8
    box = list(_random_boxes(n, gen))
    box[2] = torch.randint(0, 4, (n,), generator=gen) * (torch.pi / 2)
    box = [(b * 2).round() / 2 if i != 2 else b for i, b in enumerate(box)]
    box[3:] = [b.clamp_min(0.5) for b in box[3:]]
    segs = ((torch.rand(n, e, 4, generator=gen) * 16 - 8) * 2).round() / 2
    segs[:, :3, 3] = segs[:, :3, 1]  # horizontal
    segs[:, 3:5, 2] = segs[:, 3:5, 0]  # vertical
    mask = torch.rand(n, e, generator=gen) > 0.2
    got = segment_box_overlap(segs, *box, mask=mask)
    want = _reference_box_overlap(segs, *box, mask=mask)
    assert torch.equal(got, want)
    assert 0.1 < want.float().mean() < 0.9


def test_sparse_collision_gives_the_dense_answer_bit_for_bit():
    # poses at ~1 km from the origin (float32 round-off of a scene far out), segments near the
    # truck or far, short or long, and grazing ones: from a corner of a body straight away from
    # the body's centre, so the segment's bounding circle just touches the body's (the cull's
    # tightest case), some 1 um inside the corner, some 1 um outside
    gen = torch.Generator().manual_seed(3)
    n, e = 600, 40
    params = sample_vehicle_params(VehicleConfig(), n, gen)
    pose = torch.zeros(n, 4)
    pose[:, :2] = 1000.0 + torch.rand(n, 2, generator=gen) * 20 - 10
    pose[:, 2] = (torch.rand(n, generator=gen) * 2 - 1) * math.pi
    pose[:, 3] = (torch.rand(n, generator=gen) * 2 - 1) * 1.2
    mid = pose[:, None, :2] + (torch.rand(n, e, 2, generator=gen) * 2 - 1) * 30.0
    length = torch.rand(n, e, generator=gen) * torch.where(torch.arange(e) % 2 == 0, 1.0, 40.0)
    ang = torch.rand(n, e, generator=gen) * 2 * math.pi
    half = 0.5 * length[..., None] * torch.stack((ang.cos(), ang.sin()), -1)
    segs = torch.cat((mid - half, mid + half), -1)
    graze = []
    for box in truck_boxes(pose, params)[:2]:
        corners = rectangle_corners(*box)  # [n, 4, 2]
        centre = corners.mean(-2, keepdim=True)
        out = corners - centre
        out = out / out.norm(dim=-1, keepdim=True)
        for shift in (-1e-6, 0.0, 1e-6):
            start = corners + shift * out
            graze.append(torch.cat((start, start + 5.0 * out), -1))  # [n, 4, 4]
    segs = torch.cat((segs, *graze), 1)
    mask = torch.rand(segs.shape[:2], generator=gen) > 0.1
    # one pose per (pose, segment) pair, so each pair gets its own answer
    rep = {k: v.repeat_interleave(segs.shape[1]) for k, v in params.items()}
    one = (pose.repeat_interleave(segs.shape[1], 0), rep, segs.reshape(-1, 1, 4))
    dense, sparse = truck_collides(*one), truck_collides_sparse(*one)
    assert 0.1 < dense.float().mean() < 0.6
    graze_hits = dense.view(n, -1)[:, e:]
    assert graze_hits.any() and not graze_hits.all()
    assert torch.equal(sparse, dense)
    pair_mask = mask.reshape(-1, 1)
    masked = truck_collides(*one, pair_mask)
    assert (dense & ~masked).any()  # masked-out segments that touch
    assert torch.equal(truck_collides_sparse(*one, pair_mask), masked)
    batched = truck_collides(pose, params, segs, mask)
    assert torch.equal(truck_collides_sparse(pose, params, segs, mask), batched)
    assert torch.equal(
        truck_collides_sparse(pose, params, segs), truck_collides(pose, params, segs)
    )
    # no segment near anything: every pose is free
    far = segs + 500.0
    assert not truck_collides_sparse(pose, params, far, mask).any()
