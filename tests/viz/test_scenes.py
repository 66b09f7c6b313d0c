"""The scene-grid tool: a PNG of the requested grid, each tile showing its scene with the truck
where its start pose puts it, for any task."""

import math

import cv2
import numpy as np
import pytest
import torch

from truckrl.config.fields import build
from truckrl.sim.vehicle import truck_corners
from truckrl.tasks import EnvConfig, make_task, task_names
from truckrl.tools.scenes import main

TILE, BORDER, HALF_EXTENT = 128, 4, 50.0  # tile side [px], the tool's border [px], view [m]


def _tractor_like(rgb):
    """Pixels ``[..., 3]`` in the tractor's blues (outline (70, 140, 255), fill (38, 77, 140)),
    or half blended with the dark background: blue well above red and green."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (b - r > 40) & (b - g > 25)


def _trailer_like(rgb):
    """Pixels in the trailer's teals (outline (70, 200, 185), fill (38, 110, 100)): green and
    blue alike, both well above red (the goal's green has blue = red)."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (g - r > 40) & (b - r > 40) & (abs(g - b) < 30)


#: Rows a tile's two text lines cover: baselines at 18 and 36 px, descenders and the 1 px
#: outline below the second.
TEXT_ROWS = 2 * 18 + 8


@pytest.mark.parametrize("task", task_names())
def test_tool_draws_each_task_with_the_truck_at_its_start_pose(task, tmp_path, capsys):
    """Each tile shows its truck whole, clear of the text: centred between start and goal, or,
    where that would put the truck off the tile or under the text (a goal hundreds of metres
    away), centred on the truck's rear axle."""
    out = tmp_path / "grid.png"
    args = ["count=3", "seed=1", "cols=2", f"tile={TILE}", f"half_extent={HALF_EXTENT}"]
    args += [f"out={out}", f"task={task}"]
    assert main(args) == 0
    assert f"of task {task}" in capsys.readouterr().out
    img = cv2.imread(str(out))[..., ::-1]  # BGR -> RGB
    side = 2 * (TILE + BORDER) + BORDER  # 2 x 2 tiles with borders
    assert img.shape == (side, side, 3)
    assert (img[-BORDER - TILE :, -BORDER - TILE :] == 255).all()  # the 4th tile stays blank
    # the same scenes the tool draws: the task's own, seed 1
    cfg = build(EnvConfig, {"task": {"name": task}}, "env")
    state = make_task(cfg).sample(3, torch.Generator().manual_seed(1), torch.device("cpu"))
    pose, goal, p = state["pose"].double(), state["goal"].double(), state["params"]
    tractor, trailer, _ = truck_corners(state["pose"], p)
    m_per_px = 2 * HALF_EXTENT / TILE
    for i in range(3):
        r, c = divmod(i, 2)
        y0, x0 = BORDER + r * (TILE + BORDER), BORDER + c * (TILE + BORDER)
        tile = img[y0 : y0 + TILE, x0 : x0 + TILE]
        assert len(np.unique(tile.reshape(-1, 3), axis=0)) > 20  # not a blank or uniform tile
        # scene segments, under the two text lines: curbs light grey (225, 225, 225), obstacle
        # edges orange (235, 145, 45), each where the scene has valid segments of that kind
        below_hud = tile[48:].astype(int)
        curb = (below_hud.min(-1) > 150) & (np.ptp(below_hud, -1) < 20)
        edge = (abs(below_hud - (235, 145, 45)).max(-1) < 30).sum()
        valid = state["mask"][i]
        kinds = {int(k) for k in state["kind"][i][valid]}
        assert kinds and (0 not in kinds or curb.sum() > 20) and (1 not in kinds or edge > 20)
        assert _trailer_like(tile).sum() > 3
        # a route, where the task keeps one, as a pink line (255, 140, 200), also half blended:
        # red above blue above green
        r_, g_, b_ = (tile[..., k].astype(int) for k in range(3))
        pink = ((r_ - b_ > 15) & (b_ - g_ > 20)).sum()
        assert pink > 10 if "route_points" in state.keys() else pink == 0, pink
        # the tractor's centre: the rear axle plus half of (wheelbase + front overhang - rear
        # overhang) along the heading; y up
        ahead = 0.5 * (p["wheelbase"][i] + p["front_overhang"][i] - p["rear_overhang"][i])
        x, y, th = pose[i, 0], pose[i, 1], pose[i, 2]
        wx, wy = float(x + ahead * math.cos(th)), float(y + ahead * math.sin(th))
        rows, cols = np.nonzero(_tractor_like(tile))
        assert len(rows) > 12, "no tractor drawn"
        trailer_rows = np.nonzero(_trailer_like(tile))[0]
        # what a user sees: the whole truck inside the tile, below its text lines
        assert rows.min() >= TEXT_ROWS and trailer_rows.min() >= TEXT_ROWS, (i, rows.min())
        assert rows.max() < TILE - 1 and cols.min() > 0 and cols.max() < TILE - 1
        # the tile's centre: midway between start and goal if the whole start truck (its
        # corners) and the goal then fall inside the tile and the truck below the text; else
        # the rear axle (the truck's neighbourhood)
        mid = 0.5 * (pose[i, :2] + goal[i, :2])
        pts = torch.cat((tractor[i], trailer[i], goal[i, None, :2])).double() - mid
        pc, pr = (TILE - 1) / 2 + pts[:, 0] / m_per_px, (TILE - 1) / 2 - pts[:, 1] / m_per_px
        fits = bool((pc >= 0).all() and (pc <= TILE - 1).all() and (pr <= TILE - 1).all())
        fits = fits and bool((pr[:-1] >= TEXT_ROWS).all() and pr[-1] >= 0)
        if float((goal[i, :2] - pose[i, :2]).norm()) > 2 * HALF_EXTENT:
            assert not fits  # a goal farther than the tile is wide (networks: hundreds of m)
        cx, cy = (float(mid[0]), float(mid[1])) if fits else (float(x), float(y))
        row = (TILE - 1) / 2 - (wy - cy) / m_per_px
        col = (TILE - 1) / 2 + (wx - cx) / m_per_px
        assert math.hypot(rows.mean() - row, cols.mean() - col) < 2.0, (i, fits)
        # every tractor pixel within half its diagonal (+ 3 px: the 2 px outline, blended)
        reach = math.hypot(ahead + p["rear_overhang"][i], p["tractor_width"][i] / 2)
        dist = np.hypot(rows - row, cols - col)
        assert dist.max() <= float(reach) / m_per_px + 3.0, (i, dist.max())


@pytest.mark.parametrize(
    ("arg", "says"),
    [("count=0", "count = 0"), ("out=a.jpg", "out = 'a.jpg'"), ("task=nope", "'nope'")],
)
def test_bad_input_is_one_line(arg, says, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        code = main([arg] if arg.startswith("out") else [arg, f"out={tmp_path / 'g.png'}"])
        raise SystemExit(code)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and says in err and len(err.splitlines()) == 1
