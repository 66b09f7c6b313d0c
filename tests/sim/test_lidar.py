"""LiDAR: oracle vs hand-computed ranges; sweep and batched forms vs the oracle."""

from __future__ import annotations

import math

import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.compiled import compile_sim
from truckrl.sim.geometry import rectangle_segments
from truckrl.sim.lidar import (
    LidarConfig,
    SweepLidar,
    beam_angles,
    lidar_oracle,
    lidar_scan,
)

F64 = torch.float64
MAX_RANGE = 50.0
TOL = 1e-4  # [m]


def grid_rectangles(n: int, per_scene: int, g: torch.Generator, cell: float = 10.0) -> torch.Tensor:
    """``[n, 4 * per_scene, 4]`` non-overlapping oriented rectangles, one per cell of a 9x9 grid.

    Each rectangle fits in a circle of radius 4.3 m around a point within 0.3 m of its 10 m cell's
    centre, so none touch.
    """
    cells = torch.stack([torch.randperm(81, generator=g)[:per_scene] for _ in range(n)])
    cx = ((cells % 9).to(F64) - 4.0) * cell + (
        torch.rand(n, per_scene, generator=g, dtype=F64) - 0.5
    ) * 0.6
    cy = ((cells // 9).to(F64) - 4.0) * cell + (
        torch.rand(n, per_scene, generator=g, dtype=F64) - 0.5
    ) * 0.6
    heading = torch.rand(n, per_scene, generator=g, dtype=F64) * 2 * math.pi
    half_len = 0.5 + torch.rand(n, per_scene, generator=g, dtype=F64) * 3.0
    half_wid = 0.3 + torch.rand(n, per_scene, generator=g, dtype=F64) * 1.5
    return rectangle_segments(cx, cy, heading, half_len, half_len, half_wid).flatten(-3, -2)


def free_poses(
    segments: torch.Tensor, m: int, g: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """``m`` sensor positions ``[n, m, 2]`` in the scene's square and headings ``[n, m]``."""
    n = segments.shape[0]
    origin = (torch.rand(n, m, 2, generator=g, dtype=F64) - 0.5) * 90.0
    heading = (torch.rand(n, m, generator=g, dtype=F64) - 0.5) * 2 * math.pi
    return origin, heading


def oracle_batch(origin, heading, segments, mask, rel) -> torch.Tensor:
    """Oracle over flat envs ``origin [N, 2]`` -> ``[N, R]`` float64."""
    return torch.stack(
        [
            lidar_oracle(
                origin[i],
                float(heading[i]),
                segments[i],
                None if mask is None else mask[i],
                rel,
                MAX_RANGE,
            )
            for i in range(origin.shape[0])
        ]
    ).to(F64)


def all_methods(origin, heading, segments, mask, rel) -> dict[str, torch.Tensor]:
    """Sweep (fresh per env) and the batched scan, ``[N, R]`` each."""
    out = {
        "batched": lidar_scan(origin, heading, segments, mask, rel.to(segments.dtype), MAX_RANGE)
    }
    sweeps = []
    for i in range(origin.shape[0]):
        sweep = SweepLidar(rel, MAX_RANGE)
        sweeps.append(
            sweep(origin[i], float(heading[i]), segments[i], None if mask is None else mask[i])
        )
    out["sweep"] = torch.stack(sweeps)
    return out


def assert_agree(origin, heading, segments, mask, rel, tol=TOL) -> torch.Tensor:
    want = oracle_batch(origin, heading, segments, mask, rel)
    for name, got in all_methods(origin, heading, segments, mask, rel).items():
        err = (got.to(F64) - want).abs().max().item()
        assert err <= tol, f"{name}: max |error| = {err} m"
    return want


# --- config and layout -----------------------------------------------------------------


def test_config_defaults_and_errors():
    cfg = LidarConfig()
    assert (cfg.num_beams, cfg.max_range, cfg.fov) == (16, 50.0, 2 * math.pi)
    for field, bad in [
        ("num_beams", 0),
        ("num_beams", 2.5),
        ("fov", 0.0),
        ("fov", 7.0),
        ("max_range", -1.0),
    ]:
        with pytest.raises(ConfigError, match=f"lidar.{field}"):
            LidarConfig(**{field: bad})


def test_beam_angles_full_circle_uniform_across_seam():
    for r in (1, 4, 16, 17):
        a = beam_angles(r, 2 * math.pi, dtype=F64)
        step = 2 * math.pi / r
        assert a[0] == -math.pi and (a >= -math.pi).all() and (a < math.pi).all()
        gaps = torch.diff(torch.cat([a, a[:1] + 2 * math.pi]))
        assert torch.allclose(gaps, torch.full_like(gaps, step), atol=1e-12)
    assert beam_angles(16)[8] == 0.0  # straight ahead


def test_beam_angles_partial_fov():
    a = beam_angles(5, math.pi, dtype=F64)
    assert torch.allclose(a, torch.tensor([-2, -1, 0, 1, 2], dtype=F64) * math.pi / 4)
    assert beam_angles(1, 1.0).tolist() == [0.0]


# --- oracle against hand-computed ranges --------------------------------------------------


def test_oracle_wall_hand_computed():
    wall = torch.tensor([[10.0, -5.0, 10.0, 5.0]], dtype=F64)  # x = 10, |y| <= 5
    rel = torch.tensor([0.0, 0.3, -0.4, 0.6, math.pi / 2, -3.0], dtype=F64)
    got = lidar_oracle(torch.zeros(2, dtype=F64), 0.0, wall, None, rel, MAX_RANGE)
    # atan(5/10) = 0.4636: beams within it hit at 10/cos, the rest see nothing
    want = [10.0, 10 / math.cos(0.3), 10 / math.cos(0.4), MAX_RANGE, MAX_RANGE, MAX_RANGE]
    assert torch.allclose(got, torch.tensor(want, dtype=F64), atol=1e-9)
    assert got[3] == MAX_RANGE  # no hit is exactly max_range


def test_oracle_range_prefilter_and_clamp():
    rel = torch.tensor([0.0, 0.9], dtype=F64)
    far = torch.tensor([[60.0, -100.0, 60.0, 100.0]], dtype=F64)
    got = lidar_oracle(torch.zeros(2, dtype=F64), 0.0, far, None, rel, MAX_RANGE)
    assert got.tolist() == [MAX_RANGE, MAX_RANGE]
    # in range straight ahead (40 m) but 40/cos(0.9) = 64 m along the oblique beam: clamped
    near = torch.tensor([[40.0, -100.0, 40.0, 100.0]], dtype=F64)
    got = lidar_oracle(torch.zeros(2, dtype=F64), 0.0, near, None, rel, MAX_RANGE)
    assert torch.allclose(got, torch.tensor([40.0, MAX_RANGE], dtype=F64))


# --- degenerate cases: every implementation against hand values --------------------------


def _check_hand_case(origin, heading, segments, rel, want, mask=None):
    o = torch.tensor(origin, dtype=F64)
    h = torch.tensor(heading, dtype=F64)
    s = torch.tensor(segments, dtype=F64).view(-1, 4)
    m = None if mask is None else torch.tensor(mask)
    w = torch.tensor(want, dtype=F64)
    got = {
        "oracle": lidar_oracle(o, float(h), s, m, rel, MAX_RANGE),
        "sweep": SweepLidar(rel, MAX_RANGE)(o, float(h), s, m),
    }
    mb = None if m is None else m[None]
    got["batched"] = lidar_scan(o[None], h[None], s[None], mb, rel, MAX_RANGE)[0]
    got["batched/f32"] = lidar_scan(
        o[None].float(), h[None].float(), s[None].float(), mb, rel.float(), MAX_RANGE
    )[0]
    for name, g in got.items():
        assert torch.allclose(g.to(F64), w, atol=TOL), f"{name}: {g.tolist()} != {want}"


def test_rays_exactly_through_vertices():
    # sensor inside a 10 m square; 8 beams, the diagonal ones through the corners
    square = [[5, -5, 5, 5], [5, 5, -5, 5], [-5, 5, -5, -5], [-5, -5, 5, -5]]
    d = 5 * math.sqrt(2)
    _check_hand_case([0.0, 0.0], 0.0, square, beam_angles(8, dtype=F64), [5, d, 5, d, 5, d, 5, d])


def test_radial_edge_collinear_with_ray():
    # edge along the beam straight ahead (3 m to 8 m) and one straight behind
    segs = [[3, 0, 8, 0], [-20, 0, -9, 0]]
    _check_hand_case([0.0, 0.0], 0.0, segs, beam_angles(4, dtype=F64), [9, MAX_RANGE, 3, MAX_RANGE])


def test_edge_crossing_seam_and_zero_length_edge():
    # wall behind the sensor spans the -pi/+pi seam; a zero-length edge (a point) straight ahead
    segs = [[-10, -2, -10, 2], [7, 0, 7, 0]]
    _check_hand_case(
        [0.0, 0.0], 0.0, segs, beam_angles(4, dtype=F64), [10, MAX_RANGE, 7, MAX_RANGE]
    )
    # same scene seen with the heading turned by pi: the seam now looks forward
    _check_hand_case(
        [0.0, 0.0], math.pi, segs, beam_angles(4, dtype=F64), [7, MAX_RANGE, 10, MAX_RANGE]
    )


def test_sensor_within_a_millimetre_of_a_segment():
    segs = [[-5, 1e-3, 5, 1e-3]]  # 1 mm to the left of the sensor, 10 m long
    rel = beam_angles(4, dtype=F64)  # back, right, ahead, left
    _check_hand_case([0.0, 0.0], 0.0, segs, rel, [MAX_RANGE, MAX_RANGE, MAX_RANGE, 1e-3])
    # a beam 1 degree off the segment direction meets it after 1e-3/sin(1 deg) = 5.7 cm
    rel = torch.tensor([math.radians(1.0)], dtype=F64)
    _check_hand_case([0.0, 0.0], 0.0, segs, rel, [1e-3 / math.sin(math.radians(1.0))])


def test_out_of_range_and_all_padding():
    segs = [[55, -5, 55, 5], [0, 60, 5, 70]]
    rel = beam_angles(16, dtype=F64)
    _check_hand_case([0.0, 0.0], 0.3, segs, rel, [MAX_RANGE] * 16)
    near = [[5, -5, 5, 5], [-5, -5, -5, 5]]
    _check_hand_case([0.0, 0.0], 0.0, near, rel, [MAX_RANGE] * 16, mask=[False, False])


# --- random scenes: every implementation against the oracle ------------------------------


@pytest.mark.parametrize(("num_beams", "poses"), [(16, 10), (61, 5)])  # ~10k and ~18k rays
def test_random_rectangles_agree_with_oracle(num_beams, poses):
    g = torch.Generator().manual_seed(num_beams)
    segs = grid_rectangles(60, 20, g)  # [60, 80, 4]
    origin, heading = free_poses(segs, poses, g)
    mask = torch.rand(60, 80, generator=g) > 0.15
    n = 60 * poses
    seg_f = segs.repeat_interleave(poses, 0)
    mask_f = mask.repeat_interleave(poses, 0)
    want = assert_agree(
        origin.view(n, 2), heading.view(n), seg_f, mask_f, beam_angles(num_beams, dtype=F64)
    )
    assert (want < MAX_RANGE).float().mean() > 0.2  # the scenes are not empty
    assert (want == MAX_RANGE).any()


def test_rays_through_random_vertices():
    # every beam aims exactly (to round-off) at a rectangle corner that is not a silhouette
    # corner: the beam enters the rectangle through it, so both adjacent edges are hit there
    g = torch.Generator().manual_seed(3)
    rel = beam_angles(16, dtype=F64)
    n = 200
    origin = (torch.rand(n, 2, generator=g, dtype=F64) - 0.5) * 20
    heading = (torch.rand(n, generator=g, dtype=F64) - 0.5) * 2 * math.pi
    dist = 5 + torch.rand(n, 16, generator=g, dtype=F64) * 30
    ang = heading[:, None] + rel
    corner = origin[:, None] + dist[..., None] * torch.stack((ang.cos(), ang.sin()), -1)
    # a 1 m square rotated 45 deg to the beam has a corner pointing at the sensor
    centre = corner + (0.5 * math.sqrt(2)) * torch.stack((ang.cos(), ang.sin()), -1)
    half = torch.full_like(dist, 0.5)
    segs = rectangle_segments(centre[..., 0], centre[..., 1], ang + math.pi / 4, half, half, half)
    want = assert_agree(origin, heading, segs.flatten(-3, -2), None, rel)
    assert torch.allclose(want, dist, atol=TOL)  # hand value: the corner distance


def test_crossing_segments_still_exact():
    # random segment soup with many crossings: the sweep re-tests every open segment per ray
    g = torch.Generator().manual_seed(7)
    n, e = 300, 30
    p = (torch.rand(n, e, 2, generator=g, dtype=F64) - 0.5) * 80
    q = p + (torch.rand(n, e, 2, generator=g, dtype=F64) - 0.5) * 40
    segs = torch.cat((p, q), -1)
    origin = (torch.rand(n, 2, generator=g, dtype=F64) - 0.5) * 60
    heading = (torch.rand(n, generator=g, dtype=F64) - 0.5) * 2 * math.pi
    assert_agree(origin, heading, segs, None, beam_angles(32, dtype=F64))


def test_float32_batched_close_to_float64_oracle():
    g = torch.Generator().manual_seed(11)
    segs = grid_rectangles(40, 12, g)
    origin, heading = free_poses(segs, 25, g)
    seg_f = segs.repeat_interleave(25, 0)
    origin, heading = origin.view(-1, 2), heading.view(-1)
    rel = beam_angles(16, dtype=F64)
    want = oracle_batch(origin, heading, seg_f, None, rel)
    got = lidar_scan(origin.float(), heading.float(), seg_f.float(), None, rel.float(), MAX_RANGE)
    assert got.dtype == torch.float32
    err = (got.to(F64) - want).abs()
    # float32 round-off on coordinates and directions; grazing rays amplify it
    assert err.max() <= 1e-3
    assert (err <= TOL).float().mean() >= 0.999


def test_batched_leading_dims_and_no_segments():
    g = torch.Generator().manual_seed(5)
    segs = grid_rectangles(6, 5, g).view(2, 3, 20, 4)
    origin, heading = free_poses(segs.view(6, 20, 4), 1, g)
    rel = beam_angles(16, dtype=F64)
    got = lidar_scan(origin.view(2, 3, 2), heading.view(2, 3), segs, None, rel, MAX_RANGE)
    want = oracle_batch(origin.view(6, 2), heading.view(6), segs.view(6, 20, 4), None, rel)
    assert got.shape == (2, 3, 16)
    assert torch.allclose(got.view(6, 16), want, atol=TOL)
    empty = lidar_scan(
        origin.view(6, 2), heading.view(6), segs.view(6, 20, 4)[:, :0], None, rel, MAX_RANGE
    )
    assert (empty == MAX_RANGE).all() and empty.shape == (6, 16)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_batched_cuda_matches_cpu():
    g = torch.Generator().manual_seed(9)
    segs = grid_rectangles(50, 12, g).float()
    origin, heading = free_poses(segs, 1, g)
    rel = beam_angles(16)
    cpu = lidar_scan(origin[:, 0].float(), heading[:, 0].float(), segs, None, rel, MAX_RANGE)
    gpu = lidar_scan(
        origin[:, 0].float().cuda(),
        heading[:, 0].float().cuda(),
        segs.cuda(),
        None,
        rel.cuda(),
        MAX_RANGE,
    )
    assert torch.allclose(gpu.cpu(), cpu, atol=1e-3)


# --- the sweep's kept event order -----------------------------------------------------------


def test_sweep_cached_order_matches_fresh_sort():
    g = torch.Generator().manual_seed(13)
    rel = beam_angles(24, dtype=F64)
    scenes = grid_rectangles(3, 15, g)
    cached = SweepLidar(rel, MAX_RANGE)
    pose = torch.tensor([1.0, -2.0, 0.5], dtype=F64)
    for version, seg in enumerate(scenes):
        steps = []
        for k in range(40):  # a slow drive, then a few large jumps (teleport, half turn)
            pose = pose + torch.tensor([0.3, 0.1, 0.05], dtype=F64)
            if k % 10 == 9:
                pose = torch.cat(
                    [(torch.rand(2, generator=g, dtype=F64) - 0.5) * 100, pose[2:] + 3.0]
                )
            steps.append(pose)
        for p in steps:
            got = cached(p[:2], float(p[2]), seg, scene_id=version)
            fresh = SweepLidar(rel, MAX_RANGE)(p[:2], float(p[2]), seg)
            want = lidar_oracle(p[:2], float(p[2]), seg, None, rel, MAX_RANGE)
            assert torch.equal(got, fresh)
            assert torch.allclose(got, want, atol=TOL)


def test_sweep_scene_change_invalidates_cache():
    g = torch.Generator().manual_seed(17)
    rel = beam_angles(16, dtype=F64)
    a, b = grid_rectangles(2, 10, g)
    sweep = SweepLidar(rel, MAX_RANGE)
    o = torch.tensor([0.5, 0.5], dtype=F64)
    sweep(o, 0.2, a, scene_id="a")
    got = sweep(o, 0.2, b, scene_id="b")
    assert torch.allclose(got, lidar_oracle(o, 0.2, b, None, rel, MAX_RANGE), atol=TOL)
    assert not torch.allclose(got, lidar_oracle(o, 0.2, a, None, rel, MAX_RANGE), atol=TOL)


# --- the real scene generator ---------------------------------------------------------------


def test_generated_scenes_agree_with_oracle():
    from truckrl.sim.vehicle import VehicleConfig, sample_vehicle_params
    from truckrl.tasks.intersection import scene

    g = torch.Generator().manual_seed(21)
    n = 64
    batch = scene.generate_scenes(
        scene.SceneConfig(), sample_vehicle_params(VehicleConfig(), n, g), g
    )
    segs, mask = batch.segments.to(F64), batch.mask
    rel = beam_angles(16, dtype=F64)
    for k in range(4):  # start poses, then poses scattered around them
        jitter = (
            (torch.rand(n, 3, generator=g, dtype=F64) - 0.5)
            * torch.tensor([20.0, 20.0, 6.0], dtype=F64)
            * (k > 0)
        )
        pose = batch.start.to(F64) + jitter
        want = assert_agree(pose[:, :2], pose[:, 2], segs, mask, rel)
        assert (want < MAX_RANGE).float().mean() > 0.2 and (want == MAX_RANGE).any()


@pytest.mark.slow
def test_many_random_scenes_slow():
    g = torch.Generator().manual_seed(99)
    for num_beams in (16, 64, 250):
        segs = grid_rectangles(400, 25, g)
        origin, heading = free_poses(segs, 1, g)
        assert_agree(origin[:, 0], heading[:, 0], segs, None, beam_angles(num_beams, dtype=F64))


# --- the eager fast path of the dense scan ---------------------------------------------------


def _reference_dense(origin, heading, segments, mask, rel, max_range):
    """The dense scan as it was written before its eager fast path: to_local, then
    ray_segment_distance from (0, 0) on the whole batch at once, then the minimum."""
    from truckrl.sim.geometry import ray_segment_distance, to_local

    ends = to_local(segments.unflatten(-1, (2, 2)).flatten(-3, -2), origin, heading)
    local = ends.unflatten(-2, (-1, 2)).flatten(-2)
    zero = torch.zeros((), dtype=local.dtype).expand(2)
    d = ray_segment_distance(zero, rel.to(local), local, mask)
    return d.amin(-1).clamp_max(max_range)


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_dense_fast_path_is_bit_identical_to_ray_segment_distance(dtype):
    # chunked (more rows than one chunk holds) and in-place: every range must be the same bits
    # as the plain composition, on scenes with rays through vertices, along segments, crossing
    # segments, zero-length segments, a sensor on a segment, padding, and nothing in range
    g = torch.Generator().manual_seed(21)
    n, e = 700, 24
    rel = beam_angles(16, dtype=dtype)
    origin = ((torch.rand(n, 2, generator=g, dtype=F64) - 0.5) * 60).round()  # grid points
    heading = (torch.randint(0, 8, (n,), generator=g) * (math.pi / 4)).to(F64)  # beams on axes
    p = ((torch.rand(n, e, 2, generator=g, dtype=F64) - 0.5) * 80).round()
    q = p + ((torch.rand(n, e, 2, generator=g, dtype=F64) - 0.5) * 30).round()
    segs = torch.cat((p, q), -1)
    segs[:, 0, 2:] = segs[:, 0, :2]  # zero-length
    segs[:, 1] = torch.cat((origin - 3, origin + 3), -1)  # the sensor lies on it (diagonal)
    segs[:, 2] = torch.cat((origin + 1, origin + 20), -1) * torch.tensor([1.0, 0, 1, 0]) + (
        origin[:, 1:].repeat(1, 4) * torch.tensor([0.0, 1, 0, 1])
    )  # along the beam at 0 rad when heading is 0
    segs[-5:] += 500.0  # nothing in range
    mask = torch.rand(n, e, generator=g) > 0.3
    segs, origin, heading = segs.to(dtype), origin.to(dtype), heading.to(dtype)
    for m in (mask, None):
        got = lidar_scan(origin, heading, segs, m, rel, MAX_RANGE)
        want = _reference_dense(origin, heading, segs, m, rel, MAX_RANGE)
        assert torch.equal(got, want)
        assert (want < MAX_RANGE).float().mean() > 0.3 and (want == MAX_RANGE).any()


def test_fused_dense_form_is_bit_identical_eagerly_and_close_compiled():
    # the form torch.compile traces (materialised beam directions, coordinate-major ends) runs
    # eagerly too when gradients are needed: same bits as the plain composition there, and
    # within float32 round-off of it once compiled
    g = torch.Generator().manual_seed(8)
    n, e = 64, 24
    rel = beam_angles(16)
    origin = (torch.rand(n, 2, generator=g) - 0.5) * 60
    heading = (torch.rand(n, generator=g) - 0.5) * 7
    p = (torch.rand(n, e, 2, generator=g) - 0.5) * 80
    segs = torch.cat((p, p + (torch.rand(n, e, 2, generator=g) - 0.5) * 30), -1)
    mask = torch.rand(n, e, generator=g) > 0.3
    want = _reference_dense(origin, heading, segs, mask, rel, MAX_RANGE)
    assert (want < MAX_RANGE).float().mean() > 0.3
    got = lidar_scan(origin, heading, segs.clone().requires_grad_(True), mask, rel, MAX_RANGE)
    assert torch.equal(got.detach(), want)
    compiled = compile_sim(lidar_scan, "cpu")  # as the compiled env compiles it
    torch.testing.assert_close(
        compiled(origin, heading, segs, mask, rel, MAX_RANGE), want, rtol=1e-5, atol=1e-4
    )


def test_compiled_scan_reduces_inside_the_pair_loop():
    """Compiled as the env compiles it (:func:`compile_sim`), the LiDAR takes the minimum over
    segments where it computes the pair distances: no ``N x R x E`` buffer is allocated. Written
    out, those distances made the compiled env 2x slower at 256 beams (truckrl/sim/compiled.py)."""
    import re

    from torch._inductor.utils import run_and_get_code

    g = torch.Generator().manual_seed(3)
    n, e, r = 8, 16, 64
    origin, heading = torch.zeros(n, 2), torch.zeros(n)
    p = (torch.rand(n, e, 2, generator=g) - 0.5) * 80
    segs = torch.cat((p, p + (torch.rand(n, e, 2, generator=g) - 0.5) * 30), -1)
    mask = torch.rand(n, e, generator=g) > 0.3
    rel = beam_angles(r)
    compiled = compile_sim(lidar_scan, "cpu")
    out, codes = run_and_get_code(compiled, origin, heading, segs, mask, rel, MAX_RANGE)
    torch.testing.assert_close(
        out, _reference_dense(origin, heading, segs, mask, rel, MAX_RANGE), rtol=1e-5, atol=1e-4
    )
    shapes = [
        tuple(int(x) for x in m.split(",") if x.strip())
        for m in re.findall(r"empty_strided_cpu\(\(([\d, ]+)\)", "\n".join(codes))
    ]
    assert shapes, "no buffers found: the generated code's format changed"
    assert all(math.prod(s) < n * r * e for s in shapes), shapes
