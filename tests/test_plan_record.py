"""``truckrl plan``'s JSON carries a ``provenance`` record (the docs print it under the figures)."""

from __future__ import annotations

import json

from truckrl import cli
from truckrl.plan import main


def test_the_plan_json_names_its_command_commit_and_machine(tmp_path, monkeypatch):
    out = tmp_path / "plan.json"
    args = ["episodes=1", "planner.samples=8", "planner.iterations=1", "planner.attempts=1"]
    args += ["planner.compile=false", "quiet=true", f"out={out}"]
    monkeypatch.setattr(cli, "TYPED_ARGV", ["truckrl", "plan", *args])
    assert main(args) == 0
    prov = json.loads(out.read_text())["provenance"]
    assert prov["command"] == "truckrl plan " + " ".join(args)
    assert prov["device"] == "cpu" and prov["threads"] == 1  # plan's default threads=1
    assert set(prov) >= {"machine", "commit", "date", "load_avg_1min"}
