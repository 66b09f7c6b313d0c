"""The scene-grid tool: it writes a PNG of the requested grid size, for any task."""

import cv2
import pytest

from truckrl.tasks import task_names
from truckrl.tools.scenes import main


@pytest.mark.parametrize("task", task_names())
def test_tool_writes_png_of_each_task(task, tmp_path, capsys):
    out = tmp_path / "grid.png"
    args = ["count=3", "seed=1", "cols=2", "tile=64", f"out={out}", f"task={task}"]
    assert main(args) == 0
    img = cv2.imread(str(out))
    assert img.shape == (2 * 68 + 4, 2 * 68 + 4, 3)  # 2 x 2 tiles of 64 px, 4 px borders
    assert f"of task {task}" in capsys.readouterr().out


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
