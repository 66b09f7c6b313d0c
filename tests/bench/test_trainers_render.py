"""docs/render.py's ``"benchmark": "trainers"`` record (``truckrl bench trainers``).

The expected rows and fragment are written out by hand from the record below.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def render():
    spec = importlib.util.spec_from_file_location("docs_render_t", ROOT / "docs" / "render.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def record() -> dict:
    """Two trainers x two seeds in the harness's order (seeds outermost), one run failed."""
    run = {"train_s": 240.0, "setup_and_train_s": 243.0, "same_env_as_scored": True}
    return {
        "benchmark": "trainers",
        "args": {
            "minutes": 4.0,
            "seeds": [0, 1],
            "trainers": ["sb3", "cleanrl"],
            "task": "intersection",
            "control": "accel_angle",
            "threads": 1,
            "envs": 128,
            "episodes": 100,
            "eval_seed": 12345,
            "eval_difficulty": 2.0,
            "out": None,
        },  # fmt: skip
        "rows": [
            {
                "trainer": "sb3",
                "seed": 1,
                "frames": 1_200_000,
                "frames/s": 5000.4,
                "difficulty": 2.5,
                "success_fixed": 0.87,
                "success_reached": 0.735,
                **run,
            },
            {
                "trainer": "cleanrl",
                "seed": 1,
                "frames": 1_966_080,
                "frames/s": 8192.0,
                "difficulty": 3.0,
                "success_fixed": 0.9,
                "success_reached": 0.5,
                **run,
            },
            {
                "trainer": "sb3",
                "seed": 0,
                "frames": 980_096,
                "frames/s": 4083.73,
                "difficulty": 2.0,
                "success_fixed": 0.8,
                "success_reached": 0.8,
                **run,
            },
            {"trainer": "cleanrl", "seed": 0, "error": "exit 1"},
        ],  # fmt: skip
        "provenance": {
            "command": "truckrl bench trainers minutes=4 seeds=[0,1] trainers=[sb3,cleanrl]",
            "machine": "Linux, 2 CPUs, load average 4.2",
            "commit": "0123456789abcdef",
            "date": "2026-11-26 19:30 UTC",
            "threads": 1,
        },
    }


def test_trainers_rows_by_trainer_then_seed(render):
    header, rows = render.trainers_tables(record())[""]
    assert header == [
        "trainer",
        "seed",
        "frames",
        "frames/s",
        "difficulty reached",
        "held-out success at 2",
        "held-out success at the difficulty reached",
    ]
    assert rows == [
        ["sb3", "0", "980,096", "4,084", "2", "80.0 %", "80.0 %"],
        ["sb3", "1", "1,200,000", "5,000", "2.5", "87.0 %", "73.5 %"],
        ["cleanrl", "0", "failed (exit 1)", "", "", "", ""],
        ["cleanrl", "1", "1,966,080", "8,192", "3", "90.0 %", "50.0 %"],
    ]


def test_trainers_fragment_has_its_command(render):
    """The record is told apart by its ``benchmark`` key; the fragment ends with the command."""
    assert render.kind_of(record()) is render.trainers_tables
    text = render.fragments(record())[""]
    lines = text.splitlines()
    assert lines[0].startswith("| trainer | seed | frames |")
    assert lines[2] == "| sb3 | 0 | 980,096 | 4,084 | 2 | 80.0 % | 80.0 % |"
    assert "`truckrl bench trainers minutes=4 seeds=[0,1] trainers=[sb3,cleanrl]`" in lines[-1]


def test_trainers_command_rebuilt_without_provenance(render):
    """A record without ``provenance`` gets its command rebuilt from ``args``."""
    doc = record()
    del doc["provenance"]
    assert render.provenance(doc)["command"] == (
        "truckrl bench trainers minutes=4 seeds=[0,1] trainers=[sb3,cleanrl] task=intersection "
        "control=accel_angle envs=128 episodes=100 threads=1"
    )
