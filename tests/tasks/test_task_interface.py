"""The task interface: a second task (tests/tasks/reach/) runs through the unchanged env,
agent and evaluation; the task core runs without TorchRL."""

import subprocess
import sys

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from tests.tasks.reach.task import ReachConfig
from truckrl.env import TruckEnv
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.rl.metrics import EpisodeTracker
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.tasks import EnvConfig, make_task


def reach_env(n=8, **task):
    return TruckEnv(num_envs=n, config=EnvConfig(task=ReachConfig(**task), max_steps=30), seed=0)


def test_second_task_runs_through_the_unchanged_env():
    env = reach_env()
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["observation"].shape == (8, 27)  # 26 shared + the task's one extra
    assert set(env.task.reward_keys) == {"r_approach", "r_bonus"}

    # full speed ahead: the approach reward is the distance covered, the errors are the task's
    def full_ahead(td):
        return td.set("action", torch.tensor([[1.0, 0.0]] * 8))

    td = env.rollout(3, full_ahead)
    covered = 20.0 - td["next", "distance_error"][:, -1, 0]
    torch.testing.assert_close(td["next", "r_approach"].sum((1, 2)), covered, rtol=1e-5, atol=1e-5)
    assert torch.allclose(
        td["next", "observation"][..., 26], td["next", "distance_error"][..., 0] / 50
    )


def test_second_task_success_and_its_config_values():
    env = reach_env(n=2, distance=2.0, bonus=3.0)
    env.set_difficulty(0.0)  # 30 m tolerance: already within it after one step
    td = env.reset()
    nxt = env.step(td.set("action", torch.zeros(2, 2)))["next"]
    assert nxt["success"].all() and (nxt["r_bonus"] == 3.0).all()


def test_agent_and_evaluation_run_the_second_task():
    cfg = EnvConfig(task=ReachConfig(), max_steps=20)
    task = make_task(cfg)
    ac = make_actor_critic(ModelConfig(), task.num_features, cfg.lidar.num_beams)
    results, _, errors = evaluate_policy(ac.actor, cfg, 3.0, episodes=6, seed=1)
    assert [q.key for q in errors] == ["distance_error"]
    assert results["distance_error"].shape == (6,)
    # goals 40 m ahead (beyond the 30 m tolerance): the untrained policy's episodes time out
    # after 30 steps; the tracker's figures, counted here from the batch
    env = reach_env(distance=40.0)
    with torch.no_grad():
        batch = env.rollout(35, ac.actor, break_when_any_done=False)
    stats = EpisodeTracker(task.reward_keys, errors).update(batch)
    nxt = batch["next"]
    done = nxt["done"].squeeze(-1)
    assert stats["episodes"] == done.sum() == 8 and stats["timeout_rate"] == 1.0
    assert stats["length"] == 30.0
    final = nxt["distance_error"].squeeze(-1)[done]
    assert stats["final_distance_error"].item() == pytest.approx(final.mean().item(), rel=1e-6)
    approach = nxt["r_approach"].squeeze(-1)[:, :30].sum(-1)  # each env's first episode
    assert stats["return/r_approach"].item() == pytest.approx(approach.mean().item(), abs=1e-5)


def test_task_core_runs_without_torchrl():
    code = (
        "import sys, torch\n"
        "from truckrl.tasks import EnvConfig, make_task\n"
        "t = make_task(EnvConfig())\n"
        "s = t.sample(4, torch.Generator().manual_seed(0), torch.device('cpu'))\n"
        "flat = {k: s[k] for k in s.keys() if k not in ('params', 'route', 'kind')}\n"
        "flat['params'] = {k: s['params', k] for k in s['params'].keys()}\n"
        "new, out = t.transition(torch.zeros(4, 2), flat, torch.zeros(4))\n"
        "assert out['observation'].shape == (4, 26)\n"
        "assert not any(m.startswith('torchrl') for m in sys.modules), 'torchrl imported'\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
