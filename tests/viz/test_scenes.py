"""Smoke test of the scene-grid CLI: it writes a PNG of the requested grid size."""

import cv2

from truckrl.viz.scenes import main


def test_cli_writes_png(tmp_path, capsys):
    out = tmp_path / "grid.png"
    main(["--count", "3", "--seed", "1", "--cols", "2", "--tile", "64", "--out", str(out)])
    img = cv2.imread(str(out))
    assert img.shape == (2 * 68 + 4, 2 * 68 + 4, 3)  # 2 x 2 tiles of 64 px, 4 px borders
    assert "wrote" in capsys.readouterr().out
