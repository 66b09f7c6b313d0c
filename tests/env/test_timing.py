"""truckrl.env.timing: timing a step's parts changes nothing the env computes, puts the env
back as it was, and charges each second to one part (a draw made slow by a known amount is
charged to the draws, not to the restart around it)."""

from __future__ import annotations

import time

import torch

from truckrl.env import TruckEnv
from truckrl.env.timing import PARTS, timed_parts

#: a pool refill of 4 episodes for 4 trucks: every few restarts draw again
CONFIG = {"compile": False, "episode_pool": 4, "max_steps": 5}


def _rollout(env: TruckEnv, steps: int) -> list[torch.Tensor]:
    """Observations and rewards of ``steps`` steps with fixed actions (restarts included)."""
    gen = torch.Generator().manual_seed(3)
    td = env.reset()
    out = []
    for _ in range(steps):
        action = torch.rand(env.num_envs, 2, generator=gen) * 2.0 - 1.0
        td, nxt = env.step_and_maybe_reset(td.set("action", action))
        out += [nxt["observation"].clone(), nxt["lidar"].clone(), td["next", "reward"].clone()]
        td = nxt
    return out


def test_timing_changes_no_value_and_restores_the_env():
    plain = TruckEnv(num_envs=4, config=CONFIG, seed=5)
    timed = TruckEnv(num_envs=4, config=CONFIG, seed=5)
    originals = (timed._pool._draw, timed._pool._prepare, timed._transition_fn)
    with timed_parts(timed) as parts:
        got = _rollout(timed, 12)  # max_steps 5: every truck restarts twice
    want = _rollout(plain, 12)
    assert all(torch.equal(a, b) for a, b in zip(got, want, strict=True))
    assert (timed._pool._draw, timed._pool._prepare, timed._transition_fn) == originals
    assert "_restart" not in timed.__dict__  # the class's method again
    spent = parts.as_dict()
    assert tuple(spent) == PARTS
    assert all(v > 0.0 for v in spent.values()), spent  # each part ran at least once


def test_a_slow_draw_is_charged_to_the_draws_not_to_the_restart_around_it():
    env = TruckEnv(num_envs=4, config=CONFIG, seed=5)
    draw, calls = env._pool._draw, []

    def slow(k: int, key):
        calls.append(k)
        time.sleep(0.05)
        return draw(k, key)

    env._pool._draw = slow
    with timed_parts(env) as parts:
        _rollout(env, 12)
    refills = len(calls) - 1  # the first draw is the full reset's, outside any restart
    assert refills >= 2
    assert parts.draw >= 0.05 * len(calls)
    # the restarts that drew waited 0.05 s each inside the draw; none of it is theirs
    assert parts.restart < 0.05
