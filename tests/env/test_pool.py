"""EpisodePool (truckrl/env/pool.py): every drawn episode is handed out exactly once, in draw
order, prepared for the key of its take, across refills, takes larger than a refill and key
changes; the answer is a counter of the episodes drawn, not the pool's own bookkeeping."""

from __future__ import annotations

import torch

from truckrl.env.pool import EpisodePool


def counting_pool(size: int, prepared: bool = True) -> tuple[EpisodePool, list[int]]:
    """A pool whose episode ``i`` (the ``i``-th drawn) holds ``id = i`` and a ``[3]`` leaf; a
    preparation that writes ``id * 10 + key`` and observes ``-id``. Records each draw's size."""
    drawn = [0]
    sizes: list[int] = []

    def draw(k: int) -> dict:
        ids = torch.arange(drawn[0], drawn[0] + k)
        drawn[0] += k
        sizes.append(k)
        return {"id": ids, ("nested", "x"): ids.float().unsqueeze(-1).expand(k, 3).clone()}

    def prepare(leaves: dict, key: int) -> tuple[dict, dict]:
        return {**leaves, "start": leaves["id"] * 10 + key}, {"obs": -leaves["id"]}

    return EpisodePool(draw, size, prepare if prepared else None), sizes


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
    # a refill draws max(m, size) episodes, so the sequence does not depend on how takes split
    assert all(k >= 8 for k in sizes)
    assert sum(sizes) - len(pool) == expect


def test_without_prepare_the_drawn_episodes_come_out_as_drawn():
    pool, _ = counting_pool(size=5, prepared=False)
    got = [pool.take(m)[0]["id"] for m in (3, 4, 9, 1, 0, 6)]
    assert torch.equal(torch.cat(got), torch.arange(23))
    assert pool.take(2)[1] is None
    pool.clear()
    assert len(pool) == 0
