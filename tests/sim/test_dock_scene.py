"""Dock scene generator: the rules of truckrl/tasks/dock/scene.py on 10,000 scenes, checked in
numpy with independent geometry (truck rectangles from the vehicle parameters, exact
segment-rectangle distances, segments taken back into the dock frame)."""

import dataclasses
import math
import time

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.geometry import KIND_CURB, KIND_OBSTACLE
from truckrl.sim.vehicle import VehicleConfig, sample_vehicle_params
from truckrl.tasks.dock.scene import (
    DOCK_INFO_KEYS,
    START_APRON,
    DockSceneConfig,
    generate_dock_scenes,
)

N = 10_000
TOL = 1e-3  # [m] float32 round-off at coordinates of O(100 m)
CFG = DockSceneConfig()


def make(cfg: DockSceneConfig, n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    params = sample_vehicle_params(VehicleConfig(), n, generator=g, reverse=True)
    return generate_dock_scenes(cfg, params, generator=g), params


@pytest.fixture(scope="module")
def batch():
    scenes, params = make(CFG, N, 0)
    p = {k: v.double().numpy() for k, v in params.items()}
    # everything in the dock frame: origin = frame[:2], y axis along frame[2]
    f = scenes.frame.double().numpy()
    seg = scenes.segments.double().numpy().reshape(N, -1, 2, 2)
    return {
        "scenes": scenes,
        "p": p,
        "frame": f,
        "seg": to_dock(seg, f).reshape(N, -1, 4),
        "mask": scenes.mask.numpy(),
        "start": pose_to_dock(scenes.start.double().numpy(), f),
        "goal": pose_to_dock(scenes.goal.double().numpy(), f),
        "info": {k: v.double().numpy() for k, v in scenes.info.items()},
    }


def to_dock(xy, f):
    """World points [N, ..., 2] into the dock frame (x along the dock face, y out of it)."""
    shape = (-1,) + (1,) * (xy.ndim - 2)
    d = xy - f[:, :2].reshape(*shape, 2)
    h = f[:, 2].reshape(shape)
    # y axis along h: x axis along h - pi/2
    ex = np.stack((np.sin(h), -np.cos(h)), -1)
    ey = np.stack((np.cos(h), np.sin(h)), -1)
    return np.stack(((d * ex).sum(-1), (d * ey).sum(-1)), -1)


def pose_to_dock(pose, f):
    xy = to_dock(pose[:, :2], f)
    h = np.angle(np.exp(1j * (pose[:, 2] - f[:, 2] + math.pi / 2)))
    return np.concatenate((xy, h[:, None]), -1)


def rect(cx, cy, h, front, rear, half):
    """Corners [N, 4, 2] of a rectangle spanning front/rear along h and +-half across."""
    u = np.stack((np.cos(h), np.sin(h)), -1)
    v = np.stack((-np.sin(h), np.cos(h)), -1)
    c = np.stack((cx, cy), -1)
    out = [
        c + a[:, None] * u + b[:, None] * v
        for a, b in ((front, half), (front, -half), (-rear, -half), (-rear, half))
    ]
    return np.stack(out, 1)


def truck_rects(pose, p):
    """Tractor and trailer corners at articulation 0 for ``pose [N, 3]`` (x, y, heading)."""
    x, y, h = pose.T
    tractor = rect(
        x, y, h, p["wheelbase"] + p["front_overhang"], p["rear_overhang"], p["tractor_width"] / 2
    )
    back = p["kingpin_offset"] + p["trailer_wheelbase"]
    ax, ay = x - back * np.cos(h), y - back * np.sin(h)
    trailer = rect(
        ax,
        ay,
        h,
        p["trailer_wheelbase"] + p["trailer_front_overhang"],
        p["trailer_rear_overhang"],
        p["trailer_width"] / 2,
    )
    return tractor, trailer


def point_seg_dist(pt, a, b):
    ab = b - a
    t = np.clip(((pt - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(pt - (a + t[..., None] * ab), axis=-1)


def rect_seg_distance(corners, seg, mask):
    """Smallest distance [N] from a filled rectangle [N, 4, 2] to the valid segments [N, E, 4]
    (0 when one touches or enters it); +inf with no valid segment."""
    a, b = seg[..., None, :2], seg[..., None, 2:]  # [N, E, 1, 2]
    c0 = corners[:, None]  # [N, 1, 4, 2]
    c1 = np.roll(corners, -1, axis=1)[:, None]
    d = np.minimum(point_seg_dist(c0, a, b), point_seg_dist(a, c0, c1))
    d = np.minimum(d, point_seg_dist(b, c0, c1)).min(-1)  # [N, E]

    def cross(o, p, q):
        return (p[..., 0] - o[..., 0]) * (q[..., 1] - o[..., 1]) - (p[..., 1] - o[..., 1]) * (
            q[..., 0] - o[..., 0]
        )

    proper = (cross(a, b, c0) * cross(a, b, c1) < 0) & (cross(c0, c1, a) * cross(c0, c1, b) < 0)
    # an endpoint inside the rectangle: on the inner side of all 4 edges
    inside = (cross(c0, c1, a) > 0).all(-1) | (cross(c0, c1, a) < 0).all(-1)
    d = np.where(proper.any(-1) | inside, 0.0, d)
    return np.where(mask, d, np.inf).min(-1)


def clearance(pose, p, seg, mask):
    tractor, trailer = truck_rects(pose, p)
    return np.minimum(rect_seg_distance(tractor, seg, mask), rect_seg_distance(trailer, seg, mask))


def test_distance_oracle_can_fail():
    """The oracle itself: a segment through a rectangle is at 0, one beside it at its gap."""
    corners = rect(np.zeros(2), np.zeros(2), np.zeros(2), np.ones(2), np.ones(2), np.ones(2))
    seg = np.array([[[-5.0, 0.0, 5.0, 0.0]], [[-5.0, 1.5, 5.0, 1.5]]])
    np.testing.assert_allclose(rect_seg_distance(corners, seg, np.ones((2, 1), bool)), [0.0, 0.5])
    inner = np.array([[[-0.2, 0.0, 0.2, 0.0]], [[-0.2, 3.0, 0.2, 3.0]]])
    np.testing.assert_allclose(rect_seg_distance(corners, inner, np.ones((2, 1), bool)), [0.0, 2.0])


def test_layout_and_kinds(batch):
    s, seg, mask = batch["scenes"], batch["seg"], batch["mask"]
    B, info = CFG.max_bays, batch["info"]
    assert s.segments.shape == (N, CFG.num_segments, 4) and CFG.num_segments == 3 + 5 * B
    assert torch.isfinite(s.segments).all() and (s.segments[~s.mask] == 0).all()
    assert (s.kind[:, : 3 + B] == KIND_CURB).all() and (s.kind[:, 3 + B :] == KIND_OBSTACLE).all()
    # dock face on y = 0 and far curb on y = apron_depth, both spanning the row
    np.testing.assert_allclose(seg[:, 0, [1, 3]], 0.0, atol=TOL)
    np.testing.assert_allclose(
        seg[:, 1, [1, 3]], np.repeat(info["apron_depth"][:, None], 2, 1), atol=TOL
    )
    # walls: num_bays + 1 of them, W apart, from the dock face to bay_depth, target centred
    W, nb = info["bay_width"], info["num_bays"].astype(int)
    walls = seg[:, 2 : 3 + B]
    assert (mask[:, 2 : 3 + B].sum(1) == nb + 1).all()
    k = np.arange(B + 1)[None]
    x_expect = (k - info["target_bay"][:, None] - 0.5) * W[:, None]
    ok = mask[:, 2 : 3 + B]
    assert np.abs(np.where(ok, walls[..., 0] - x_expect, 0)).max() < TOL
    assert np.abs(np.where(ok, walls[..., 2] - x_expect, 0)).max() < TOL
    assert (
        np.abs(np.where(ok, walls[..., 3] - walls[..., 1] - info["bay_depth"][:, None], 0)).max()
        < TOL
    )


def test_target_bay_is_free(batch):
    """No valid segment enters the target bay (|x| < W/2, 0 < y < bay_depth), shrunk by TOL:
    its walls lie on its sides and the dock face on its back."""
    info = batch["info"]
    half, depth = info["bay_width"] / 2 - TOL, info["bay_depth"] - TOL
    z = np.zeros(N)
    bay = rect(z, z + TOL, z + math.pi / 2, depth - TOL, z, half)  # y from TOL to depth
    d = rect_seg_distance(bay, batch["seg"], batch["mask"])
    assert (d > 0).all()


def test_goal_at_the_dock_face_and_clear(batch):
    p, goal, info = batch["p"], batch["goal"], batch["info"]
    back = p["kingpin_offset"] + p["trailer_wheelbase"] + p["trailer_rear_overhang"]
    # heading along the bay axis (+y), trailer rear-centre dock_gap in front of the face, centred
    np.testing.assert_allclose(goal[:, 2], math.pi / 2, atol=1e-4)
    np.testing.assert_allclose(goal[:, 0], 0.0, atol=TOL)
    np.testing.assert_allclose(goal[:, 1] - back, CFG.dock_gap, atol=TOL)
    gap = clearance(goal, p, batch["seg"], batch["mask"])
    # nearest: the dock face (dock_gap) or a wall ((W - width) / 2 >= 0.45 m by default)
    widest = np.maximum(p["tractor_width"], p["trailer_width"])
    expect = np.minimum(CFG.dock_gap, (info["bay_width"] - widest) / 2)
    assert (gap >= expect - TOL).all()
    assert (gap > 0.1).all()


def test_start_on_the_apron_and_clear(batch):
    p, start, info = batch["p"], batch["start"], batch["info"]
    tractor, trailer = truck_rects(start, p)
    y = np.concatenate((tractor, trailer), 1)[..., 1]
    assert (y.min(1) >= info["bay_depth"] + CFG.start_clearance - TOL).all()
    assert (y.max(1) <= info["apron_depth"] - CFG.start_clearance + TOL).all()
    gap = clearance(start, p, batch["seg"], batch["mask"])
    assert (gap >= CFG.start_clearance - TOL).all()
    # pulled forward: the trailer behind the tractor, heading within the configured angle of
    # the dock face direction (clamped to fit the apron, never beyond)
    along = np.abs(np.cos(start[:, 2]))
    assert (along >= math.cos(max(abs(a) for a in CFG.start_angle)) - 1e-4).all()
    alpha = np.arcsin(np.sin(start[:, 2]))  # + = nose away from the dock
    assert (alpha >= CFG.start_angle[0] - 1e-4).all() and (alpha <= CFG.start_angle[1] + 1e-4).all()
    assert (alpha > 0.3).mean() > 0.1  # angled starts exist


def test_pulled_out_goal_is_clear(batch):
    """The start curriculum's claim: the goal truck pulled straight out by pull_room is clear."""
    goal, info = batch["goal"].copy(), batch["info"]
    assert (info["pull_room"] >= 0).all()
    pulled = goal.copy()
    pulled[:, 1] += info["pull_room"]
    gap = clearance(pulled, batch["p"], batch["seg"], batch["mask"])
    assert (gap >= 0.1).all()
    # and the claim is tight: 0.1 m beyond start_clearance further the truck hits the far curb
    k = slice(0, 1000)
    beyond = goal[k].copy()
    beyond[:, 1] += info["pull_room"][k] + CFG.start_clearance + 0.1
    p = {key: v[k] for key, v in batch["p"].items()}
    assert (clearance(beyond, p, batch["seg"][k], batch["mask"][k]) == 0).all()


def test_metadata(batch):
    info, seg, mask, p = batch["info"], batch["seg"], batch["mask"], batch["p"]
    assert set(batch["scenes"].info) == set(DOCK_INFO_KEYS)
    assert all(v.shape == (N,) for v in batch["scenes"].info.values())
    W, nb, t = info["bay_width"], info["num_bays"], info["target_bay"]
    assert (W >= 3.5 - 1e-5).all() and (W <= 4.5 + 1e-5).all()
    assert set(np.unique(nb)) == set(range(5, 10))
    assert (t >= 0).all() and (t < nb).all()
    assert (info["start_kind"] == START_APRON).all()
    # recount the parked trailers from the segments: one rectangle per occupied bay
    B = CFG.max_bays
    park = seg[:, 3 + B :].reshape(N, B, 4, 4)
    pmask = mask[:, 3 + B :].reshape(N, B, 4).all(-1)
    assert (pmask.sum(1) == info["occupied_bays"]).all()
    cx = park[..., [0, 2]].mean((-1, -2))  # rectangle centre x [N, B]
    bay_of = np.rint(cx / W[:, None])  # offset from the target in bays
    assert (np.where(pmask, bay_of, 9) != 0).all()  # never in the target bay
    nbrs = (pmask & (np.abs(bay_of) == 1)).sum(1)
    assert (nbrs == info["neighbours_occupied"]).all()
    assert set(np.unique(nbrs)) == {0, 1, 2}
    occ = info["occupied_bays"] / (nb - 1)
    assert abs(occ.mean() - CFG.occupied_prob) < 0.02
    # start descriptors recomputed from the start pose
    start = batch["start"]
    back = p["kingpin_offset"] + p["trailer_wheelbase"] + p["trailer_rear_overhang"]
    rear = start[:, :2] - back[:, None] * np.stack((np.cos(start[:, 2]), np.sin(start[:, 2])), -1)
    np.testing.assert_allclose(info["start_distance"], rear[:, 1], atol=TOL)
    drive = np.sign(np.cos(start[:, 2]))
    np.testing.assert_allclose(info["start_lateral_offset"], drive * rear[:, 0], atol=TOL)
    lo, hi = CFG.start_lateral_offset
    assert (info["start_lateral_offset"] >= lo - TOL).all()
    assert (info["start_lateral_offset"] <= hi + TOL).all()
    goal_rear = np.stack((np.zeros(N), np.full(N, CFG.dock_gap)), -1)
    np.testing.assert_allclose(
        info["start_goal_distance"], np.linalg.norm(rear - goal_rear, axis=-1), atol=TOL
    )
    rel = np.angle(np.exp(1j * (start[:, 2] - math.pi / 2)))
    np.testing.assert_allclose(np.cos(info["start_heading"] - rel), 1.0, atol=1e-6)
    assert (np.abs(np.abs(info["start_heading"]) - math.pi / 2) <= 0.53).all()
    lo, hi = CFG.apron_depth
    assert (info["apron_depth"] >= lo - TOL).all() and (info["apron_depth"] <= hi + TOL).all()
    for k in ("pull_draw", "apron_draw"):
        assert (info[k] >= 0).all() and (info[k] < 1).all() and abs(info[k].mean() - 0.5) < 0.02


def test_seeded_and_fast():
    a, _ = make(CFG, 64, 5)
    b, _ = make(CFG, 64, 5)
    c, _ = make(CFG, 64, 6)
    assert torch.equal(a.segments, b.segments) and torch.equal(a.start, b.start)
    assert not torch.equal(a.segments, c.segments)
    g = torch.Generator().manual_seed(0)
    params = sample_vehicle_params(VehicleConfig(), 1024, generator=g, reverse=True)
    t0 = time.perf_counter()
    generate_dock_scenes(CFG, params, generator=g)
    assert time.perf_counter() - t0 < 1.0  # batched: far below a second


def test_config_checks():
    with pytest.raises(ConfigError, match="parked_lateral_jitter"):
        DockSceneConfig(parked_lateral_jitter=0.6)
    with pytest.raises(ConfigError, match="env.task.scene.bay_width"):
        DockSceneConfig(bay_width=(4.0, 3.0))
    with pytest.raises(ConfigError, match="occupied_prob"):
        DockSceneConfig(occupied_prob=1.5)


def test_narrow_apron_is_raised_and_angles_clamped():
    """A too shallow apron is deepened so the goal and start fit; steep angles get clamped."""
    cfg = dataclasses.replace(CFG, apron_depth=(5.0, 5.0), start_angle=(1.2, 1.2))
    scenes, params = make(cfg, 2000, 1)
    p = {k: v.double().numpy() for k, v in params.items()}
    f = scenes.frame.double().numpy()
    seg = to_dock(scenes.segments.double().numpy().reshape(2000, -1, 2, 2), f).reshape(2000, -1, 4)
    mask = scenes.mask.numpy()
    start = pose_to_dock(scenes.start.double().numpy(), f)
    goal = pose_to_dock(scenes.goal.double().numpy(), f)
    assert (scenes.info["apron_depth"] > 5.0).all()
    assert (clearance(start, p, seg, mask) >= cfg.start_clearance - TOL).all()
    assert (clearance(goal, p, seg, mask) > 0.1).all()
    alpha = np.arcsin(np.sin(start[:, 2]))
    assert (alpha < 1.2 - 0.1).all()
