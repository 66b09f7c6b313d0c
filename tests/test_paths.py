"""``truckrl tools paths`` and its parts: recorded paths, the scene filter, the drawing."""

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.planning import held_out_states
from truckrl.rl.policy import load_policy
from truckrl.tasks import EnvConfig
from truckrl.tools.paths import main, select
from truckrl.viz.draw import make_view, world_to_pixel
from truckrl.viz.paths import PATH_COLOR, draw_path, grid


def test_recorded_paths_start_at_the_start_and_stop_with_the_episode(tiny_checkpoint):
    run, _, _ = tiny_checkpoint
    pol = load_policy(run)
    res, _, _ = evaluate_policy(pol.actor, pol.env_config, 0.0, 5, 3, record_paths=True)
    starts = held_out_states(pol.env_config, 5, 3, "cpu", 0.0)
    path = res["path"]
    assert path.shape[0] == 5 and path.shape[2] == 4
    assert path.shape[1] == int(res["length"].max()) + 1  # the start, then one pose per step
    assert torch.equal(path[:, 0], starts["pose"])
    for i, n in enumerate(res["length"].long().tolist()):  # held once the episode has ended
        assert (path[i, n:] == path[i, n]).all()


def test_select_keeps_the_episodes_in_every_named_bin_of_the_task():
    results = {
        "success": torch.tensor([True, False, False, True]),
        "route": torch.tensor([3, 3, 2, 3]),
        "turn_angle": torch.tensor([-2.0, -1.0, 2.0, -2.5]),  # rad: 114.6, 57.3, 114.6, 143.2 deg
        "trailer_length": torch.full((4,), 12.0),
        "crossing_angle": torch.full((4,), 1.5),
        "start_road_width": torch.full((4,), 14.0),
        "goal_road_width": torch.full((4,), 14.0),
        "goal_distance": torch.full((4,), 50.0),
    }
    task = "intersection"
    assert select(results, task, ("route right",)).tolist() == [True, True, False, True]
    both = ("route right", "turn [deg] right 110-180")
    assert select(results, task, both).tolist() == [True, False, False, True]
    assert select(results, task, ()).all()
    with pytest.raises(ConfigError, match="category = 'route diagonal': task 'intersection' has"):
        select(results, task, ("route diagonal",))


def test_draw_path_puts_the_trace_where_the_truck_went():
    start = held_out_states(EnvConfig(compile=False), 1, 0, "cpu", 0.0)[0]
    goal = start["goal"][:2]
    x = torch.linspace(0.0, 1.0, 21)[:, None]  # a straight trace from 10 m left of the goal
    xy = goal + torch.tensor([-10.0, 0.0]) + x * torch.tensor([10.0, 0.0])
    path = torch.cat([xy, torch.zeros(21, 2)], 1)
    img = draw_path(start, path, every=100, size_px=200, view_half_extent=30.0)
    assert img.shape == (200, 200, 3) and img.dtype == np.uint8
    view = make_view(200, (0.5 * (path[0, :2] + goal)).numpy(), view_half_extent=30.0)
    mid = np.round(world_to_pixel((goal + torch.tensor([-5.0, 0.0])).numpy(), view)).astype(int)
    assert np.abs(img[mid[1], mid[0]].astype(int) - PATH_COLOR).max() < 40
    with pytest.raises(ValueError, match="every"):
        draw_path(start, path, every=0)


def test_grid_lays_rows_and_columns_with_gaps():
    a = np.zeros((10, 20, 3), np.uint8)
    g = grid([[a, a, a], [a, a, a]], gap_px=2)
    assert g.shape == (22, 64, 3)
    assert (g[10:12] == 255).all() and (g[:, 20:22] == 255).all() and (g[:10, :20] == 0).all()


def test_cli_draws_one_row_per_checkpoint_in_the_same_scenes(tiny_checkpoint, tmp_path, capsys):
    run, _, _ = tiny_checkpoint
    out = tmp_path / "p.png"
    args = [f"checkpoints=[{run},{run}]", "episodes=6", "count=2", "outcome=any"]
    assert main([*args, "labels=[a,b]", f"out={out}", "threads=1"]) == 0
    import cv2

    img = cv2.imread(str(out))
    assert img.shape == (2 * 360 + 4, 2 * 360 + 4, 3)
    top, bottom = img[:360], img[364:]
    label_rows = 30  # the labels differ ("a" / "b"); the drawings must not
    assert np.array_equal(top[label_rows:], bottom[label_rows:])
    # each of the row's two tiles shows a scene with a driven path (PATH_COLOR, RGB; cv2 reads
    # BGR), not a blank or uniform tile
    for tile in (top[label_rows:, :360], top[label_rows:, 364:]):
        assert len(np.unique(tile.reshape(-1, 3), axis=0)) > 20
        path_px = (np.abs(tile[..., ::-1].astype(int) - PATH_COLOR).max(-1) < 40).sum()
        assert path_px > 10, path_px
    text = capsys.readouterr().out
    assert "6 of 6 scenes (seed 12345" in text and "drawn: scenes [0, 1]" in text


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["category=route diagonal"], "category = 'route diagonal': task "),
        (["labels=[a,b]"], "labels: 2 given for 1 checkpoints"),
        (["count=0"], "count = 0 is outside the allowed range [1, 64]"),
        (["difficulty=31"], "difficulty = 31 is outside the allowed range [0.0, 30.0]"),
        (["outcome=won"], "outcome = 'won' is not one of"),
        (["--route", "right"], "'--route': arguments are KEY=VALUE"),
    ],
)
def test_bad_options_are_one_line(tiny_checkpoint, tmp_path, capsys, extra, message):
    run, _, _ = tiny_checkpoint
    try:
        code = main([f"checkpoints={run}", f"out={tmp_path / 'p.png'}", "episodes=4", *extra])
    except SystemExit as e:  # bad KEY=VALUE input exits while parsing
        code = e.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "p.png").exists()
