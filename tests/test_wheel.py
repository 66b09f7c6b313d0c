"""The built wheel works outside the source tree: ``pip install truckrl-*.whl`` into a fresh venv,
then the entry points find their Hydra configs (shipped as package data) from another directory,
the README's Python example runs against the installed copy, and the wheel carries the license
(in its ``.dist-info``) and the ``py.typed`` marker.

Marked ``wheel`` (minutes: it installs torch and every dependency into a new venv); not in the
default selection, ``make test`` runs it after the default suite (``pytest -m wheel``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

import truckrl
from tests.conftest import ROOT
from tests.test_readme import README, python_example

pytestmark = pytest.mark.wheel

#: The torch build installed first (as the Makefile does): a plain `torch` requirement would
#: resolve to a multi-GB CUDA build.
TORCH = "torch==2.13.0"
SKIP = (".git", ".venv", "outputs", "build", "dist", "*.egg-info", "__pycache__", ".*_cache")


def run(cmd: list, cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    proc = subprocess.run(
        [str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, f"{cmd}: exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc


def test_wheel_installs_in_a_fresh_venv_and_runs_from_elsewhere(tmp_path):
    times: dict[str, float] = {}
    t0 = time.monotonic()
    src = tmp_path / "src"  # a copy: the build writes build/ and *.egg-info next to the sources
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(*SKIP))
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", tmp_path / "dist", src], tmp_path)
    (wheel,) = (tmp_path / "dist").glob("truckrl-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for name in ("train", "evaluate", "play", "export", "control/accel_rate", "experiment/fast"):
        assert f"truckrl/conf/{name}.yaml" in names, name
    assert "truckrl/tasks/intersection/pretrained.pt" in names  # checkpoint=pretrained
    assert "truckrl/py.typed" in names  # PEP 561: the package's annotations are for type checkers
    licenses = [n for n in names if ".dist-info/" in n and n.rsplit("/", 1)[-1] == "LICENSE"]
    assert licenses, "no LICENSE in the wheel's .dist-info"
    for name in ("dock/conf/experiment/dock", "intersection/conf/train_scenes/demos_intersection"):
        assert f"truckrl/tasks/{name}.yaml" in names, name  # the task folders' presets
    times["build"] = time.monotonic() - t0

    t0 = time.monotonic()
    run([sys.executable, "-m", "venv", tmp_path / "venv"], tmp_path)
    py = tmp_path / "venv" / "bin" / "python"
    run([py, "-m", "pip", "install", "--quiet", TORCH], tmp_path)
    run([py, "-m", "pip", "install", "--quiet", wheel], tmp_path)  # with its dependencies
    times["install"] = time.monotonic() - t0

    t0 = time.monotonic()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = run(
        [py, "-c", "import torch, truckrl; print(truckrl.__file__, torch.__version__)"], elsewhere
    )
    location, torch_version = where.stdout.split()
    assert Path(location).is_relative_to(tmp_path / "venv"), location  # the installed copy
    assert torch_version.startswith("2.13.0"), torch_version  # not replaced by another build
    installed = run(
        [py, "-c", "import importlib.metadata as m; print(m.version('truckrl'))"], elsewhere
    )
    assert installed.stdout.strip() == truckrl.__version__  # the metadata reads __version__
    example = python_example(README.read_text())
    assert example is not None, (
        f"{README} has no ```python block: the README's Python example is missing"
    )
    run([py, "-c", example], elsewhere)  # the README's Python example, on the installed copy
    job = run([py, "-m", "truckrl.train", "--cfg", "job"], elsewhere)
    assert "collector:" in job.stdout and "num_envs: 1024" in job.stdout  # experiment=fast
    helped = run([py, "-m", "truckrl.evaluate", "--help"], elsewhere).stdout  # the help template
    assert "Deterministic evaluation" in helped and "checkpoint=" in helped
    assert "format: onnx" in run([py, "-m", "truckrl.export", "--help"], elsewhere).stdout
    script = tmp_path / "venv" / "bin" / "truckrl"  # the console script
    listed = run([script, "--help"], elsewhere).stdout
    assert "usage: truckrl <command>" in listed and len(listed.splitlines()) < 25
    dock = run([script, "train", "experiment=dock", "--cfg", "job"], elsewhere).stdout
    assert "name: dock" in dock  # a task folder's preset, found from the installed package
    crossings = run([script, "train", "--cfg", "job"], elsewhere).stdout
    assert "crossing_prob: 1.0" in crossings  # train_scenes of the default experiment and task
    play = run([py, "-m", "truckrl.play", "headless=true", "max_frames=3"], elsewhere)
    assert "3 frames, 2 steps" in play.stdout
    shipped = run(
        [py, "-m", "truckrl.play", "checkpoint=pretrained", "headless=true", "max_frames=3"],
        elsewhere,
    )
    assert "3 frames, 2 steps" in shipped.stdout
    times["run"] = time.monotonic() - t0
    print("wheel test times [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in times.items()))
