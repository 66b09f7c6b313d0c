"""Body collision: the box clip against independent answers (contour test, dense sampling)."""

import torch

from truckrl.sim.collision import contour_collides, truck_collides
from truckrl.sim.geometry import (
    point_segment_distance,
    polygon_segments,
    rectangle_corners,
    segment_box_overlap,
    segments_intersect,
    to_local,
)
from truckrl.sim.vehicle import VehicleConfig, sample_vehicle_params, vehicle_outline


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


def test_truck_collides_agrees_with_outline_contour_on_crossing_segments():
    gen = torch.Generator().manual_seed(1)
    n = 500
    params = sample_vehicle_params(VehicleConfig(), n, gen)
    pose = torch.zeros(n, 4)
    pose[:, 3] = torch.rand(n, generator=gen) - 0.5
    segs = torch.rand(n, 10, 4, generator=gen) * 40 - 20
    mask = torch.rand(n, 10, generator=gen) > 0.3
    contour = contour_collides(vehicle_outline(pose, params), segs, mask)
    body = truck_collides(pose, params, segs, mask)
    # the body test also sees segments wholly inside a body; random 20 m segments never are,
    # so on this data both must agree exactly, and they must disagree nowhere else
    far = point_segment_distance(pose[:, None, :2], segs)[:, 0] > 30
    assert torch.equal(body, contour)
    assert not body[far.all(-1)].any()


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
