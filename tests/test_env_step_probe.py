"""launch/env_step_probe.py: the side-by-side env probe runs and rejects bad input."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROBE = ROOT / "launch" / "env_step_probe.py"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(PROBE), *args], capture_output=True, text=True, cwd=ROOT, timeout=300
    )


def test_probe_prints_a_median_rate():
    out = run("--eager", "--envs", "4", "--warmup", "2", "--steps", "3", "--windows", "2",
              "--beams", "8")  # fmt: skip
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip().splitlines()[-1]
    assert "N=4 R=8 compile=False" in line and "env-steps/s" in line and "windows:" in line


def test_probe_rejects_bad_input_with_exit_2():
    out = run("--steps", "0")
    assert out.returncode == 2
    assert "--steps 0: must be >= 1" in out.stderr
