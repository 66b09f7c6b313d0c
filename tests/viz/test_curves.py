"""Learning-curve rendering from real TensorBoard events written here."""

import numpy as np
from torch.utils.tensorboard import SummaryWriter

from truckrl.tools.curves import main
from truckrl.viz.curves import LINE_COLORS, milestones, render, smooth


def _write_run(tmp_path):
    w = SummaryWriter(log_dir=str(tmp_path / "tb"))
    for i, d in enumerate([0, 0, 0.5, 0.5, 1.0, 1.0]):
        w.add_scalar("curriculum/difficulty", d, global_step=(i + 1) * 100)
        w.add_scalar("episode/success_rate", 0.1 * i, global_step=(i + 1) * 100)
        w.add_scalar("episode/final_pos_error_m", 30 - i, global_step=(i + 1) * 100)
    w.close()


def test_milestones_and_png(tmp_path, capsys):
    _write_run(tmp_path)
    assert main([f"run={tmp_path}", f"out={tmp_path / 'c.png'}"]) == 0
    assert (tmp_path / "c.png").stat().st_size > 1000
    out = capsys.readouterr().out
    assert "| 0.5 |" in out and "| 1 |" in out
    from truckrl.viz.curves import load_scalars

    rows = milestones(load_scalars(tmp_path))
    assert [(r["difficulty"], r["frames"]) for r in rows] == [(0, 100), (0.5, 300), (1.0, 500)]
    img = render(load_scalars(tmp_path), width=400, panel_h=120)
    assert img.shape == (360, 400, 3)
    import cv2

    png = cv2.imread(str(tmp_path / "c.png"))[..., ::-1]  # BGR -> RGB
    blue = (np.abs(png.astype(int) - LINE_COLORS[0]).max(-1) < 30).sum()
    assert blue > 100  # the curves are drawn, not only the frame


def _plot_box(panel):
    """Rows and columns ``(top, bottom, left, right)`` of a panel's grey plot frame, found in
    the image: the rows and columns with the most frame grey (120, 120, 120)."""
    grey = (panel == 120).all(-1)
    per_row, per_col = grey.sum(1), grey.sum(0)
    rows = np.flatnonzero(per_row > 0.5 * per_row.max())
    cols = np.flatnonzero(per_col > 0.5 * per_col.max())
    return rows.min(), rows.max(), cols.min(), cols.max()


def test_render_draws_each_series_where_its_values_put_it():
    # 10 minutes; difficulty 0 -> 1, success rate 0.25 throughout, error 30 -> 10 m, all linear
    # (the 5-sample moving average leaves a line unchanged away from its ends)
    t = np.linspace(0.0, 10.0, 21)
    frames = np.arange(21) * 100.0
    scalars = {
        "curriculum/difficulty": np.stack((t, frames, t / 10.0), -1),
        "episode/success_rate": np.stack((t, frames, np.full(21, 0.25)), -1),
        "episode/final_pos_error_m": np.stack((t, frames, 30.0 - 2.0 * t), -1),
    }
    img = render(scalars, width=400, panel_h=120)
    assert img.shape == (360, 400, 3)
    # at 3 min (0.3 of the time axis), in each panel's frame (y axis from 0 to the top of its
    # range): difficulty 0.3 of [0, 1], success 0.25 of [0, 1], error 24 of [0, 30]
    for k, frac in enumerate((0.3, 0.25, 24.0 / 30.0)):
        panel = img[120 * k : 120 * (k + 1)]
        top, bottom, left, right = _plot_box(panel)
        x, y = round(left + 0.3 * (right - left)), round(bottom - frac * (bottom - top))
        near = panel[y - 1 : y + 2, x - 1 : x + 2].astype(int)
        assert (np.abs(near - LINE_COLORS[0]).max(-1) < 40).any(), (k, x, y)
        # and not at the mirror height
        y_mirror = round(top + frac * (bottom - top))
        far = panel[y_mirror - 1 : y_mirror + 2, x - 1 : x + 2].astype(int)
        assert not (np.abs(far - LINE_COLORS[0]).max(-1) < 40).any(), (k, x, y_mirror)


def test_smooth_is_a_moving_average_and_missing_run_fails(tmp_path, capsys):
    assert smooth([1.0, 2.0, 3.0, 4.0, 5.0], 3).tolist() == [1.5, 2.0, 3.0, 4.0, 4.5]
    assert main([f"run={tmp_path / 'nope'}"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: run = ") and "no TensorBoard directory" in err
    assert len(err.splitlines()) == 1
