"""EpisodePool (truckrl/env/pool.py): every drawn episode is handed out exactly once, in draw
order, prepared for the key of its take, across refills, takes larger than a refill, refills
that return fewer episodes than asked, and key changes; a new draw key drops the held ones. The
answer is a counter of the episodes drawn, not the pool's own bookkeeping."""

from __future__ import annotations

import pytest
import torch

from truckrl.env.pool import EpisodePool


def counting_pool(
    size: int, prepared: bool = True, short: int = 0, draw_key=None
) -> tuple[EpisodePool, list[tuple[int, object]]]:
    """A pool whose episode ``i`` (the ``i``-th drawn) holds ``id = i`` and a ``[3]`` leaf; a
    preparation that writes ``id * 10 + key`` and observes ``-id``. Refill ``r`` returns
    ``r % (short + 1)`` episodes fewer than asked. Records each draw's ``(size, draw key)``."""
    drawn = [0]
    sizes: list[tuple[int, object]] = []

    def draw(k: int, key) -> dict:
        sizes.append((k, key))
        k -= (len(sizes) - 1) % (short + 1)
        ids = torch.arange(drawn[0], drawn[0] + k)
        drawn[0] += k
        return {"id": ids, ("nested", "x"): ids.float().unsqueeze(-1).expand(k, 3).clone()}

    def prepare(leaves: dict, key: int) -> tuple[dict, dict]:
        return {**leaves, "start": leaves["id"] * 10 + key}, {"obs": -leaves["id"]}

    return EpisodePool(draw, size, prepare if prepared else None, draw_key), sizes


def test_episodes_come_out_once_in_draw_order_prepared_for_their_take():
    pool, sizes = counting_pool(size=8)
    g = torch.Generator().manual_seed(0)
    expect, key = 0, 0
    for t in range(60):
        m = int(torch.randint(0, 13, (1,), generator=g))  # sometimes more than a refill
        if t % 7 == 6:
            key += 1  # a new difficulty: held episodes are prepared again
        leaves, obs = pool.take(m, key)
        want = torch.arange(expect, expect + m)
        assert torch.equal(leaves["id"], want), t
        assert torch.equal(leaves[("nested", "x")][:, 0], want.float())
        assert torch.equal(leaves["start"], want * 10 + key), t
        assert torch.equal(obs["obs"], -want)
        expect += m
    # a refill asks for max(m, size) episodes
    assert all(k >= 8 for k, _ in sizes)
    assert sum(k for k, _ in sizes) - len(pool) == expect


def test_short_refills_give_the_same_sequence_whatever_the_takes():
    """Refills that return 8, 6, 7, 8, 6, ... of the 8 asked for: takes up to a refill's size
    get the drawn episodes in order from the same refills however they split, and a take larger
    than the refills gets them in order too (its refills asked for the whole take)."""
    got = {}
    for name, takes in (("ones", [1] * 40), ("mixed", [5, 0, 7, 3, 8, 6, 8, 3])):
        pool, sizes = counting_pool(size=8, short=2)
        ids = [pool.take(m, 0)[0]["id"] for m in takes]
        assert torch.equal(torch.cat(ids), torch.arange(40)), name
        got[name] = sizes
    assert got["ones"] == got["mixed"] == [(8, None)] * 6
    pool, sizes = counting_pool(size=8, short=2)
    assert torch.equal(pool.take(8, 0)[0]["id"], torch.arange(8))
    assert torch.equal(pool.take(50, 0)[0]["id"], torch.arange(8, 58))
    assert sizes == [(8, None), (50, None), (50, None)]  # 49 of 50 asked, then a refill


def test_a_new_draw_key_drops_the_held_episodes():
    """Keys 0-9 share draw key 0 (a new key prepares the held episodes again), key 10 has draw
    key 1: the held episodes are dropped and the refill is asked for draw key 1."""
    pool, sizes = counting_pool(size=8, draw_key=lambda key: key // 10)
    assert torch.equal(pool.take(3, 0)[0]["id"], torch.arange(3))
    leaves, _ = pool.take(2, 5)
    assert torch.equal(leaves["id"], torch.tensor([3, 4]))
    assert torch.equal(leaves["start"], torch.tensor([35, 45]))
    leaves, obs = pool.take(2, 10)
    assert torch.equal(leaves["id"], torch.tensor([8, 9]))  # episodes 5-7 dropped
    assert torch.equal(leaves["start"], torch.tensor([90, 100]))
    assert torch.equal(obs["obs"], torch.tensor([-8, -9]))
    assert sizes == [(8, 0), (8, 1)]


def test_a_refill_without_episodes_is_an_error():
    def draw(k: int, key) -> dict:
        return {"id": torch.zeros(0, dtype=torch.long)}

    with pytest.raises(RuntimeError, match="returned no episode"):
        EpisodePool(draw, 4).take(1)


def test_without_prepare_the_drawn_episodes_come_out_as_drawn():
    pool, _ = counting_pool(size=5, prepared=False)
    got = [pool.take(m)[0]["id"] for m in (3, 4, 9, 1, 0, 6)]
    assert torch.equal(torch.cat(got), torch.arange(23))
    assert pool.take(2)[1] is None
    pool.clear()
    assert len(pool) == 0
