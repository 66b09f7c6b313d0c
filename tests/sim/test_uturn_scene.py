"""Turnaround scenes (truckrl/tasks/uturn/scene.py): every rule of the module doc on 10,000 scenes,
checked with geometry written here (numpy, separating axes). The driven turnaround is in
tests/rl/test_uturn_driver.py."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.collision import contour_collides
from truckrl.sim.geometry import KIND_CURB
from truckrl.sim.vehicle import (
    VehicleConfig,
    kinematics_step,
    sample_vehicle_params,
    vehicle_outline,
)
from truckrl.tasks.uturn.scene import (
    DEAD_END_SLOT,
    INFO_KEYS,
    NUM_SEGMENTS,
    UTurnSceneConfig,
    generate_uturn_scenes,
)

N = 10_000
TOL = 1e-3  # [m] float32 round-off at coordinates of O(100 m)


def make(cfg: UTurnSceneConfig, n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    params = sample_vehicle_params(VehicleConfig(), n, generator=g, reverse=True)
    return generate_uturn_scenes(cfg, params, generator=g), params


@pytest.fixture(scope="module")
def batch():
    cfg = UTurnSceneConfig()
    sc, params = make(cfg, N, 2024)
    p = {k: v.double().numpy() for k, v in params.items()}
    return cfg, sc, p


# ----------------------------------------------------------------------------- independent geometry
def footprint(pose: np.ndarray, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Tractor and trailer rectangles ``[n, 4, 2]`` at articulation 0, from the parameters alone.

    Tractor: ``wheelbase + front_overhang`` ahead of the rear axle, ``rear_overhang`` behind.
    Trailer (aligned): its axle ``kingpin_offset + trailer_wheelbase`` behind the tractor axle,
    ``trailer_wheelbase + trailer_front_overhang`` ahead of its axle, ``trailer_rear_overhang``
    behind.
    """
    x, y, h = pose[:, 0], pose[:, 1], pose[:, 2]
    u = np.stack((np.cos(h), np.sin(h)), -1)
    v = np.stack((-np.sin(h), np.cos(h)), -1)

    def rect(ahead, behind, half):
        c = np.stack((x, y), -1)
        pts = [
            c + a[:, None] * u + s * half[:, None] * v
            for a, s in ((ahead, -1), (ahead, 1), (-behind, 1), (-behind, -1))
        ]
        return np.stack(pts, 1)

    tractor = rect(
        p["wheelbase"] + p["front_overhang"], p["rear_overhang"], 0.5 * p["tractor_width"]
    )
    axle = p["kingpin_offset"] + p["trailer_wheelbase"]
    trailer = rect(
        p["trailer_wheelbase"] + p["trailer_front_overhang"] - axle,
        axle + p["trailer_rear_overhang"],
        0.5 * p["trailer_width"],
    )
    return tractor, trailer


def sat_gap(rect: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Separating-axis gap [m] between convex rectangles ``[n, 4, 2]`` and segments
    ``[n, E, 4]``: the largest separation over the candidate axes (rectangle edge normals and
    the segment normal); > 0 means disjoint, <= 0 overlapping or touching. Shape ``[n, E]``."""
    a, b = seg[..., :2], seg[..., 2:]
    d = b - a
    axes = [rect[:, 1] - rect[:, 0], rect[:, 2] - rect[:, 1]]  # rectangle edge directions
    axes = [np.broadcast_to(ax[:, None], d.shape) for ax in axes]
    axes.append(np.stack((-d[..., 1], d[..., 0]), -1))  # segment normal
    gap = np.full(d.shape[:2], -np.inf)
    for ax in axes:
        norm = np.linalg.norm(ax, axis=-1, keepdims=True)
        ax = ax / np.where(norm > 0, norm, 1.0)
        pr = np.einsum("nkc,nec->nek", rect, ax)  # rectangle corners projected
        pa, pb = (a * ax).sum(-1), (b * ax).sum(-1)
        sep = np.maximum(np.minimum(pa, pb) - pr.max(-1), pr.min(-1) - np.maximum(pa, pb))
        gap = np.maximum(gap, sep)
    return gap


def local(points: np.ndarray, info: dict) -> np.ndarray:
    """World points ``[n, ..., 2]`` in the scene frame (mouth centre, road heading)."""
    o = np.stack((info["mouth_x"], info["mouth_y"]), -1)
    h = info["road_heading"]
    shape = (-1,) + (1,) * (points.ndim - 2)
    c, s = np.cos(h).reshape(shape), np.sin(h).reshape(shape)
    q = points - o.reshape(o.shape[0], *([1] * (points.ndim - 2)), 2)
    return np.stack((c * q[..., 0] + s * q[..., 1], -s * q[..., 0] + c * q[..., 1]), -1)


# ----------------------------------------------------------------------------- rules on 10,000 scenes
def test_layout_shapes_and_kinds(batch):
    cfg, sc, _ = batch
    assert sc.segments.shape == (N, NUM_SEGMENTS, 4) and sc.mask.shape == (N, NUM_SEGMENTS)
    assert (sc.kind == KIND_CURB).all()
    assert torch.equal(sc.mask[:, DEAD_END_SLOT], sc.info["dead_end"].bool())
    assert sc.mask[:, :DEAD_END_SLOT].all()
    assert (sc.segments[~sc.mask] == 0).all()
    assert set(sc.info) == set(INFO_KEYS)
    assert all(v.shape == (N,) for v in sc.info.values())


def test_start_and_goal_footprints_collision_free(batch):
    cfg, sc, p = batch
    seg = sc.segments.double().numpy()
    for pose in (sc.start, sc.goal):
        for rect in footprint(pose.double().numpy(), p):
            gap = sat_gap(rect, seg)
            gap = np.where(sc.mask.numpy(), gap, np.inf)
            assert gap.min() > 0.05, f"a footprint comes within {gap.min():.3f} m of a segment"
        # and the simulator's own test agrees
        pose4 = torch.cat((pose, torch.zeros(N, 1)), -1)
        params = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in p.items()}
        assert not contour_collides(vehicle_outline(pose4, params), sc.segments, sc.mask).any()


def test_footprints_on_the_road_in_their_lanes(batch):
    """Both trucks lie between the curbs, in their own half (start right, goal left), before the
    mouth's near chamfer and within the road's ends."""
    cfg, sc, p = batch
    info = {k: v.double().numpy() for k, v in sc.info.items()}
    half = 0.5 * info["road_width"][:, None]
    near = -(0.5 * info["branch_width"] / np.sin(info["branch_angle"]))
    for pose, lane in ((sc.start, -1.0), (sc.goal, 1.0)):
        for rect in footprint(pose.double().numpy(), p):
            q = local(rect, info)
            assert (np.abs(q[..., 1]) <= half + TOL).all()
            assert (lane * q[..., 1] >= -TOL).all(), "a truck leaves its half of the road"
            assert (q[..., 0] <= near[:, None] + TOL).all(), "a truck reaches into the mouth"
            assert (q[..., 0] >= -cfg.half_extent + 50.0).all(), "LiDAR range past the road end"


def test_goal_behind_start_facing_back(batch):
    _, sc, _ = batch
    s, g = sc.start.double(), sc.goal.double()
    u = torch.stack((s[:, 2].cos(), s[:, 2].sin()), -1)
    d = g[:, :2] - s[:, :2]
    assert ((d * u).sum(-1) <= TOL).all(), "the goal is not behind the start"
    assert ((u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0]) > 0).all(), "the goal is not in the left lane"
    turn = torch.remainder(g[:, 2] - s[:, 2], 2 * math.pi)
    assert torch.allclose(turn, torch.full_like(turn, math.pi), atol=1e-5)
    assert torch.allclose(sc.info["goal_distance"].double(), d.norm(dim=-1), atol=TOL)


def test_forward_uturn_criterion(batch):
    """road and branch narrower than 2 L_t / tan(max_steer) + w_t by at least forward_margin."""
    cfg, sc, p = batch
    need = 2.0 * p["wheelbase"] / np.tan(p["max_steer"]) + p["tractor_width"]
    for key in ("road_width", "branch_width"):
        w = sc.info[key].double().numpy()
        assert (w <= need - cfg.forward_margin + TOL).all(), key
    assert np.allclose(sc.info["forward_width"].double().numpy(), need, atol=TOL)


def test_forward_uturn_bound_is_real():
    """The bound of the criterion, driven: a full-lock forward U-turn of a tractor-trailer (the
    tightest forward loop) moves the rear axle sideways by 2 R, so the tractor body spans at
    least 2 R + w_t across the road; every such loop is wider than a generated road."""
    g = torch.Generator().manual_seed(5)
    params = sample_vehicle_params(VehicleConfig(), 500, generator=g)
    pose = torch.zeros(500, 4)
    steer = params["max_steer"]
    y_hi = torch.zeros(500)
    radius = params["wheelbase"] / torch.tan(steer)
    done = torch.zeros(500, dtype=torch.bool)
    for _ in range(4000):
        pose, _ = kinematics_step(pose, torch.full((500,), 1.0), steer, params, 0.01)
        done = done | (pose[:, 2] < 0)  # heading wrapped past pi
        y = torch.where(done, y_hi, pose[:, 1])
        y_hi = torch.maximum(y_hi, y)
    assert done.all()
    assert torch.allclose(y_hi, 2 * radius, rtol=0.01)
    sc = generate_uturn_scenes(UTurnSceneConfig(), params, g)
    assert (sc.info["road_width"] < y_hi + params["tractor_width"] - 0.3).all()


def test_branch_takes_the_truck(batch):
    """Depth >= truck length, width >= widest body + 2 clearance; and the segments really have
    that width (side walls) and depth (end wall to the curb line)."""
    cfg, sc, p = batch
    length = (
        p["wheelbase"]
        + p["front_overhang"]
        + np.maximum(
            p["rear_overhang"],
            p["kingpin_offset"] + p["trailer_wheelbase"] + p["trailer_rear_overhang"],
        )
    )
    widest = np.maximum(p["tractor_width"], p["trailer_width"])
    info = {k: v.double().numpy() for k, v in sc.info.items()}
    assert np.allclose(info["truck_length"], length, atol=TOL)
    assert (info["branch_depth"] >= cfg.branch_depth_factor[0] * length - TOL).all()
    assert (info["branch_depth"] >= length).all()
    assert (info["branch_width"] >= widest + 2 * cfg.branch_side_clearance - TOL).all()
    seg = sc.segments.double().numpy()
    w0, w1, end, curb = seg[:, 5], seg[:, 6], seg[:, 7], seg[:, 1]
    d = w0[:, 2:] - w0[:, :2]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    q = w1[:, :2] - w0[:, :2]
    across = np.abs(d[:, 0] * q[:, 1] - d[:, 1] * q[:, 0])
    assert np.allclose(across, info["branch_width"], atol=1e-2)
    c = curb[:, 2:] - curb[:, :2]
    c /= np.linalg.norm(c, axis=-1, keepdims=True)
    for pt in (end[:, :2], end[:, 2:]):
        r = pt - curb[:, :2]
        depth = np.abs(c[:, 0] * r[:, 1] - c[:, 1] * r[:, 0])
        assert np.allclose(depth, info["branch_depth"], atol=1e-2)


def test_dead_end_leaves_room_to_pull_past(batch):
    cfg, sc, _ = batch
    info = {k: v.double().numpy() for k, v in sc.info.items()}
    dead = info["dead_end"] > 0.5
    assert 0.2 < dead.mean() < 0.4  # dead_end_prob 0.3
    wall = sc.segments[:, DEAD_END_SLOT].double().numpy().reshape(N, 2, 2)
    x_wall = local(wall, info)[..., 0]
    far = 0.5 * info["branch_width"] / np.sin(info["branch_angle"])  # far wall at the curb
    beyond = x_wall[dead].min(-1) - far[dead]
    assert (beyond >= cfg.dead_end_gap[0] * info["truck_length"][dead]).all()


def test_metadata_within_range(batch):
    cfg, sc, _ = batch
    info = {k: v.double().numpy() for k, v in sc.info.items()}
    assert (info["road_width"] <= cfg.road_width[1] + TOL).all()
    assert (info["road_width"] >= 4.0).all()
    assert (info["branch_width"] <= cfg.branch_width[1] + TOL).all()
    assert set(np.unique(info["branch_side"])) == {-1.0, 1.0}
    assert np.array_equal(info["branch_left"], (info["branch_side"] > 0).astype(float))
    assert 0.45 < info["branch_left"].mean() < 0.55
    lo, hi = cfg.branch_angle
    assert ((info["branch_angle"] >= lo - 1e-6) & (info["branch_angle"] <= hi + 1e-6)).all()
    assert (
        (info["start_gap"] >= cfg.start_gap[0] - TOL)
        & (info["start_gap"] <= cfg.start_gap[1] + TOL)
    ).all()
    assert np.allclose(info["road_heading"], sc.start[:, 2].double().numpy(), atol=1e-5), (
        "the frame's heading is the start's"
    )
    assert (info["goal_distance"] > 0).all() and (info["goal_distance"] < 40.0).all()


def test_same_seed_same_scenes_and_bad_config():
    a, _ = make(UTurnSceneConfig(), 64, 3)
    b, _ = make(UTurnSceneConfig(), 64, 3)
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, dict):
            assert all(torch.equal(x[k], y[k]) for k in x)
        else:
            assert torch.equal(x, y)
    with pytest.raises(ConfigError, match="env.task.scene.branch_angle"):
        UTurnSceneConfig(branch_angle=(0.2, 1.5))
    with pytest.raises(ConfigError, match="env.task.scene.branch_depth_factor"):
        UTurnSceneConfig(branch_depth_factor=(0.8, 1.2))
    with pytest.raises(ConfigError, match="half_extent"):
        UTurnSceneConfig(half_extent=50.0)
