"""``python -m truckrl.evaluate``: deterministic, self-consistent results and clear errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from truckrl.agent.checkpoint import CheckpointError, save_checkpoint
from truckrl.agent.curriculum import Curriculum
from truckrl.agent.network import make_actor_critic
from truckrl.agent.ppo import PPO
from truckrl.agent.rollout import evaluate_policy
from truckrl.evaluate import evaluate
from truckrl.train import CONFIG_PATH, Counters, TrainConfig, checkpoint_state

ROOT = Path(__file__).resolve().parent.parent
MAX_STEPS = 40


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A checkpoint in the format truckrl.train writes (untrained weights, short episodes)."""
    with initialize_config_dir(config_dir=CONFIG_PATH, version_base=None):
        cfg = compose("train", overrides=[f"env.max_steps={MAX_STEPS}", "env.num_envs=4"])
    tc = TrainConfig.from_hydra(cfg)
    torch.manual_seed(0)
    ac = make_actor_critic(tc.model, 26, tc.env.lidar.num_beams)
    state = checkpoint_state(
        ac,
        PPO(ac, tc.ppo),
        Curriculum(tc.curriculum),
        Counters(iteration=3, frames=300),
        OmegaConf.to_yaml(cfg, resolve=True),
        tc.seed,
        (26, tc.env.lidar.num_beams),
    )
    run = tmp_path_factory.mktemp("run")
    save_checkpoint(run / "checkpoints" / "last.pt", state)
    return run, ac, tc


def test_outcomes_agree_with_final_errors(trained):
    _, ac, tc = trained
    res, (tol_m, tol_deg) = evaluate_policy(ac.actor, tc.env, 0.0, episodes=24, seed=5)
    assert tol_m == pytest.approx(30.0) and tol_deg == pytest.approx(60.0)  # paper: difficulty 0
    ended = res["success"] | res["collision"] | res["jackknife"] | res["truncated"]
    assert ended.all()
    s = res["success"]
    assert (res["pos_error"][s] <= tol_m).all()
    assert (res["tractor_heading_error"][s] <= tol_deg + 1e-4).all()
    assert (res["trailer_heading_error"][s] <= tol_deg + 1e-4).all()
    assert (res["length"][res["truncated"]] == MAX_STEPS).all()
    assert ((res["length"] >= 1) & (res["length"] <= MAX_STEPS)).all()


def test_cli_is_deterministic_and_matches_in_process_run(trained, tmp_path):
    run, ac, tc = trained
    out = tmp_path / "eval.json"
    cmd = [sys.executable, "-m", "truckrl.evaluate", f"checkpoint={run}", "episodes=12"]
    cmd += ["seed=7", "difficulty=1", f"output={out}", f"hydra.run.dir={tmp_path}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout.strip().splitlines()[-1])
    written = json.loads(out.read_text())
    assert printed["success_rate"] == written["success_rate"]
    assert written["episodes"] == 12 and written["difficulty"] == 1.0
    assert written["tolerance_position_m"] == pytest.approx(15.0)  # 30 m x 2^-1
    res, _ = evaluate_policy(ac.actor, tc.env, 1.0, episodes=12, seed=7)
    assert written["success_rate"] == pytest.approx(res["success"].float().mean().item())
    assert written["pos_error_m_mean"] == pytest.approx(res["pos_error"].mean().item(), rel=1e-5)
    assert written["pos_error_m_p95"] <= res["pos_error"].max().item() + 1e-6


def test_missing_checkpoint_is_one_line(tmp_path):
    cmd = [sys.executable, "-m", "truckrl.evaluate", f"checkpoint={tmp_path / 'nope.pt'}"]
    cmd += [f"hydra.run.dir={tmp_path}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("CheckpointError:") and "nope.pt" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_corrupt_checkpoint_raises_checkpoint_error(trained, tmp_path):
    run, _, _ = trained
    bad = tmp_path / "bad.pt"
    bad.write_bytes((run / "checkpoints" / "last.pt").read_bytes()[:500])
    cfg = OmegaConf.create(
        {"checkpoint": str(bad), "difficulty": None, "episodes": 2, "seed": 0}
        | {"device": "cpu", "output": None}
    )
    with pytest.raises(CheckpointError, match="cannot read"):
        evaluate(cfg, tmp_path)
