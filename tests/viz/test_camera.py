"""The viewer's camera and the layers a road network adds: a scene too large to show whole is
followed (the truck at the image centre, the LiDAR's range in view), a small one keeps its fixed
framing; a state's route is a thin line, its traffic filled boxes (cars and trucks apart).

Expected pixels are hand-computed from the view (``(size - 1) / 2`` at the centre, rows grow
downwards, ``metres_per_px`` = 2 half extent / size), not taken from the renderer.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from truckrl.env import TruckEnv
from truckrl.sim.vehicle import truck_corners
from truckrl.viz.config import ViewConfig
from truckrl.viz.draw import COLORS, draw_state
from truckrl.viz.video import FrameState, fixed_camera, render_frame

BG = np.array(COLORS["background"])


@pytest.fixture(scope="module")
def env():
    e = TruckEnv(num_envs=1, seed=0)  # the default task: start and goal within a view
    e.reset()
    return e


def _tractor_like(rgb):
    """Tractor blues (outline (70, 140, 255), fill (38, 77, 140)), also half blended."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (b - r > 40) & (b - g > 25)


def _near(pixel, name, tol=12) -> bool:
    return bool(np.abs(pixel.astype(int) - np.array(COLORS[name])).max() <= tol)


def _frame(env, state, view: ViewConfig) -> np.ndarray:
    """The viewer's bird's-eye view of ``state`` (batch ``[1]``), no beams drawn."""
    beams = env.task.rel_angles.shape[0]
    fs = FrameState(
        state=state[0],
        ranges=torch.full((beams,), math.inf),
        task=env.task,
        config=env.config,
        tolerance=(1.0, 0.1),
        difficulty=0.0,
        rewards={},
        camera=fixed_camera(state, view),
    )
    return render_frame(fs, view)[0]


def _tractor_centre(state) -> tuple[float, float, float]:
    """World centre [m] of the tractor body and its heading: the rear axle plus half of
    (wheelbase + front overhang - rear overhang) along the heading."""
    p = state["params"]
    x, y, th = (float(state["pose"][0, i]) for i in range(3))
    ahead = 0.5 * float(p["wheelbase"][0] + p["front_overhang"][0] - p["rear_overhang"][0])
    return x + ahead * math.cos(th), y + ahead * math.sin(th), th


def test_a_scene_larger_than_the_view_is_followed_at_the_lidar_range(env):
    state = env.get_state().clone()
    x, y = (float(v) for v in state["pose"][0, :2])
    state["goal"][0, :2] = torch.tensor([x + 400.0, y - 300.0])  # 500 m away
    # one curb 60 m east of the truck: inside a view of 50 m LiDAR + 15 m margin, not 40 m
    state["segments"][0, 0] = torch.tensor([x + 60.0, y - 5.0, x + 60.0, y + 5.0])
    state["mask"][0] = False
    state["mask"][0, 0] = True
    view = ViewConfig(size_px=320, panel_px=0)
    assert fixed_camera(state, view) is None
    img = _frame(env, state, view)
    m_per_px = 2 * (50.0 + 15.0) / 320  # half extent: LiDAR range + margin
    cx, cy, _ = _tractor_centre(state)
    col = 159.5 + (cx - x) / m_per_px  # the rear axle at the image centre, north up
    row = 159.5 - (cy - y) / m_per_px
    rows, cols = np.nonzero(_tractor_like(img))
    assert len(rows) > 20, "no tractor drawn"
    assert math.hypot(rows.mean() - row, cols.mean() - col) < 1.5
    curb_col = round(159.5 + 60.0 / m_per_px)  # column 307
    assert _near(img[160, curb_col], "curb", tol=60)
    assert (img[160, curb_col + 6] == BG).all() and (img[160, curb_col - 6] == BG).all()


@pytest.mark.parametrize("seed", range(4))
def test_a_small_scene_keeps_its_fixed_framing(seed):
    env = TruckEnv(num_envs=1, seed=seed)
    env.reset()
    state = env.get_state()
    view = ViewConfig(size_px=320, panel_px=0)
    cam = fixed_camera(state, view)
    assert cam is not None
    tractor, trailer, _ = truck_corners(state["pose"], state["params"])
    pts = np.concatenate([tractor[0], trailer[0], state["goal"][0, None, :2]]).astype(float)
    lo, hi = pts.min(0), pts.max(0)
    half = max(40.0, 0.5 * float((hi - lo).max()) + 15.0)  # view.half_extent, view.margin
    np.testing.assert_allclose(np.asarray(cam["center"], float), 0.5 * (lo + hi), atol=1e-5)
    assert cam["view_half_extent"] == pytest.approx(half)
    img = _frame(env, state, view)
    m_per_px = 2 * half / 320
    cx, cy, _ = _tractor_centre(state)
    col = 159.5 + (cx - 0.5 * (lo[0] + hi[0])) / m_per_px
    row = 159.5 - (cy - 0.5 * (lo[1] + hi[1])) / m_per_px
    rows, cols = np.nonzero(_tractor_like(img))
    assert len(rows) > 20
    assert math.hypot(rows.mean() - row, cols.mean() - col) < 1.5


def test_a_long_route_is_followed_even_with_the_goal_near(env):
    state = env.get_state().clone()
    x, y = (float(v) for v in state["pose"][0, :2])
    view = ViewConfig()
    route = torch.tensor([[x, y], [x + 150.0, y], [x + 150.0, y + 150.0], [x, y + 1.0]])
    state["route_points"] = route[None]
    assert fixed_camera(state, view) is None
    state["route_points"] = route[None] * 0.1 + torch.tensor([0.9 * x, 0.9 * y])  # 15 m
    assert fixed_camera(state, view) is not None


def _bare(env, pose_xy=(0.0, 0.0)):
    """The env's state with no curbs, the truck at ``pose_xy`` heading east (batch ``[1]``)."""
    state = env.get_state().clone()
    state["pose"][0] = torch.tensor([*pose_xy, 0.0, 0.0])
    state["mask"][0] = False
    return state


def _draw(env, state) -> np.ndarray:
    """201 x 201 px, 0.25 m/px, centred on the rear axle: world (x0 + dx, y0 + dy) at
    column 100 + 4 dx, row 100 - 4 dy."""
    beams = env.task.rel_angles.shape[0]
    return draw_state(
        state[0], np.full(beams, np.inf), env.task.rel_angles, size_px=201, metres_per_px=0.25
    )


def test_route_drawn_as_a_thin_line(env):
    state = _bare(env, (10.0, 20.0))
    plain = _draw(env, state)
    # 20 m north of the truck, x from -20 m to +20 m around it: row 20, columns 20 to 180
    state["route_points"] = torch.tensor([[[-10.0, 40.0], [10.0, 40.0], [30.0, 40.0]]])
    img = _draw(env, state)
    for c in (25, 60, 80, 120, 175):  # (not at its joint, column 100)
        assert _near(img[20, c], "route", tol=30), c
        assert (img[22, c] == BG).all() and (img[18, c] == BG).all(), c  # thin: one row
    assert (img[20, 10] == BG).all() and (img[20, 190] == BG).all()  # not past its ends
    assert np.array_equal(img[30:], plain[30:])  # nothing else changed


def _traffic(state, x0: float, y0: float) -> None:
    """One straight lane 20 m south of ``(x0, y0)``, east from x0 - 20 to x0 + 20 m, and four
    vehicle slots on it: a car at s = 5 m, a truck at 20 m, an empty slot at 30 m and a car
    waiting off the network at 35 m (in place, the ``tr_`` keys of the network task)."""
    f32, i64 = torch.float32, torch.long
    lane = torch.tensor([[[x0 - 20.0, y0 - 20.0], [x0 + 20.0, y0 - 20.0]]])
    keys = {
        "lanes": lane,
        "cum": torch.tensor([[0.0, 40.0]]),
        "lane_len": torch.tensor([40.0]),
        "pieces": torch.tensor([0]),
        "successor": torch.tensor([-1]),
        "zone_centre": torch.zeros(1, 2),
        "zone_radius": torch.zeros(1),
        "zone_mask": torch.zeros(1, dtype=torch.bool),
        "lane": torch.zeros(4, dtype=i64),
        "home": torch.zeros(4, dtype=i64),
        "s": torch.tensor([5.0, 20.0, 30.0, 35.0]),
        "v": torch.zeros(4),
        "v0": torch.ones(4),
        "length": torch.tensor([4.5, 12.0, 4.5, 4.5], dtype=f32),
        "width": torch.tensor([2.0, 2.5, 2.0, 2.0], dtype=f32),
        "truck": torch.tensor([False, True, False, False]),
        "active": torch.tensor([True, True, False, True]),
        "waiting": torch.tensor([False, False, False, True]),
    }
    for k, v in keys.items():
        state[f"tr_{k}"] = v[None]


def test_traffic_drawn_filled_cars_and_trucks_apart(env):
    state = _bare(env, (5.0, -3.0))
    plain = _draw(env, state)
    _traffic(state, 5.0, -3.0)
    img = _draw(env, state)
    # row 180 (20 m south); car at x0 - 15 m (column 40), truck at x0 (column 100), the empty
    # slot at x0 + 10 m (column 140), the waiting car at x0 + 15 m (column 160)
    assert _near(img[180, 40], "car_fill") and _near(img[178, 45], "car_fill")
    assert _near(img[180, 100], "traffic_truck_fill") and _near(img[180, 80], "traffic_truck_fill")
    assert _near(img[175, 100], "traffic_truck", tol=60)  # its outline, 1.25 m = 5 rows up
    for c in (140, 160):
        assert (img[170:191, c - 6 : c + 7] == BG).all(), c  # no vehicle drawn there
    # the traffic's colours nowhere but on its two boxes (car: columns 31-49, truck 76-124)
    changed = np.nonzero((img != plain).any(-1))
    assert changed[0].min() >= 170 and changed[0].max() <= 190
    assert set(changed[1].tolist()) <= set(range(29, 52)) | set(range(74, 127))
