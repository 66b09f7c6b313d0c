"""Scene generator: every rule of the module doc checked on 10,000 scenes with independent geometry."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.collision import contour_collides
from truckrl.sim.geometry import (
    polygon_segments,
    segment_segment_distance,
    segments_intersect,
)
from truckrl.sim.vehicle import VehicleConfig, sample_vehicle_params, truck_corners, vehicle_outline
from truckrl.tasks.intersection.scene import (
    CURB_SLOTS,
    ROUTE_LEFT,
    ROUTE_NAMES,
    ROUTE_RIGHT,
    ROUTE_STRAIGHT_ON,
    ROUTE_STRAIGHT_ROAD,
    SceneBatch,
    SceneConfig,
    generate_scenes,
)

N = 10_000
TOL = 1e-3  # [m] float32 round-off at coordinates of O(100 m)


def make(cfg: SceneConfig, n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    params = sample_vehicle_params(VehicleConfig(), n, generator=g)
    return generate_scenes(cfg, params, generator=g), params


@pytest.fixture(scope="module")
def default_batch():
    cfg = SceneConfig()
    batch, params = make(cfg, N, 123)
    return cfg, batch, params


@pytest.fixture(scope="module", params=["default", "one_round"])
def batch(request, default_batch):
    """The default batch, and a batch whose rejection stops after one round (fallbacks)."""
    if request.param == "default":
        return default_batch
    cfg = SceneConfig(rounds=1, obstacle_keep_prob=1.0)
    b, params = make(cfg, 2000, 7)
    return cfg, b, params


def pose4(pose: torch.Tensor) -> torch.Tensor:
    return torch.cat((pose, torch.zeros_like(pose[:, :1])), dim=-1)


def road_frames(b: SceneBatch):
    """Per road: centre [N,2,2], direction d [N,2,2], left normal n [N,2,2], width [N,2]."""
    c, h, w = b.roads[..., :2], b.roads[..., 2], b.roads[..., 3]
    d = torch.stack((torch.cos(h), torch.sin(h)), -1)
    n = torch.stack((-torch.sin(h), torch.cos(h)), -1)
    return c, d, n, w


def pose_road(b: SceneBatch, pose: torch.Tensor) -> torch.Tensor:
    """Index [N] of the road a pose is aligned with; asserts exactly one is."""
    diff = pose[:, 2:3] - b.roads[..., 2]
    aligned = (torch.sin(diff).abs() < 1e-4) & b.road_mask
    assert (aligned.sum(-1) == 1).all(), "pose heading not parallel to exactly one road"
    return aligned.long().argmax(-1)


def expected_corners(b: SceneBatch) -> np.ndarray:
    """Curb-curb crossing points [N, 4, 2] from the road lines, solved in float64."""
    roads = b.roads.double().numpy()
    c, h, w = roads[:, 0, :2], roads[..., 2], roads[..., 3]
    d = np.stack((np.cos(h), np.sin(h)), -1)  # [N, 2, 2]
    nrm = np.stack((-np.sin(h), np.cos(h)), -1)
    out = []
    for s0, s1 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        p0 = c + s0 * 0.5 * w[:, :1] * nrm[:, 0]
        p1 = c + s1 * 0.5 * w[:, 1:] * nrm[:, 1]
        a = np.stack((d[:, 0], -d[:, 1]), -1)  # p0 + t d0 = p1 + u d1
        tu = np.linalg.solve(a, (p1 - p0)[..., None])[..., 0]
        out.append(p0 + tu[:, :1] * d[:, 0])
    return np.stack(out, 1)


def test_shapes_mask_and_kind(batch):
    cfg, b, _ = batch
    n, e = b.segments.shape[:2]
    assert e == CURB_SLOTS + 4 * cfg.max_obstacles == cfg.num_segments
    assert b.mask.shape == b.kind.shape == (n, e) and b.mask.dtype == torch.bool
    assert b.kind.dtype == torch.int8
    assert (b.kind[:, :CURB_SLOTS] == 0).all() and (b.kind[:, CURB_SLOTS:] == 1).all()
    assert b.start.shape == b.goal.shape == (n, 3)
    assert b.intersection.shape == (n, 4, 2) and b.roads.shape == (n, 2, 4)
    # curb slots: 2 for a straight road, all 8 at a crossing
    assert b.mask[:, :2].all()
    assert (b.mask[:, 2:CURB_SLOTS] == b.crossing.unsqueeze(-1)).all()
    assert (b.road_mask[:, 0]).all() and (b.road_mask[:, 1] == b.crossing).all()
    # an obstacle is all 4 edges or none; padding is zeroed
    obs = b.mask[:, CURB_SLOTS:].view(n, -1, 4)
    assert (obs == obs[..., :1]).all()
    assert (b.segments[~b.mask] == 0).all()
    assert (b.intersection[~b.crossing] == 0).all()
    assert torch.isfinite(b.segments).all() and torch.isfinite(b.start).all()
    assert torch.isfinite(b.goal).all()


def test_scene_mix(default_batch):
    cfg, b, _ = default_batch
    frac = b.crossing.float().mean().item()
    assert abs(frac - cfg.crossing_prob) < 0.03
    count = b.mask[:, CURB_SLOTS:].sum(-1) / 4
    assert 3.0 < count.float().mean().item() < cfg.max_obstacles * cfg.obstacle_keep_prob
    w = b.roads[..., 3][b.road_mask]
    assert w.min() >= cfg.road_width[0] and w.max() <= cfg.road_width[1]


def test_crossing_curbs_meet_at_the_junctions(batch):
    _, b, _ = batch
    x = b.crossing
    corners = expected_corners(b)[x.numpy()]
    got = b.intersection[x].double().numpy()
    np.testing.assert_allclose(got, corners, atol=TOL)  # same points, same (CCW) order
    xs, ys = corners[..., 0], corners[..., 1]
    area = 0.5 * (xs * np.roll(ys, -1, 1) - np.roll(xs, -1, 1) * ys).sum(-1)
    assert (area > 0).all()
    # every junction is the endpoint of exactly one curb piece of each road
    curbs = b.segments[x, :CURB_SLOTS].double().numpy()
    ends = curbs.reshape(-1, 8, 2, 2)
    dist = np.linalg.norm(ends[:, :, :, None] - corners[:, None, None], axis=-1)  # [M, 8, 2, 4]
    at = dist < TOL
    assert (at.sum((1, 2)) == 2).all()
    road_of_slot = np.arange(8) // 4
    for r in (0, 1):
        assert (at[:, road_of_slot == r].sum((1, 2)) == 1).all()
    assert (at.sum((2, 3)) == 1).all()  # each piece has exactly one junction end


def test_curb_pieces_lie_on_their_lines_outside_the_other_road(batch):
    _, b, _ = batch
    c, d, n, w = road_frames(b)
    curbs = b.segments[:, :CURB_SLOTS].view(-1, 8, 2, 2)
    road = torch.arange(8) // 4  # slots 0-3 road 0, 4-7 road 1 (a straight road uses 0-1)
    for r in (0, 1):
        sel = b.mask[:, :CURB_SLOTS] & (road == r)
        rel = curbs - c[:, r].view(-1, 1, 1, 2)
        off = (rel * n[:, r].view(-1, 1, 1, 2)).sum(-1)
        on_line = (off.abs() - 0.5 * w[:, r].view(-1, 1, 1)).abs() < TOL
        assert on_line.all(-1)[sel].all()
        along = (rel * d[:, r].view(-1, 1, 1, 2)).sum(-1)
        # each piece reaches the end of its road
        assert (along.abs().amax(-1)[sel] > 99.0).all()
    # at a crossing, the midpoint of each piece is outside the other road
    mid = curbs.mean(2)
    for r in (0, 1):
        other = 1 - r
        off = ((mid - c[:, other].unsqueeze(1)) * n[:, other].unsqueeze(1)).sum(-1)
        outside = off.abs() > 0.5 * w[:, other].unsqueeze(1)
        assert outside[b.crossing][:, road == r].all()


@pytest.mark.parametrize("which", ["start", "goal"])
def test_poses_never_collide(batch, which):
    _, b, params = batch
    outline = vehicle_outline(pose4(getattr(b, which)), params)
    assert not contour_collides(outline, b.segments, b.mask).any()


@pytest.mark.parametrize("which", ["start", "goal"])
def test_poses_aligned_and_within_their_road(batch, which):
    cfg, b, params = batch
    pose = getattr(b, which)
    r = pose_road(b, pose)
    c, d, n, w = road_frames(b)
    rows = torch.arange(len(b))
    tractor, trailer, _ = truck_corners(pose4(pose), params)
    pts = torch.cat((tractor, trailer), 1) - c[rows, r].unsqueeze(1)
    off = (pts * n[rows, r].unsqueeze(1)).sum(-1)
    along = (pts * d[rows, r].unsqueeze(1)).sum(-1)
    assert (off.abs() <= 0.5 * w[rows, r].unsqueeze(1) + TOL).all()
    assert (along.abs() <= cfg.half_extent + TOL).all()
    # right-hand half of the road, LiDAR reach to the curb ends
    u = torch.stack((torch.cos(pose[:, 2]), torch.sin(pose[:, 2])), -1)
    right = torch.stack((u[:, 1], -u[:, 0]), -1)
    rel = pose[:, :2] - c[rows, r]
    assert ((rel * right).sum(-1) > 0).all()
    assert ((rel * d[rows, r]).sum(-1).abs() <= cfg.half_extent - cfg.curb_reach + TOL).all()


@pytest.mark.parametrize("which", ["start", "goal"])
def test_poses_outside_the_intersection(batch, which):
    cfg, b, params = batch
    x = b.crossing
    pose = pose4(getattr(b, which))[x]
    p = {k: v[x] for k, v in params.items()}
    box = torch.tensor(expected_corners(b)[x.numpy()], dtype=torch.float32)
    gap = segment_segment_distance(vehicle_outline(pose, p), polygon_segments(box))
    assert (gap.flatten(1).amin(-1) >= cfg.pose_intersection_margin - TOL).all()
    # no point of the footprint inside the intersection (= inside both road bands)
    tractor, trailer, _ = truck_corners(pose, p)
    s = torch.linspace(0, 1, 5)
    pts = []
    for quad in (tractor, trailer):
        a, bb, cc = quad[:, 0], quad[:, 1], quad[:, 3]
        grid = a[:, None, None] + s[None, :, None, None] * (bb - a)[:, None, None]
        grid = grid + s[None, None, :, None] * (cc - a)[:, None, None]
        pts.append(grid.flatten(1, 2))
    pts = torch.cat(pts, 1)
    c, d, n, w = road_frames(b)
    inside = torch.ones(pts.shape[:2], dtype=torch.bool)
    for r in (0, 1):
        off = ((pts - c[x, r].unsqueeze(1)) * n[x, r].unsqueeze(1)).sum(-1)
        inside &= off.abs() <= 0.5 * w[x, r].unsqueeze(1)
    assert not inside.any()


def test_goal_is_reachable_forward(batch):
    cfg, b, _ = batch
    c, d, _, _ = road_frames(b)
    rows = torch.arange(len(b))
    u_s = torch.stack((torch.cos(b.start[:, 2]), torch.sin(b.start[:, 2])), -1)
    u_g = torch.stack((torch.cos(b.goal[:, 2]), torch.sin(b.goal[:, 2])), -1)
    dist = (b.goal[:, :2] - b.start[:, :2]).norm(dim=-1)
    assert (dist >= cfg.goal_distance[0] - TOL).all() and (dist <= cfg.goal_distance[1] + TOL).all()
    # straight road: same heading, goal ahead
    s = ~b.crossing
    assert ((u_s * u_g).sum(-1)[s] > 1 - 1e-6).all()
    assert (((b.goal[:, :2] - b.start[:, :2]) * u_s).sum(-1)[s] > 0).all()
    # crossing: start approaches the centre, goal leaves it, on another arm (no U-turn)
    x = b.crossing
    centre = c[:, 0]
    assert (((centre - b.start[:, :2]) * u_s).sum(-1)[x] > 0).all()
    assert (((b.goal[:, :2] - centre) * u_g).sum(-1)[x] > 0).all()
    rs, rg = pose_road(b, b.start), pose_road(b, b.goal)
    side_s = torch.sign(((b.start[:, :2] - centre) * d[rows, rs]).sum(-1))
    side_g = torch.sign(((b.goal[:, :2] - centre) * d[rows, rg]).sum(-1))
    same_arm = (rs == rg) & (side_s == side_g)
    assert not same_arm[x].any()
    # all three exits occur: straight on, and turns to either side
    turn = u_s[:, 0] * u_g[:, 1] - u_s[:, 1] * u_g[:, 0]
    straight_on = (rs == rg) & x
    assert straight_on.sum() > 0.1 * x.sum()
    assert ((turn > 0.1) & x).sum() > 0.12 * x.sum()  # left: fewer, by the left-turn exit rule
    assert ((turn < -0.1) & x).sum() > 0.2 * x.sum()


def inside_convex(points: torch.Tensor, polys: torch.Tensor) -> torch.Tensor:
    """Points [N, P, 2] strictly inside counter-clockwise quads [N, Q, 4, 2] -> [N, P, Q]."""
    a = polys.unsqueeze(1)  # [N, 1, Q, 4, 2]
    e = torch.roll(a, -1, dims=-2) - a
    w = points[:, :, None, None] - a
    cross = e[..., 0] * w[..., 1] - e[..., 1] * w[..., 0]
    return (cross > 0).all(-1)


def obstacle_edges(b: SceneBatch):
    n = len(b)
    edges = b.segments[:, CURB_SLOTS:].view(n, -1, 4, 4)
    return edges, b.mask[:, CURB_SLOTS:].view(n, -1, 4)[..., 0]


def near_pair_distances(a, b, a_mask, b_mask, reach: float, pairs=None) -> torch.Tensor:
    """Distances [P] between the quads ``a [N, A, 4, 2]`` and ``b [N, B, 4, 2]`` (corners) of every
    valid pair (restricted to ``pairs [A, B]`` if given) whose bounding circles come within
    ``reach``; the other valid pairs are farther than ``reach`` apart by the circle bound, so
    only these need the exact segment distance."""
    ca, cb = a.mean(2), b.mean(2)
    ra = (a - ca.unsqueeze(2)).norm(dim=-1).amax(-1)
    rb = (b - cb.unsqueeze(2)).norm(dim=-1).amax(-1)
    gap = (ca.unsqueeze(2) - cb.unsqueeze(1)).norm(dim=-1) - ra.unsqueeze(2) - rb.unsqueeze(1)
    near = (gap < reach) & a_mask.unsqueeze(2) & b_mask.unsqueeze(1)
    if pairs is not None:
        near &= pairs
    n, i, j = near.nonzero(as_tuple=True)
    ea, eb = polygon_segments(a[n, i]), polygon_segments(b[n, j])  # [P, 4, 4]
    return segment_segment_distance(ea, eb).flatten(1).amin(-1)


def footprints(b: SceneBatch, params) -> torch.Tensor:
    """Tractor and trailer corners of start and goal: [N, 4, 4, 2]."""
    bodies = [truck_corners(pose4(p), params)[:2] for p in (b.start, b.goal)]
    return torch.stack([q for pair in bodies for q in pair], 1)


def test_obstacles_keep_clear_of_start_and_goal(batch):
    cfg, b, params = batch
    edges, kept = obstacle_edges(b)
    obs = edges[..., :2]  # [N, K, 4, 2] corners, counter-clockwise
    feet = footprints(b, params)
    everywhere = torch.ones(feet.shape[:2], dtype=torch.bool)
    dist = near_pair_distances(obs, feet, kept, everywhere, cfg.obstacle_pose_clearance)
    assert (dist >= cfg.obstacle_pose_clearance - TOL).all()
    # neither contains the other
    assert not (inside_convex(feet.flatten(1, 2), obs) & kept.unsqueeze(1)).any()
    assert not (inside_convex(obs.mean(2), feet) & kept.unsqueeze(-1)).any()


def test_obstacles_keep_clear_of_each_other_and_of_the_curbs(batch):
    cfg, b, _ = batch
    edges, kept = obstacle_edges(b)
    obs = edges[..., :2]
    k = obs.shape[1]
    upper = torch.ones(k, k, dtype=torch.bool).triu(1)  # each pair once, never with itself
    dist = near_pair_distances(obs, obs, kept, kept, cfg.obstacle_min_gap, upper)
    assert (dist >= cfg.obstacle_min_gap - TOL).all()
    # an obstacle never touches a curb
    hit = segments_intersect(
        edges.flatten(1, 2),
        b.segments[:, :CURB_SLOTS],
        b.mask[:, CURB_SLOTS:],
        b.mask[:, :CURB_SLOTS],
    )
    assert not hit.any()


def test_obstacles_keep_clear_of_the_intersection(batch):
    cfg, b, _ = batch
    x = b.crossing
    edges, kept = obstacle_edges(b)
    edges, kept = edges[x], kept[x]
    box = torch.tensor(expected_corners(b)[x.numpy()], dtype=torch.float32)
    dist = (
        segment_segment_distance(edges.flatten(1, 2), polygon_segments(box))
        .view(*kept.shape, -1)
        .amin(-1)
    )
    assert (dist[kept] >= cfg.obstacle_intersection_clearance - TOL).all()
    centre = edges[..., :2].mean(2)  # mean of the 4 corners
    c, _, n, w = road_frames(b)
    inside = torch.ones_like(kept)
    for r in (0, 1):
        off = ((centre - c[x, r].unsqueeze(1)) * n[x, r].unsqueeze(1)).sum(-1)
        inside &= off.abs() <= 0.5 * w[x, r].unsqueeze(1)
    assert not inside[kept].any()


def test_obstacles_stay_in_their_curb_strip(batch):
    cfg, b, _ = batch
    edges, kept = obstacle_edges(b)
    c, _, n, w = road_frames(b)
    corners = edges[..., :2]  # [N, K, 4, 2]
    strip = cfg.obstacle_curb_offset[1] + cfg.obstacle_width[1]
    ok = torch.zeros_like(kept)
    for r in (0, 1):
        off = ((corners - c[:, r].view(-1, 1, 1, 2)) * n[:, r].view(-1, 1, 1, 2)).sum(-1)
        depth = 0.5 * w[:, r].view(-1, 1, 1) - off.abs()  # inward distance from the nearer curb
        same_side = (torch.sign(off) == torch.sign(off[..., :1])).all(-1)
        in_strip = (depth >= cfg.obstacle_curb_offset[0] - TOL).all(-1) & (
            depth <= strip + TOL
        ).all(-1)
        ok |= same_side & in_strip & b.road_mask[:, r : r + 1]
    assert ok[kept].all()


def test_same_seed_same_scenes_different_seed_different():
    cfg = SceneConfig()
    a, _ = make(cfg, 256, 5)
    b, _ = make(cfg, 256, 5)
    c, _ = make(cfg, 256, 6)
    for f in dataclasses.fields(SceneBatch):
        assert torch.equal(getattr(a, f.name), getattr(b, f.name)), f.name
    assert not torch.equal(a.start, c.start)
    assert not torch.equal(a.segments, c.segments)


def test_each_scene_takes_its_first_valid_rejection_round():
    # the rounds are computed in one batched pass; a scene whose first round is valid must keep
    # that round's poses however many rounds follow (the pose draws come first, round by round)
    cfg1 = SceneConfig(rounds=1, crossing_prob=1.0)
    one, _ = make(cfg1, 2000, 11)
    many, _ = make(dataclasses.replace(cfg1, rounds=8), 2000, 11)
    first_ok = one.route != ROUTE_STRAIGHT_ROAD  # a crossing without a valid pair falls back
    assert 0.3 < first_ok.float().mean() < 1.0  # both kinds of scene occur
    assert torch.equal(many.start[first_ok], one.start[first_ok])
    assert torch.equal(many.goal[first_ok], one.goal[first_ok])
    assert torch.equal(many.route[first_ok], one.route[first_ok])
    # later rounds rescue most of the scenes round 0 left without a pair
    rescued = (many.route != ROUTE_STRAIGHT_ROAD) & ~first_ok
    assert rescued.sum() > 0.5 * (~first_ok).sum()


def test_device_follows_generator_and_cuda():
    cfg = SceneConfig()
    params = sample_vehicle_params(VehicleConfig(), 8)
    b = generate_scenes(cfg, params)  # no generator: global RNG, params' device
    assert b.device.type == "cpu" and len(b) == 8
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    g = torch.Generator(device="cuda").manual_seed(0)
    params = sample_vehicle_params(VehicleConfig(), 64, generator=g, device="cuda")
    b = generate_scenes(cfg, params, generator=g)
    assert b.segments.is_cuda and b.start.is_cuda


def test_assign_overwrites_only_the_indexed_scenes():
    cfg = SceneConfig()
    big, _ = make(cfg, 10, 1)
    small, _ = make(cfg, 3, 2)
    # a copy of every field (SceneBatch.to on the tensors' own device returns the same tensors)
    before = SceneBatch(**{f.name: getattr(big, f.name).clone() for f in dataclasses.fields(big)})
    idx = torch.tensor([7, 0, 4])
    big.assign(idx, small)
    rest = torch.tensor([i for i in range(10) if i not in (7, 0, 4)])
    for f in dataclasses.fields(SceneBatch):
        new, old, src = getattr(big, f.name), getattr(before, f.name), getattr(small, f.name)
        assert torch.equal(new[idx], src), f.name
        assert torch.equal(new[rest], old[rest]), f.name
    # no start pose of one batch is in the other, so a write to the wrong scenes shows
    assert not (before.start[:, None] == small.start[None]).all(-1).any()


def test_no_obstacles_and_straight_only_configs():
    b, _ = make(SceneConfig(max_obstacles=0, crossing_prob=0.0), 100, 3)
    assert b.segments.shape[1] == CURB_SLOTS and not b.crossing.any()
    assert b.mask[:, :2].all() and not b.mask[:, 2:].any()
    b, _ = make(SceneConfig(obstacle_keep_prob=0.0), 100, 3)
    assert not b.mask[:, CURB_SLOTS:].any()


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("road_width", (-10.0, 18.0)),
        ("road_width", (18.0, 10.0)),
        ("crossing_prob", 1.5),
        ("crossing_prob", -0.1),
        ("obstacle_keep_prob", 2.0),
        ("rounds", 0),
        ("rounds", 2.5),
        ("max_obstacles", -1),
        ("crossing_angle", (0.0, 1.0)),
        ("goal_distance", (70.0, 25.0)),
        ("goal_distance", (25.0, 500.0)),
        ("obstacle_length", (0.0, 5.0)),
        ("obstacle_curb_offset", (0.0, 0.5)),
        ("obstacle_spacing", 5.0),
        ("curb_reach", 150.0),
        ("half_extent", -1.0),
        ("shoulder_gap", (-1.0, 1.0)),
        ("min_free_corridor", 9.0),
        ("min_free_corridor", 1.0),
        ("obstacle_intersection_clearance", 1.0),
    ],
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ConfigError, match=rf"scene\.{field}"):
        SceneConfig(**{field: value})


def test_departure_and_approach_lanes_are_free(batch):
    """No obstacle on the pose's half of its road from the footprint's rear to pose_zone_length
    ahead of the start's front / from pose_zone_length behind the goal's rear to its front."""
    cfg, b, params = batch
    edges, kept = obstacle_edges(b)
    corners = edges[..., :2]  # [N, K, 4, 2]
    c, d, n, _ = road_frames(b)
    rows = torch.arange(len(b))
    front = params["wheelbase"] + params["front_overhang"]
    rear = torch.maximum(
        params["rear_overhang"],
        params["kingpin_offset"] + params["trailer_wheelbase"] + params["trailer_rear_overhang"],
    )
    zone = cfg.pose_zone_length
    for pose, t0, t1 in ((b.start, -rear, front + zone), (b.goal, -rear - zone, front)):
        r = pose_road(b, pose)
        u = torch.stack((torch.cos(pose[:, 2]), torch.sin(pose[:, 2])), -1)
        ahead = ((corners - pose[:, None, None, :2]) * u[:, None, None]).sum(-1)  # [N, K, 4]
        overlap = (ahead.amax(-1) > t0[:, None]) & (ahead.amin(-1) < t1[:, None])
        side = ((corners - c[rows, r][:, None, None]) * n[rows, r][:, None, None]).sum(-1)
        pose_side = ((pose[:, :2] - c[rows, r]) * n[rows, r]).sum(-1)
        same_half = (torch.sign(side) == torch.sign(pose_side)[:, None, None]).all(-1)
        # an obstacle of this road has its first (front) edge across the road direction
        edge = corners[..., 1, :] - corners[..., 0, :]
        same_road = (edge * d[rows, r][:, None]).sum(-1).abs() < 1e-3 * edge.norm(dim=-1)
        assert not (kept & same_road & same_half & overlap).any()


# ---------------------------------------------------------------- route descriptors


def test_route_fields_shapes_and_dtypes(batch):
    _, b, _ = batch
    n = len(b)
    assert b.route.shape == (n,) and b.route.dtype == torch.int8
    for name in ("turn_angle", "crossing_angle", "start_road_width", "goal_road_width"):
        t = getattr(b, name)
        assert t.shape == (n,) and t.dtype == torch.float32 and torch.isfinite(t).all(), name
    assert b.goal_distance.shape == (n,) and torch.isfinite(b.goal_distance).all()
    assert set(b.route.unique().tolist()) <= {0, 1, 2, 3}
    assert ROUTE_NAMES[ROUTE_STRAIGHT_ROAD] == "straight road"
    assert ROUTE_NAMES[ROUTE_STRAIGHT_ON] == "straight on"
    assert (ROUTE_NAMES[ROUTE_LEFT], ROUTE_NAMES[ROUTE_RIGHT]) == ("left", "right")


def expected_routes(b: SceneBatch) -> tuple[np.ndarray, np.ndarray]:
    """Route [N] and signed turn angle [N] (float64, rad) from the start and goal poses only."""
    start, goal = b.start.double().numpy(), b.goal.double().numpy()
    u_s = np.stack((np.cos(start[:, 2]), np.sin(start[:, 2])), -1)
    u_g = np.stack((np.cos(goal[:, 2]), np.sin(goal[:, 2])), -1)
    cross = u_s[:, 0] * u_g[:, 1] - u_s[:, 1] * u_g[:, 0]
    dot = (u_s * u_g).sum(-1)
    turn = np.arctan2(cross, dot)
    # no crossing on this scene: one road, so start and goal are parallel (and the same way)
    one_road = ~b.crossing.numpy()
    route = np.where(cross > 0, ROUTE_LEFT, ROUTE_RIGHT)
    route = np.where(np.abs(cross) < 1e-6, ROUTE_STRAIGHT_ON, route)
    route = np.where(one_road, ROUTE_STRAIGHT_ROAD, route)
    return route, turn


def test_route_matches_the_poses(batch):
    _, b, _ = batch
    route, turn = expected_routes(b)
    np.testing.assert_array_equal(b.route.numpy(), route)
    np.testing.assert_allclose(b.turn_angle.double().numpy(), turn, atol=1e-5)
    # straight road and straight on: identical headings, so the turn is exactly 0
    ahead = (b.route == ROUTE_STRAIGHT_ROAD) | (b.route == ROUTE_STRAIGHT_ON)
    assert torch.equal(b.start[ahead, 2], b.goal[ahead, 2])
    assert (b.turn_angle[ahead] == 0).all()
    assert (b.route[~b.crossing] == ROUTE_STRAIGHT_ROAD).all()
    assert (b.route[b.crossing] != ROUTE_STRAIGHT_ROAD).all()
    # straight on stays on its road; a turn changes road
    rs, rg = pose_road(b, b.start), pose_road(b, b.goal)
    assert ((rs == rg) == ahead).all()


def test_turns_have_the_expected_sign_and_side(batch):
    _, b, _ = batch
    left, right = b.route == ROUTE_LEFT, b.route == ROUTE_RIGHT
    assert (b.turn_angle[left] > 0).all() and (b.turn_angle[right] < 0).all()
    assert (b.turn_angle.abs() < math.pi).all()  # never a U-turn
    # the goal lies on the side of the start's line of travel that the turn names
    u_s = torch.stack((torch.cos(b.start[:, 2]), torch.sin(b.start[:, 2])), -1)
    rel = b.goal[:, :2] - b.start[:, :2]
    side = u_s[:, 0] * rel[:, 1] - u_s[:, 1] * rel[:, 0]  # > 0: goal left of the start's line
    assert (side[left] > 0).all() and (side[right] < 0).all()


def test_crossing_angle_widths_and_goal_distance(batch):
    cfg, b, _ = batch
    x = b.crossing
    h = b.roads[..., 2].double()
    between = torch.remainder(h[:, 1] - h[:, 0], 2 * math.pi)  # road 0 -> road 1, CCW
    np.testing.assert_allclose(b.crossing_angle[x].double(), between[x], atol=1e-5)
    assert (b.crossing_angle[~x] == 0).all()
    lo, hi = cfg.crossing_angle
    assert (b.crossing_angle[x] >= lo - 1e-6).all() and (b.crossing_angle[x] <= hi + 1e-6).all()
    # a turn is the crossing angle or its supplement
    turns = (b.route == ROUTE_LEFT) | (b.route == ROUTE_RIGHT)
    a, t = b.crossing_angle[turns].double(), b.turn_angle[turns].double().abs()
    assert (torch.minimum((t - a).abs(), (t - (math.pi - a)).abs()) < 1e-5).all()
    # widths of the roads the poses are aligned with
    rows = torch.arange(len(b))
    for width, pose in ((b.start_road_width, b.start), (b.goal_road_width, b.goal)):
        assert torch.equal(width, b.roads[rows, pose_road(b, pose), 3])
        assert (width >= cfg.road_width[0]).all() and (width <= cfg.road_width[1]).all()
    assert torch.equal(b.start_road_width[~x], b.goal_road_width[~x])
    dist = np.linalg.norm(b.goal[:, :2].double().numpy() - b.start[:, :2].double().numpy(), axis=-1)
    np.testing.assert_allclose(b.goal_distance.double().numpy(), dist, atol=TOL)
    lo, hi = cfg.goal_distance
    assert (b.goal_distance >= lo - TOL).all() and (b.goal_distance <= hi + TOL).all()


def test_route_frequencies(default_batch):
    """All four routes occur, in proportions that fit the generator (measured on 10,000 scenes:
    30 % straight road, 33 % straight on, 12 % left, 25 % right; 31 / 30 / 16 / 23 % without the
    left-turn exit rule)."""
    cfg, b, _ = default_batch
    frac = torch.bincount(b.route.long(), minlength=4).double() / len(b)
    straight_road, straight_on, left, right = frac.tolist()
    assert abs(straight_road + straight_on + left + right - 1.0) < 1e-9
    crossings = 1.0 - straight_road
    assert abs(crossings - cfg.crossing_prob) < 0.03  # few fallbacks at the default rounds
    # each exit of a crossing is picked with probability 1/3 per round; rejection (the goal
    # distance must fit on the arm, and the left-turn exit rule) makes them unequal (left turns
    # are the rarest)
    for f in (straight_on, left, right):
        assert 0.15 * crossings < f < 0.6 * crossings
    # the one-round config falls back to straight roads often: still all four routes occur
    b1, _ = make(SceneConfig(rounds=1), 2000, 7)
    counts = torch.bincount(b1.route.long(), minlength=4)
    assert (counts > 100).all()
    assert counts[ROUTE_STRAIGHT_ROAD] > (1 - cfg.crossing_prob) * 2000 + 100  # fallbacks


def exit_room(b: SceneBatch, trailer_wheelbase: torch.Tensor) -> np.ndarray:
    """[N] goal-to-corner distance / trailer wheelbase - tan(|turn| / 2), in float64 from the
    poses (the corner solved as a 2x2 system; NaN where the lanes are parallel)."""
    s, g = b.start.double().numpy(), b.goal.double().numpy()
    u = np.stack((np.cos(s[:, 2]), np.sin(s[:, 2])), -1)
    v = np.stack((np.cos(g[:, 2]), np.sin(g[:, 2])), -1)
    out = np.full(len(b), np.nan)
    for i in np.flatnonzero(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]) > 1e-6):
        # s + t u = g - k v  ->  [u, v] (t, k) = g - s
        t, k = np.linalg.solve(np.stack((u[i], v[i]), -1), g[i, :2] - s[i, :2])
        turn = abs(math.atan2(math.sin(g[i, 2] - s[i, 2]), math.cos(g[i, 2] - s[i, 2])))
        out[i] = k / float(trailer_wheelbase[i]) - math.tan(0.5 * turn)
    return out


def test_left_turns_leave_the_trailer_room_to_straighten(default_batch):
    """Every left turn's goal lies (tan(turn / 2) + left_turn_exit) trailer wheelbases past the
    lane corner; right turns are not limited (some fall below the bound)."""
    cfg, b, params = default_batch
    room = exit_room(b, params["trailer_wheelbase"])
    left, right = (b.route == ROUTE_LEFT).numpy(), (b.route == ROUTE_RIGHT).numpy()
    assert left.sum() > 1000
    assert (room[left] >= cfg.left_turn_exit - 1e-4).all()
    assert (room[right] < cfg.left_turn_exit).sum() > 100


def test_the_exit_rule_only_replaces_the_left_turns_it_rejects():
    """The rule draws no random numbers: with it off, every scene it would not reject comes
    out bit for bit the same; the ones it rejects are drawn again and then satisfy it."""
    on, off = SceneConfig(), SceneConfig(left_turn_exit=0.0)
    b_on, params = make(on, 4000, 5)
    b_off, _ = make(off, 4000, 5)
    room = exit_room(b_off, params["trailer_wheelbase"])
    rejected = torch.from_numpy((b_off.route == ROUTE_LEFT).numpy() & (room < on.left_turn_exit))
    assert 40 < int(rejected.sum()) < 400  # about 3 % of scenes at the defaults
    for f in dataclasses.fields(SceneBatch):
        a, c = getattr(b_on, f.name), getattr(b_off, f.name)
        assert torch.equal(a[~rejected], c[~rejected]), f.name
    assert not torch.equal(b_on.start[rejected], b_off.start[rejected])
    again = exit_room(b_on, params["trailer_wheelbase"])[rejected.numpy()]
    left_again = (b_on.route[rejected] == ROUTE_LEFT).numpy()
    assert (again[left_again] >= on.left_turn_exit - 1e-4).all()
