"""BEV drawing: image shapes, where known world geometry lands in pixels, view centring."""

import math

import numpy as np
import pytest
import torch

from truckrl.viz.draw import COLORS, draw_scene, make_view, world_to_pixel

BG = np.array(COLORS["background"])


def close(pixel, name, tol=8) -> bool:
    return bool(np.abs(pixel.astype(int) - np.array(COLORS[name])).max() <= tol)


def test_world_to_pixel_hand_values_and_y_up():
    view = make_view(101, center=(10.0, 20.0), metres_per_px=0.5)
    px = world_to_pixel(np.array([[10.0, 20.0], [12.0, 21.0], [10.0, 15.0]]), view)
    np.testing.assert_allclose(px, [[50.0, 50.0], [54.0, 48.0], [50.0, 60.0]])
    assert make_view(100, view_half_extent=50.0).metres_per_px == 1.0
    assert make_view((200, 100), view_half_extent=25.0).metres_per_px == 0.5  # shorter side


@pytest.mark.parametrize(("size", "shape"), [(64, (64, 64, 3)), ((120, 80), (80, 120, 3))])
def test_shape_and_dtype(size, shape):
    img = draw_scene(np.zeros((0, 4)), size_px=size)
    assert img.shape == shape and img.dtype == np.uint8
    assert (img == BG).all()


def test_segment_colours_the_expected_pixels():
    segs = np.array([[-10.0, 0.0, 10.0, 0.0], [-10.0, 20.0, 10.0, 20.0]])
    img = draw_scene(segs, center=(0.0, 0.0), size_px=101, metres_per_px=1.0)
    for col in range(42, 59):
        assert close(img[50, col], "curb"), col  # y = 0 on the centre row
        assert close(img[30, col], "curb"), col  # y = +20 is 20 rows *up*
    assert (img[70, 50] == BG).all()  # nothing at y = -20
    assert (img[50, 70] == BG).all()  # beyond the segment's end
    assert (img[50, 30] == BG).all()


def test_view_centring():
    segs = np.array([[195.0, -50.0, 205.0, -50.0]])
    img = draw_scene(segs, center=(200.0, -50.0), size_px=101, metres_per_px=0.5)
    assert close(img[50, 50], "curb") and close(img[50, 40], "curb")
    assert (img[50, 35] == BG).all()
    # default centre: the middle of the valid segments' bounding box
    img2 = draw_scene(segs, size_px=101, metres_per_px=0.5)
    assert np.array_equal(img, img2)


def test_torch_and_numpy_inputs_agree_and_mask_hides_padding():
    segs = np.array([[-10.0, 0.0, 10.0, 0.0], [0.0, -10.0, 0.0, 10.0]])
    mask = np.array([True, False])
    a = draw_scene(segs, mask, center=(0, 0), size_px=64)
    b = draw_scene(torch.tensor(segs), torch.tensor(mask), center=torch.zeros(2), size_px=64)
    assert np.array_equal(a, b)
    assert (a[10, 32] == BG).all()  # the vertical segment is padding: not drawn
    assert not (a[32, 32] == BG).all()


def test_obstacles_filled_and_truck_bodies():
    # a 6 m x 4 m obstacle as 4 chained edges of kind 1 around (20, 0)
    c = np.array([[23.0, -2.0], [23.0, 2.0], [17.0, 2.0], [17.0, -2.0]])
    segs = np.concatenate((c, np.roll(c, -1, axis=0)), axis=1)
    tractor = np.array([[3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]])
    trailer = tractor - np.array([10.0, 0.0])
    img = draw_scene(
        segs,
        np.ones(4, bool),
        np.ones(4, int),
        tractor=tractor,
        trailer=trailer,
        center=(0.0, 0.0),
        size_px=101,
        metres_per_px=0.5,
    )
    assert close(img[50, 90], "obstacle_fill")  # obstacle centre x = 20 m -> column 90
    assert close(img[46, 90], "obstacle")  # its top edge y = 2 m -> row 46
    assert close(img[50, 50], "tractor_fill")
    assert close(img[50, 30], "trailer_fill")  # trailer centre x = -10 m -> column 30


def test_lidar_goal_and_hud():
    base = draw_scene(np.zeros((0, 4)), center=(0, 0), size_px=101, metres_per_px=1.0)
    img = draw_scene(
        np.zeros((0, 4)),
        lidar_origin=[0.0, 0.0],
        lidar_ranges=[20.0, math.inf],
        lidar_angles=[math.pi / 2, 0.0],
        center=(0, 0),
        size_px=101,
        metres_per_px=1.0,
    )
    assert close(img[40, 50], "lidar", tol=40)  # beam straight up
    assert (img[50, 60] == BG).all()  # the infinite beam is not drawn
    img = draw_scene(
        np.zeros((0, 4)),
        goal=[0.0, 0.0, math.pi],
        goal_tolerance=(20.0, 0.3),
        center=(0, 0),
        size_px=101,
        metres_per_px=1.0,
        arrow_length=5.0,
    )
    assert close(img[50, 47], "goal", tol=40)  # the arrow points to -x
    assert close(img[50, 42], "tolerance")  # heading wedge (radius 10 m) beyond the arrow tip
    assert (img[50, 58] == BG).all()  # no wedge behind the goal
    assert close(img[50, 70], "tolerance", tol=60)  # the 20 m position-tolerance circle
    assert close(img[30, 50], "tolerance", tol=60)
    hud = draw_scene(
        np.zeros((0, 4)), center=(0, 0), size_px=101, metres_per_px=1.0, hud_lines=["hi"]
    )
    assert not np.array_equal(hud[:25, :40], base[:25, :40])
    assert np.array_equal(hud[60:], base[60:])
