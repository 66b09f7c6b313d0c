"""Episode statistics: per-episode sums across batch boundaries vs a Python loop."""

import pytest
import torch
from tensordict import TensorDict

from truckrl.env import TruckEnv
from truckrl.rl.metrics import EpisodeTracker, episode_sums, finished_in_time_order
from truckrl.tasks import EnvConfig
from truckrl.tasks.intersection.task import IntersectionTask

REWARD_TERMS = IntersectionTask.reward_keys
ERRORS = IntersectionTask.error_quantities


def loop_sums(x, done, carry):
    """Oracle: walk each env's steps, closing an episode at every done."""
    e, t, k = x.shape
    sums = torch.full_like(x, float("nan"))
    carry = carry.clone()
    for i in range(e):
        run = carry[i].clone()
        for j in range(t):
            run += x[i, j]
            if done[i, j]:
                sums[i, j] = run
                run = torch.zeros(k)
        carry[i] = run
    return sums, carry


def test_episode_sums_match_a_loop_over_two_batches():
    g = torch.Generator().manual_seed(0)
    carry = torch.zeros(5, 3)
    ref_carry = carry.clone()
    for _ in range(2):  # the second batch continues the episodes left open by the first
        x = torch.randn(5, 9, 3, generator=g, dtype=torch.float64).float()
        done = torch.rand(5, 9, generator=g) < 0.25
        sums, carry = episode_sums(x, done, carry)
        ref, ref_carry = loop_sums(x, done, ref_carry)
        torch.testing.assert_close(sums[done], ref[done])
        torch.testing.assert_close(carry, ref_carry)


def fake_batch(done, success, pos_error, step_count, r):
    """A [E, T] batch with the env's keys (values chosen by hand)."""
    e, t = done.shape
    col = lambda v: v.reshape(e, t, 1)  # noqa: E731
    nxt = {k: torch.zeros(e, t, 1) for k in ("reward", *REWARD_TERMS)}
    nxt["reward"] = col(r)
    nxt["r_progress"] = col(r)
    nxt.update(
        done=col(done),
        truncated=torch.zeros(e, t, 1, dtype=torch.bool),
        success=col(success),
        collision=col(~success & done),
        jackknife=torch.zeros(e, t, 1, dtype=torch.bool),
        pos_error=col(pos_error),
        tractor_heading_error=torch.zeros(e, t, 1),
        trailer_heading_error=torch.zeros(e, t, 1),
        step_count=col(step_count),
        difficulty=torch.zeros(e, t, 1),
    )
    return TensorDict({"next": nxt}, [e, t])


def test_tracker_statistics_by_hand():
    done = torch.tensor([[False, True, False], [False, False, True]])
    success = torch.tensor([[False, True, False], [False, False, False]])
    pos = torch.tensor([[9.0, 1.0, 9.0], [9.0, 9.0, 3.0]])
    steps = torch.tensor([[4, 5, 1], [7, 8, 9]])
    r = torch.tensor([[1.0, 2.0, 4.0], [1.0, 1.0, 1.0]])
    stats = EpisodeTracker(REWARD_TERMS, ERRORS).update(fake_batch(done, success, pos, steps, r))
    assert stats["episodes"] == 2
    assert stats["success_rate"] == 0.5 and stats["collision_rate"] == 0.5
    assert stats["final_pos_error"] == pytest.approx(2.0)  # (1 + 3) / 2
    assert stats["length"] == pytest.approx(7.0)  # (5 + 9) / 2
    assert stats["return/reward"] == pytest.approx(3.0)  # (1 + 2 and 1 + 1 + 1) / 2
    assert stats["step/reward"] == pytest.approx(10.0 / 6)
    # time order: env 0 ended at t=1, env 1 at t=2
    assert finished_in_time_order(fake_batch(done, success, pos, steps, r), "success").tolist() == [
        True,
        False,
    ]


def test_real_env_episode_end_values_belong_to_the_finished_episode():
    # 4-step episodes: goals within 30 m end in one step, the others time out after 4
    env = TruckEnv(num_envs=64, seed=0, config=EnvConfig(max_steps=4))
    td = env.rollout(10, break_when_any_done=False)
    nxt = td["next"]
    done = nxt["done"].squeeze(-1)
    ok = nxt["success"].squeeze(-1)
    assert ok.any()
    assert (nxt["pos_error"].squeeze(-1)[ok] <= 30.0).all()  # success is within 30 m (difficulty 0)
    # at every done the step count is the finished episode's length: the steps since the
    # previous done of that env (or since the rollout's start), counted here
    length = torch.zeros(done.shape, dtype=torch.long)
    since = torch.zeros(done.shape[0], dtype=torch.long)
    for t in range(done.shape[1]):
        since += 1
        length[:, t] = since
        since[done[:, t]] = 0
    assert torch.equal(nxt["step_count"].squeeze(-1)[done], length[done])
    assert (length[done] == 1).any() and (length[done] == 4).any()  # both kinds of episode
