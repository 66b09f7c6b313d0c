"""A (re)start must not bias the curriculum: after every environment restarts at once, the first
episodes to finish are the short ones, which in this task are mostly successes.

The synthetic episodes here make that bias as strong as the real one: successes end after 20-60
steps, crashes after 50-200, the rest time out at 200 (success rate 13 %; measured on real
resumes: 97 % success in the first iteration). Fed in finish order (the
old way) the curriculum's EMA crosses the 0.70 promotion threshold in the first batch after a
restart; fed by :class:`~truckrl.rl.cohorts.StartOrderFeed` it stays at the true rate.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import Tensor

from truckrl.rl.cohorts import StartOrderFeed
from truckrl.rl.curriculum import Curriculum, CurriculumConfig, ema_trajectory
from truckrl.rl.metrics import finished_in_time_order

P_SUCCESS, MAX_STEPS = 0.13, 200


def episodes(n_envs: int, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``done``, ``success`` ``[E, steps]`` of back-to-back episodes, all starting at step 0."""
    rng = np.random.default_rng(seed)
    done = np.zeros((n_envs, steps), bool)
    success = np.zeros((n_envs, steps), bool)
    for e in range(n_envs):
        t = 0
        while True:
            u = rng.random()
            if u < P_SUCCESS:
                length, ok = rng.integers(20, 61), True
            elif u < P_SUCCESS + 0.3:
                length, ok = rng.integers(50, MAX_STEPS + 1), False
            else:
                length, ok = MAX_STEPS, False
            t += length
            if t > steps:
                break
            done[e, t - 1], success[e, t - 1] = True, ok
    return done, success


def batches(done: np.ndarray, success: np.ndarray, horizon: int):
    """Collector-like batches ``[E, T]`` (time last) with ("next", done / success / difficulty)."""
    for t0 in range(0, done.shape[1], horizon):
        d = torch.from_numpy(done[:, t0 : t0 + horizon, None].copy())
        s = torch.from_numpy(success[:, t0 : t0 + horizon, None].copy())
        nxt = TensorDict({"done": d, "success": s, "difficulty": torch.zeros(d.shape)}, d.shape[:2])
        yield TensorDict({"next": nxt}, d.shape[:2])


@pytest.fixture(scope="module")
def restart():
    return episodes(1024, 20 * 64, seed=0)


def test_finish_order_is_biased_right_after_a_restart(restart):
    first = next(batches(*restart, 64))
    early = finished_in_time_order(first, "success").float().mean().item()
    assert early > 0.7  # 6x the true rate: the bias the feed removes
    cur = Curriculum(CurriculumConfig())
    cur.ema = P_SUCCESS  # where a resumed run's EMA was
    cur.update(finished_in_time_order(first, "success"))
    assert cur.ema > 3 * P_SUCCESS


def ema_after_restart(feed: StartOrderFeed | None, seed: int, steps: int = 5 * 64) -> Tensor:
    """The curriculum's EMA over the first ``steps`` after a restart from its steady value."""
    parts = []
    for b in batches(*episodes(256, steps, seed), 64):
        parts.append(feed.update(b)[0] if feed else finished_in_time_order(b, "success"))
    return ema_trajectory(P_SUCCESS, 0.995, torch.cat(parts))


def test_a_resume_does_not_push_the_ema_up():
    """Like the EMA rising at 17 of 19 real resumes: in finish order it rises at every restart,
    far; in start order it rises or falls as chance has it, and only a little."""
    finish = [ema_after_restart(None, s) for s in range(10)]
    start = [ema_after_restart(StartOrderFeed(), s) for s in range(10)]
    assert all(e.max() > 0.21 for e in finish)  # +0.08 and more: 5 standard deviations
    assert 2 <= sum(e[-1] > P_SUCCESS for e in start) <= 8
    assert max(e.max() for e in start) < 0.19  # the EMA's own noise: sd 0.017


def test_start_order_feed_sees_the_true_success_rate_from_the_first_episode(restart):
    feed = StartOrderFeed()
    released = [feed.update(b)[0] for b in batches(*restart, 64)]
    stream = torch.cat(released)
    n = len(stream)
    assert n > 5000
    for part in (stream[:300], stream[:1000], stream):  # the EMA's memory is ~200 episodes
        sigma = (P_SUCCESS * (1 - P_SUCCESS) / len(part)) ** 0.5
        assert abs(part.mean().item() - P_SUCCESS) < 4 * sigma + 0.01, (len(part), part.mean())
    ema = ema_trajectory(0.0, 0.995, stream)
    assert ema[200:].max().item() < 0.3  # never near the 0.70 threshold
    cur = Curriculum(CurriculumConfig())
    feed = StartOrderFeed()
    assert not any(cur.update(*feed.update(b)) for b in batches(*restart, 64))


def test_every_episode_is_released_once_oldest_start_first():
    # env 0: episodes of 2 steps (start 0, 2, 4); env 1: one of 5 steps (start 0), then running
    done = torch.zeros(2, 6, dtype=torch.bool)
    done[0, [1, 3, 5]] = True
    done[1, 4] = True
    success = torch.zeros(2, 6, dtype=torch.bool)
    success[0, 3] = True  # the episode that started at step 2
    nxt = TensorDict(
        {
            "done": done[..., None],
            "success": success[..., None],
            "difficulty": torch.zeros(2, 6, 1),
        },
        [2, 6],
    )
    feed = StartOrderFeed()
    first, _ = feed.update(TensorDict({"next": nxt[:, :3]}, [2, 3]))
    assert first.numel() == 0  # env 1's episode from step 0 still runs: nothing is complete
    second, _ = feed.update(TensorDict({"next": nxt[:, 3:]}, [2, 3]))
    # frontier: env 0 runs from step 6, env 1 from step 5 -> starts 0, 0, 2, 4 are released
    assert second.tolist() == [0.0, 0.0, 1.0, 0.0]
    assert feed.waiting == 0
