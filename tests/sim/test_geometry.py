"""Segment geometry against hand-computed cases and brute-force / float64 oracles."""

import math

import numpy as np
import pytest
import torch

from truckrl.sim.geometry import (
    point_segment_distance,
    polygon_segments,
    ray_segment_distance,
    rectangle_corners,
    rectangle_segments,
    segment_segment_distance,
    segments_intersect,
    segments_to_local,
    to_local,
    unit_vectors,
    wrap_angle,
)


def seg(*coords) -> torch.Tensor:
    return torch.tensor(coords, dtype=torch.float32).view(-1, 4)


def intersects(a, b) -> bool:
    return bool(segments_intersect(seg(*a), seg(*b))[0, 0])


# --- segments_intersect -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ((0, 0, 2, 2), (0, 2, 2, 0), True),  # proper crossing
        ((0, 0, 1, 0), (0, 1, 1, 1), False),  # parallel, disjoint
        ((0, 0, 2, 0), (1, 0, 3, 0), True),  # collinear, overlapping
        ((0, 0, 3, 0), (1, 0, 2, 0), True),  # collinear, one inside the other
        ((0, 0, 1, 0), (2, 0, 3, 0), False),  # collinear, disjoint
        ((0, 0, 1, 0), (1, 0, 2, 0), True),  # collinear, touching endpoints
        ((0, 0, 1, 0), (1, 0, 1, 1), True),  # touching endpoints at a corner
        ((0, 0, 2, 0), (1, 0, 1, 1), True),  # T-junction: endpoint on the other's interior
        ((0, 0, 2, 0), (1, 0.01, 1, 1), False),  # T just short
        ((0, 0, 2, 0), (2.01, -1, 2.01, 1), False),  # passes just beyond the end
        ((0, 0, 1, 1), (2, 2, 3, 3), False),  # collinear diagonal, disjoint
        ((0, 0, 0, 0), (-1, 0, 1, 0), True),  # degenerate point on a segment
    ],
)
def test_segments_intersect_hand_cases(a, b, expected):
    assert intersects(a, b) is expected
    assert intersects(b, a) is expected
    assert intersects(b[2:] + b[:2], a) is expected  # endpoint order does not matter


def _solve_params(p, r, q, s):
    """Float64 Cramer solve of ``p + t r = q + u s`` for broadcast arrays ``[..., 2]``."""
    det = r[..., 0] * -s[..., 1] + s[..., 0] * r[..., 1]
    w = q - p
    t = (w[..., 0] * -s[..., 1] + s[..., 0] * w[..., 1]) / det
    u = (r[..., 0] * w[..., 1] - r[..., 1] * w[..., 0]) / det
    return t, u


def test_segments_intersect_random_vs_oracle():
    rng = np.random.default_rng(0)
    a = rng.uniform(-10, 10, (400, 1, 4))
    b = rng.uniform(-10, 10, (1, 300, 4))
    got = segments_intersect(
        torch.tensor(a[:, 0], dtype=torch.float32), torch.tensor(b[0], dtype=torch.float32)
    )
    assert got.shape == (400, 300)
    t, u = _solve_params(a[..., :2], a[..., 2:] - a[..., :2], b[..., :2], b[..., 2:] - b[..., :2])
    expected = (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    assert 1000 < expected.sum() < 100000  # both outcomes are well represented
    assert (got.numpy() == expected).mean() > 0.999  # float32 vs float64 at grazing contacts


def test_segments_intersect_padding_and_batch_shapes():
    a = seg(0, 0, 2, 2, 5, 5, 6, 6).expand(3, 2, 4)
    b = seg(0, 2, 2, 0).expand(3, 1, 4)
    a_mask = torch.tensor([[True, True], [False, True], [True, True]])
    b_mask = torch.tensor([[True], [True], [False]])
    hit = segments_intersect(a, b, a_mask, b_mask)
    assert hit.shape == (3, 2, 1)
    assert hit[:, :, 0].tolist() == [[True, False], [False, False], [False, False]]


# --- point_segment_distance ---------------------------------------------------------------------


def test_point_segment_distance_hand_cases():
    s = seg(0, 0, 4, 0)
    pts = torch.tensor([[2.0, 3.0], [-3.0, 4.0], [7.0, -4.0], [1.0, 0.0]])
    d = point_segment_distance(pts, s)[:, 0]
    torch.testing.assert_close(d, torch.tensor([3.0, 5.0, 5.0, 0.0]))
    # degenerate segment = a point
    d = point_segment_distance(torch.tensor([[3.0, 4.0]]), seg(0, 0, 0, 0))
    torch.testing.assert_close(d, torch.tensor([[5.0]]))


def test_point_segment_distance_vs_dense_sampling():
    rng = np.random.default_rng(1)
    segs = rng.uniform(-20, 20, (40, 4))
    pts = rng.uniform(-30, 30, (100, 2))
    d = point_segment_distance(
        torch.tensor(pts, dtype=torch.float32), torch.tensor(segs, dtype=torch.float32)
    )
    t = np.linspace(0.0, 1.0, 2001)
    samples = segs[:, None, :2] + t[None, :, None] * (
        segs[:, None, 2:] - segs[:, None, :2]
    )  # [E,S,2]
    brute = np.linalg.norm(pts[:, None, None, :] - samples[None], axis=-1).min(-1)  # [P, E]
    step = np.linalg.norm(segs[:, 2:] - segs[:, :2], axis=-1) / 2000
    assert np.all(d.numpy() <= brute + 1e-4)
    assert np.all(d.numpy() >= brute - step[None] / 2 - 1e-4)


def test_point_segment_distance_mask():
    d = point_segment_distance(
        torch.zeros(1, 2), seg(0, 1, 1, 1, 0, 2, 1, 2), torch.tensor([True, False])
    )
    assert d[0, 0] == 1.0 and math.isinf(d[0, 1])


# --- segment_segment_distance -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ((0, 0, 2, 2), (0, 2, 2, 0), 0.0),  # crossing
        ((0, 0, 4, 0), (1, 1, 3, 1), 1.0),  # parallel, overlapping in x
        ((0, 0, 1, 0), (4, 0, 6, 0), 3.0),  # collinear, disjoint
        ((0, 0, 1, 0), (4, 4, 4, 9), 5.0),  # endpoint to endpoint (3-4-5)
        ((0, 0, 2, 0), (1, 0, 1, 1), 0.0),  # T-junction
    ],
)
def test_segment_segment_distance_hand_cases(a, b, expected):
    d = segment_segment_distance(seg(*a), seg(*b))
    torch.testing.assert_close(d, torch.tensor([[float(expected)]]))


def test_segment_segment_distance_vs_brute_force():
    rng = np.random.default_rng(2)
    a = rng.uniform(-10, 10, (30, 4))
    b = rng.uniform(-10, 10, (20, 4))
    d = segment_segment_distance(
        torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32)
    )
    t = np.linspace(0.0, 1.0, 301)
    pa = a[:, None, :2] + t[None, :, None] * (a[:, None, 2:] - a[:, None, :2])  # [A, S, 2]
    pb = b[:, None, :2] + t[None, :, None] * (b[:, None, 2:] - b[:, None, :2])
    brute = np.empty((30, 20))
    for i in range(30):
        brute[i] = np.linalg.norm(pa[i][None, :, None] - pb[:, None], axis=-1).min((1, 2))
    step = (
        np.linalg.norm(a[:, 2:] - a[:, :2], axis=-1)[:, None]
        + np.linalg.norm(b[:, 2:] - b[:, :2], axis=-1)[None]
    ) / 300
    assert np.all(d.numpy() <= brute + 1e-4)
    assert np.all(d.numpy() >= brute - step - 1e-4)
    assert (d.numpy() == 0).sum() > 20  # intersecting pairs are covered too


def test_segment_segment_distance_padding():
    d = segment_segment_distance(
        seg(0, 0, 1, 0), seg(0, 1, 1, 1, 0, 2, 1, 2), b_mask=torch.tensor([False, True])
    )
    assert math.isinf(d[0, 0]) and d[0, 1] == 2.0


# --- ray_segment_distance -----------------------------------------------------------------------


def ray(origin, angle, *segments, mask=None) -> torch.Tensor:
    return ray_segment_distance(
        torch.tensor(origin, dtype=torch.float32),
        torch.tensor([angle], dtype=torch.float32),
        seg(*segments),
        mask,
    )[0]


def test_ray_hits_through_vertices():
    # a polygon corner at (5, 0): the ray along +x hits both edges meeting there at distance 5
    d = ray((0.0, 0.0), 0.0, 5, -1, 5, 0, 5, 0, 6, 1)
    torch.testing.assert_close(d, torch.tensor([5.0, 5.0]))
    # diagonal ray exactly through an endpoint
    d = ray((0.0, 0.0), math.pi / 4, 3, 3, 3, 8)
    torch.testing.assert_close(d, torch.tensor([3.0 * math.sqrt(2.0)]))


def test_ray_collinear_with_segment():
    d = ray((0.0, 0.0), 0.0, 3, 0, 8, 0, 8, 0, 3, 0, -8, 0, -3, 0, -2, 0, 4, 0)
    assert d[:2].tolist() == [3.0, 3.0]  # nearest endpoint ahead, either orientation
    assert math.isinf(d[2])  # collinear but behind
    assert d[3] == 0.0  # the origin lies on it


def test_ray_starting_on_a_segment():
    d = ray((0.0, 0.0), 0.3, 0, -1, 0, 1, -1, 0, 1, 0)
    assert d[0].item() == pytest.approx(0.0, abs=1e-6)
    assert d[1].item() == pytest.approx(0.0, abs=1e-6)


def test_ray_misses_return_inf():
    d = ray(
        (0.0, 0.0),
        0.0,
        1,
        1,
        5,
        1,
        -5,
        -1,
        -5,
        1,
        5,
        0.5,
        5,
        3,
        2,
        0,
        2,
        1,
        mask=torch.tensor([True, True, True, False]),
    )
    assert torch.isinf(d).all()  # parallel, behind, passes beside, padding


def test_ray_random_vs_oracle():
    rng = np.random.default_rng(3)
    segs = rng.uniform(-20, 20, (30, 4))
    angles = rng.uniform(-math.pi, math.pi, 64)
    origin = np.array([0.5, -0.25])
    d = ray_segment_distance(
        torch.tensor(origin, dtype=torch.float32),
        torch.tensor(angles, dtype=torch.float32),
        torch.tensor(segs, dtype=torch.float32),
    )
    r = np.stack((np.cos(angles), np.sin(angles)), -1)[:, None]  # [R, 1, 2]
    t, u = _solve_params(origin, r, segs[None, :, :2], segs[None, :, 2:] - segs[None, :, :2])
    expected = np.where((t >= 0) & (u >= 0) & (u <= 1), t, np.inf)
    hit = np.isfinite(expected)
    assert hit.sum() > 100
    assert (np.isfinite(d.numpy()) == hit).mean() > 0.999
    both = hit & np.isfinite(d.numpy())
    np.testing.assert_allclose(d.numpy()[both], expected[both], rtol=1e-4, atol=1e-4)


# --- angles, frames, rectangles -----------------------------------------------------------------


def test_wrap_angle_range_and_equivalence():
    a = torch.linspace(-20.0, 20.0, 4001, dtype=torch.float64)
    w = wrap_angle(a)
    assert (w >= -math.pi).all() and (w < math.pi).all()
    torch.testing.assert_close(torch.sin(w), torch.sin(a))
    torch.testing.assert_close(torch.cos(w), torch.cos(a))
    assert wrap_angle(torch.tensor(math.pi, dtype=torch.float64)).item() == pytest.approx(-math.pi)
    assert wrap_angle(torch.tensor(0.5)).item() == pytest.approx(0.5)


def test_to_local_hand_case():
    pts = torch.tensor([[[1.0, 3.0]]])
    local = to_local(pts, torch.tensor([[1.0, 1.0]]), torch.tensor([math.pi / 2]))
    torch.testing.assert_close(local, torch.tensor([[[2.0, 0.0]]]))  # 2 m straight ahead


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_segments_to_local_is_to_local_of_the_ends_bit_for_bit(dtype):
    # the LiDAR and the body clips rotate segments with segments_to_local; its coordinates must
    # be the very bits to_local gives for the same ends (the golden rollout depends on it)
    g = torch.Generator().manual_seed(5)
    segs = ((torch.rand(3, 40, 4, generator=g, dtype=torch.float64) - 0.5) * 400).to(dtype)
    origin = ((torch.rand(3, 2, generator=g, dtype=torch.float64) - 0.5) * 400).to(dtype)
    heading = ((torch.rand(3, generator=g, dtype=torch.float64) - 0.5) * 20).to(dtype)
    x0, y0, x1, y1 = segments_to_local(segs, origin, heading)
    ends = to_local(segs.unflatten(-1, (2, 2)).flatten(-3, -2), origin, heading)  # [3, 80, 2]
    assert x0.shape == (3, 40) and x0.dtype == dtype
    assert torch.equal(torch.stack((x0, y0), -1), ends[:, 0::2])
    assert torch.equal(torch.stack((x1, y1), -1), ends[:, 1::2])
    # hand case: a segment 2 m ahead of a truck at (1, 1) facing +y, running to its left
    got = segments_to_local(
        torch.tensor([[[1.0, 3.0, -1.0, 3.0]]]),
        torch.tensor([[1.0, 1.0]]),
        torch.tensor([math.pi / 2]),
    )
    torch.testing.assert_close(torch.cat(got, -1), torch.tensor([[2.0, 0.0, 2.0, 2.0]]))


def test_unit_vectors_are_the_exact_cosines_and_sines():
    a = torch.linspace(-7.0, 7.0, 1001)
    cs = unit_vectors(a)
    assert cs.shape == (1001, 2)
    assert torch.equal(cs[:, 0], torch.cos(a)) and torch.equal(cs[:, 1], torch.sin(a))


def test_rectangle_corners_ccw_and_hand_values():
    c = rectangle_corners(*(torch.tensor(v) for v in (1.0, 2.0, 0.0, 3.0, 1.0, 0.5)))
    expected = torch.tensor([[4.0, 1.5], [4.0, 2.5], [0.0, 2.5], [0.0, 1.5]])
    torch.testing.assert_close(c, expected)
    c = rectangle_corners(*(torch.tensor(v) for v in (0.0, 0.0, math.pi / 2, 3.0, 1.0, 0.5)))
    torch.testing.assert_close(
        c, torch.tensor([[0.5, 3.0], [-0.5, 3.0], [-0.5, -1.0], [0.5, -1.0]]), atol=1e-6, rtol=0
    )
    # random rectangles: positive shoelace area equal to length x width
    g = torch.Generator().manual_seed(0)
    v = torch.rand(6, 100, generator=g) * torch.tensor([[10], [10], [7], [5], [5], [2]]) + 0.1
    c = rectangle_corners(*v)
    x, y = c[..., 0], c[..., 1]
    area = 0.5 * (x * y.roll(-1, -1) - x.roll(-1, -1) * y).sum(-1)
    torch.testing.assert_close(area, (v[3] + v[4]) * 2 * v[5], rtol=1e-4, atol=1e-4)


def test_rectangle_and_polygon_edges():
    corners = torch.tensor([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    e = polygon_segments(corners)
    expected = torch.tensor(
        [[0, 0, 2, 0], [2, 0, 2, 1], [2, 1, 0, 1], [0, 1, 0, 0]], dtype=torch.float32
    )
    torch.testing.assert_close(e, expected)
    args = [torch.tensor(v) for v in (1.0, 2.0, 0.7, 3.0, 1.0, 0.5)]
    edges = rectangle_segments(*args)
    torch.testing.assert_close(edges, polygon_segments(rectangle_corners(*args)))
