"""Shared test fixtures: one tiny checkpoint, Hydra composition, and the CLI runner.

Subprocess tests of the real entry points are marked ``e2e`` (kept in the default suite); they
pass ``env.compile=false``, ``ppo.compile=false`` and ``collector.compile_policy=false``
because compiling the step, the loss or the rollout policy costs 5-20 s per process.

Under pytest-xdist (``-n 2``, one worker per core) each worker runs torch on one thread, and so
does every process it starts (``OMP_NUM_THREADS=1`` in its environment): two workers with two
intra-op threads each would contend for the two cores. A test that sets ``threads`` itself still
gets what it sets.

``OMP_WAIT_POLICY=PASSIVE`` (set before torch loads its OpenMP runtime, so for this process and
every process it starts): an idle intra-op thread sleeps instead of spinning. The tests' tensors
are tiny, so with two threads the spinning cost as much CPU as the work (a ``threads=2`` tiny
training run: 12 s of CPU spinning, 6 s passive, the same bits either way) and, on two
cores, took it from the other test process. It changes how threads wait, not the arithmetic.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads OpenMP (docstring)

import subprocess  # noqa: E402
import sys  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import torch  # noqa: E402
import yaml  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402

from truckrl.cli import CONFIG_PATH, to_config, with_task_presets  # noqa: E402
from truckrl.config.schemas import TrainConfig, register  # noqa: E402
from truckrl.rl.checkpoint import save_training_state  # noqa: E402
from truckrl.rl.curriculum import Curriculum  # noqa: E402
from truckrl.rl.network import make_actor_critic  # noqa: E402
from truckrl.rl.ppo import PPO  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def pytest_configure(config):
    """One torch thread per xdist worker and per process it starts (see the module docstring)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        os.environ["OMP_NUM_THREADS"] = "1"
        torch.set_num_threads(1)


#: Overrides that make a training run take seconds.
TINY_TRAIN = [
    "collector.num_envs=16",
    "collector.steps_per_env=16",
    "ppo.num_minibatches=2",
    "ppo.num_epochs=1",
    "log.video_interval=0",
    "log.progress_bar=false",
    "env.compile=false",
    "ppo.compile=false",
    "collector.compile_policy=false",
    "demos.episodes=0",  # the default experiment=demos would plan 600 scenes first
    "demos.bc_coeff=0",  # ... and keep cloning them
]
TINY_BATCH = 16 * 16  # frames per iteration with TINY_TRAIN


def compose_config(name: str, *overrides: str):
    """The Hydra config ``conf/<name>.yaml`` composed with ``overrides`` (no run dir), with the
    task folders' presets on the search path as the entry points have them."""
    register()
    with initialize_config_dir(config_dir=CONFIG_PATH, version_base=None):
        return compose(name, overrides=with_task_presets(list(overrides)))


def run_cli(module: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m truckrl.<module> args...`` from the repo root; output captured."""
    return subprocess.run(
        [sys.executable, "-m", f"truckrl.{module}", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory):
    """A checkpoint in the format training writes (untrained weights, 40-step episodes).

    Returns ``(run_dir, actor_critic, train_config)``.
    """
    cfg = compose_config("train", "env.max_steps=40", "env.compile=false", "collector.num_envs=4")
    tc = to_config(TrainConfig, cfg)
    torch.manual_seed(0)
    beams = tc.env.lidar.num_beams
    ac = make_actor_critic(tc.model, 26, beams)
    run = tmp_path_factory.mktemp("run")
    save_training_state(
        run / "checkpoints" / "last.pt",
        model=ac.model,
        ppo=PPO(ac, tc.ppo),
        curriculum=Curriculum(tc.curriculum),
        counters={"iteration": 3, "frames": 300, "wall_time_s": 1.0},
        config_yaml=yaml.safe_dump(asdict(tc)),
        num_obs=26,
        num_beams=beams,
    )
    return run, ac, tc
