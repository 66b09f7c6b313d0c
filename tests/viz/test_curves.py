"""Learning-curve rendering from real TensorBoard events written here."""

from torch.utils.tensorboard import SummaryWriter

from truckrl.tools.curves import main
from truckrl.viz.curves import milestones, render, smooth


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


def test_smooth_is_a_moving_average_and_missing_run_fails(tmp_path, capsys):
    assert smooth([1.0, 2.0, 3.0, 4.0, 5.0], 3).tolist() == [1.5, 2.0, 3.0, 4.0, 4.5]
    assert main([f"run={tmp_path / 'nope'}"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: run = ") and "no TensorBoard directory" in err
    assert len(err.splitlines()) == 1
