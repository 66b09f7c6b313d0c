"""``python -m truckrl.evaluate``: deterministic, self-consistent results and clear errors."""

from __future__ import annotations

import json

import pytest

from tests.conftest import run_cli
from truckrl.agent.checkpoint import CheckpointError
from truckrl.agent.rollout import evaluate_policy
from truckrl.configs import EvaluateConfig
from truckrl.evaluate import evaluate

MAX_STEPS = 40  # the tiny checkpoint's env.max_steps


def test_outcomes_agree_with_final_errors(tiny_checkpoint):
    _, ac, tc = tiny_checkpoint
    res, (tol_m, tol_deg), _ = evaluate_policy(ac.actor, tc.env, 0.0, episodes=24, seed=5)
    assert tol_m == pytest.approx(30.0) and tol_deg == pytest.approx(60.0)  # paper: difficulty 0
    ended = res["success"] | res["collision"] | res["jackknife"] | res["truncated"]
    assert ended.all()
    s = res["success"]
    assert (res["pos_error"][s] <= tol_m).all()
    assert (res["tractor_heading_error"][s] <= tol_deg + 1e-4).all()
    assert (res["trailer_heading_error"][s] <= tol_deg + 1e-4).all()
    assert (res["length"][res["truncated"]] == MAX_STEPS).all()
    assert ((res["length"] >= 1) & (res["length"] <= MAX_STEPS)).all()


@pytest.mark.e2e
def test_cli_is_deterministic_and_matches_in_process_run(tiny_checkpoint, tmp_path):
    run, ac, tc = tiny_checkpoint
    out = tmp_path / "eval.json"
    args = [f"checkpoint={run}", "episodes=12", "seed=7", "difficulty=1", f"output={out}"]
    proc = run_cli("evaluate", *args, f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout.strip().splitlines()[-1])
    written = json.loads(out.read_text())
    assert printed["success_rate"] == written["success_rate"]
    assert written["episodes"] == 12 and written["difficulty"] == 1.0
    assert written["tolerance_position_m"] == pytest.approx(15.0)  # 30 m x 2^-1
    res, _, _ = evaluate_policy(ac.actor, tc.env, 1.0, episodes=12, seed=7)
    assert written["success_rate"] == pytest.approx(res["success"].float().mean().item())
    assert written["pos_error_m_mean"] == pytest.approx(res["pos_error"].mean().item(), rel=1e-5)
    assert written["pos_error_m_p95"] <= res["pos_error"].max().item() + 1e-6


@pytest.mark.e2e
def test_missing_checkpoint_is_one_line(tmp_path):
    proc = run_cli("evaluate", f"checkpoint={tmp_path / 'nope.pt'}", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("error:") and "nope.pt" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_corrupt_checkpoint_raises_checkpoint_error(tiny_checkpoint, tmp_path):
    run, _, _ = tiny_checkpoint
    bad = tmp_path / "bad.pt"
    bad.write_bytes((run / "checkpoints" / "last.pt").read_bytes()[:500])
    with pytest.raises(CheckpointError, match="cannot read"):
        evaluate(EvaluateConfig(checkpoint=str(bad), episodes=2, seed=0), tmp_path)
