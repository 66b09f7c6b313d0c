"""``python -m truckrl.bench env``: a quick run within its budget, and one-line option errors."""

import json

import pytest

from tests.conftest import run_cli

pytestmark = pytest.mark.e2e


def test_quick_run_prints_its_time_and_writes_json(tmp_path):
    proc = run_cli("bench", "env", "--quick", "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith("bench env took"))
    seconds = float(line.split()[3])
    assert seconds < 60  # budget 15 s on an idle 2-core machine; generous under CI load
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    assert {r["trucks"] for r in record["rows"]} == {1, 256}


@pytest.mark.parametrize(
    "args", [["--workers", "0"], ["--envs", "0"], ["--steps", "0"], ["--device", "nope"]]
)
def test_bad_options_are_one_line_exit_2(args, tmp_path):
    proc = run_cli("bench", "env", *args, "--out", str(tmp_path))
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("error:") and len(proc.stderr.strip().splitlines()) == 1


def test_every_option_has_help():
    proc = run_cli("bench", "env", "--help")
    assert proc.returncode == 0
    for opt in ("--quick", "--envs", "--workers", "--parallel-envs", "--steps", "--compile"):
        line = next(x for x in proc.stdout.splitlines() if x.strip().startswith(opt))
        assert len(line.strip()) > len(opt) + 8, opt  # followed by a description
