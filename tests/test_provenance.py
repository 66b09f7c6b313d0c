"""The provenance every figure's JSON carries (truckrl.cli.provenance): the command as typed."""

import re

import pytest

from truckrl.cli import invoked_command, provenance


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (
            ["truckrl eval", "checkpoint=pretrained", "difficulty=6"],
            "truckrl eval checkpoint=pretrained difficulty=6",
        ),
        (
            ["/x/.venv/bin/truckrl", "bench", "env", "envs=[1024]"],
            "truckrl bench env 'envs=[1024]'",
        ),
        (["/x/truckrl/evaluate.py", "seed=1"], "python /x/truckrl/evaluate.py seed=1"),
    ],
)
def test_the_command_is_the_one_typed(argv, expected):
    assert invoked_command(argv) == expected


def test_provenance_names_commit_date_machine_and_threads(monkeypatch):
    monkeypatch.setattr("sys.argv", ["truckrl eval", "episodes=3"])
    monkeypatch.setattr("truckrl.cli.TYPED_ARGV", [])  # an in-process command earlier kept its own
    p = provenance("cpu")
    assert p["command"] == "truckrl eval episodes=3"
    assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?|not recorded.*", p["commit"])
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", p["date"])
    assert "CPUs" in p["machine"] and p["threads"] >= 1 and p["device"] == "cpu"


def test_an_eval_json_names_the_command_as_typed(tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "e.json"
    args = ["eval", "checkpoint=pretrained", "episodes=2", f"output={out}"]
    subprocess.run([sys.executable, "-m", "truckrl", *args], check=True, capture_output=True)
    p = json.loads(out.read_text())["provenance"]
    assert p["command"] == f"truckrl eval checkpoint=pretrained episodes=2 output={out}"
