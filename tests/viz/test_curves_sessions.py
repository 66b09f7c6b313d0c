"""load_scalars counts the minutes of training sessions, not the time a run lay stopped."""

from pathlib import Path

import numpy as np
from torch.utils.tensorboard import SummaryWriter

from truckrl.viz.curves import load_scalars


def _session(tb: Path, pid: str, points: list[tuple[float, int, float]]) -> None:
    """One session's event file, renamed to carry ``pid`` as its writer's process id."""
    before = set(tb.glob("events.out.tfevents.*"))
    w = SummaryWriter(str(tb))
    for wall, step, value in points:
        w.add_scalar("curriculum/difficulty", value, step, walltime=wall)
    w.close()
    (new,) = set(tb.glob("events.out.tfevents.*")) - before
    parts = new.name.split(".")
    parts[3] = str(int(points[0][0]))  # the start time in the name orders the sessions
    parts[-2] = pid
    new.rename(new.with_name(".".join(parts)))


def test_a_resumed_run_counts_no_gap_between_sessions(tmp_path):
    tb = tmp_path / "tb"
    tb.mkdir()
    _session(tb, "111", [(1000.0, 0, 0.0), (1060.0, 100, 1.0)])  # 1 min of training
    _session(tb, "222", [(5000.0, 200, 1.5), (5120.0, 300, 2.0)])  # an hour later: 2 more min
    d = load_scalars(tmp_path)["curriculum/difficulty"]
    np.testing.assert_allclose(d[:, 0], [0.0, 1.0, 1.0, 3.0])  # by hand: gaps of 0, then 2 min
    np.testing.assert_array_equal(d[:, 1], [0, 100, 200, 300])
    np.testing.assert_array_equal(d[:, 2], [0.0, 1.0, 1.5, 2.0])
