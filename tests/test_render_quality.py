"""docs/render.py's ``"kind": "quality"`` record: minutes to a good policy, one row per run.

The expected rows are written out by hand from the record below.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def render():
    spec = importlib.util.spec_from_file_location("docs_render_q", ROOT / "docs" / "render.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def record(reached: dict | None) -> dict:
    return {
        "kind": "quality",
        "target": {"success": 0.95, "difficulty": 6.0},
        "runs": [
            {
                "seed": 3,
                "device": "CPU",
                "minutes_to_difficulty_6": 7.84,
                "frames_to_difficulty_6": 25_000_000,
                "checks_at_6": [
                    {"minutes": 9.0, "frames": 30_000_000, "success": 0.91},
                    {"minutes": 12.5, "frames": 40_000_000, "success": 0.955},
                    {"minutes": 14.0, "frames": 45_000_000, "success": 0.93},
                ],
                "quality_reached": reached,
                "stopped": {"minutes": 60, "frames": 200_000_000, "reason": "max_minutes"},
                "final_heldout": {"episodes": 1000, "seed": 12345, "success": 0.978},
            }
        ],
        "provenance": {"command": "truckrl train seed=3", "commit": "abcdef1234" + "5" * 30},
    }


def test_a_run_that_reached_the_target(render):
    header, rows = render.quality_tables(record({"minutes": 12.5, "frames": 40_000_000}))[""]
    assert header[4] == "held-out ≥ 95.0 % at 6"
    assert rows == [
        [
            "3",
            "CPU",
            "7.8 (25.0 M)",
            "95.5 % at 12.5 min",  # the best check, not the last one
            "12.5 min (40.0 M frames)",
            "60 min, 200.0 M frames (max_minutes)",
            "97.8 % of 1,000 (seed 12345)",
        ]
    ]


def test_a_run_that_did_not_says_so_with_its_stop(render):
    _, rows = render.quality_tables(record(None))[""]
    assert rows[0][4] == "not within 60 min"


def test_a_run_that_stopped_below_difficulty_6_names_where(render):
    doc = record(None)
    doc["runs"][0].update(minutes_to_difficulty_6=None, frames_to_difficulty_6=None,
                          difficulty_reached=5.0, checks_at_6=[])  # fmt: skip
    _, rows = render.quality_tables(doc)[""]
    assert rows[0][2:5] == ["not reached (stopped at 5)", "none", "not within 60 min"]


def test_the_record_is_told_from_the_other_kinds_and_gets_its_provenance(render):
    frag = render.fragments(record(None))[""]
    assert frag.splitlines()[0].startswith("| seed | device | minutes (frames) to difficulty 6 |")
    assert "`truckrl train seed=3`" in frag and "commit `abcdef1234`" in frag
