"""``python -m truckrl.tasks.network.tools.solvable``: its record and its one-line errors."""

from __future__ import annotations

import json

import pytest

from truckrl.tasks.network.tools.solvable import main


def test_the_record_counts_every_episode(tmp_path, capsys):
    out = tmp_path / "driver.json"
    args = ["episodes=6", "difficulties=[0,1]", "traffic=[1,0]", f"out={out}"]
    assert main(args) == 0
    data = json.loads(out.read_text())
    assert [(r["difficulty"], r["traffic_share"]) for r in data["runs"]] == [
        (0.0, 1.0), (0.0, 0.0), (1.0, 1.0), (1.0, 0.0),
    ]  # fmt: skip
    for r in data["runs"]:
        rates = r["success_rate"] + r["collision_rate"] + r["jackknife_rate"] + r["timeout_rate"]
        assert rates == pytest.approx(1.0)  # every episode ends one way
        failed = round(r["episodes"] * (1.0 - r["success_rate"]))
        assert r["failed_before_goal"] + r["failed_at_goal"] + r["failed_past_goal"] == failed
        junctions = [c for c in r["categories"] if c["dimension"] == "junctions"]
        assert sum(c["count"] for c in junctions) == r["episodes"]
    assert data["tolerances"]["1"] == pytest.approx([15.0, 30.0])
    head = data["runs"][2]  # the last difficulty, the first share: docs/render.py's table
    assert (data["difficulty"], data["traffic_share"]) == (1.0, 1.0)
    assert data["success_rate"] == head["success_rate"] and data["categories"] == head["categories"]
    assert (data["tolerance_position_m"], data["tolerance_heading_deg"]) == pytest.approx(
        (15.0, 30.0)
    )
    assert "difficulty 1, traffic x0" in capsys.readouterr().out


@pytest.mark.parametrize(("arg", "field"), [("episodes=0", "episodes"), ("traffic=[2]", "traffic")])
def test_bad_input_is_one_line_and_exit_code_2(arg, field, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([arg, "out=null"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and field in err
