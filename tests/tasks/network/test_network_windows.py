"""The network task's curb windows hold every curb the LiDAR can reach from within
``window_slack`` of their route stretch (docs/networks.md, "Speed"): checked by brute force in
numpy over every curb of the chain, not by the code under test."""

import math

import numpy as np
import pytest
import torch

from truckrl.config.fields import build
from truckrl.tasks import EnvConfig, make_task


@pytest.fixture(scope="module")
def episodes():
    cfg = build(EnvConfig, {"task": {"name": "network"}}, "env")
    state = make_task(cfg).sample(48, torch.Generator().manual_seed(7), torch.device("cpu"))
    return cfg, state


def _point_segment(px, py, seg):
    """Distances ``[..., E]`` from points ``px, py [..., 1]`` to segments ``seg [E, 4]``."""
    x0, y0, x1, y1 = seg.T
    dx, dy = x1 - x0, y1 - y0
    t = ((px - x0) * dx + (py - y0) * dy) / np.maximum(dx * dx + dy * dy, 1e-12)
    t = np.clip(t, 0.0, 1.0)
    return np.hypot(px - x0 - t * dx, py - y0 - t * dy)


def _segment_distance(a, b):
    """Distances ``[A, B]`` between segments ``a [A, 4]`` and ``b [B, 4]`` (0 where they
    cross): the least of the four end-to-segment distances, or 0."""
    ends = [
        _point_segment(a[:, 0:1], a[:, 1:2], b),
        _point_segment(a[:, 2:3], a[:, 3:4], b),
        _point_segment(b[:, 0:1], b[:, 1:2], a).T,
        _point_segment(b[:, 2:3], b[:, 3:4], a).T,
    ]
    d = np.minimum.reduce(ends)

    def side(p, q, r):  # sign of the turn p -> q -> r, [A, B]
        return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    a0, a1 = (a[:, None, 0], a[:, None, 1]), (a[:, None, 2], a[:, None, 3])
    b0, b1 = (b[None, :, 0], b[None, :, 1]), (b[None, :, 2], b[None, :, 3])
    cross = (side(a0, a1, b0) * side(a0, a1, b1) < 0) & (side(b0, b1, a0) * side(b0, b1, a1) < 0)
    return np.where(cross, 0.0, d)


def test_windows_hold_every_curb_the_lidar_reaches_from_near_their_stretch(episodes):
    """A LiDAR origin within ``slack`` of stretch ``c``'s route pieces sees curbs within
    ``max_range`` of itself, so within ``max_range + slack`` of the pieces: each such curb of
    the whole chain must be a valid slot of window ``c``, and every valid slot a real curb."""
    cfg, state = episodes
    reach = cfg.lidar.max_range + cfg.task.scene.window_slack
    points = state["route_points"].double().numpy()
    segments = state["segments"].double().numpy()
    mask = state["mask"].numpy()
    window, valid = state["window"].numpy(), state["window_valid"].numpy()
    n, chunks, _ = window.shape
    R = points.shape[1]
    group = math.ceil((R - 1) / chunks)  # route pieces per stretch
    needed = 0
    for i in range(n):
        ids = np.flatnonzero(mask[i])
        curbs = segments[i, ids]
        pieces = np.concatenate((points[i, :-1], points[i, 1:]), 1)  # [R - 1, 4]
        dist = _segment_distance(pieces, curbs)  # [R - 1, curbs]
        for c in range(chunks):
            lo, hi = c * group, min(c * group + group, R - 1)
            if lo >= hi:
                continue
            need = set(ids[(dist[lo:hi] <= reach).any(0)].tolist())
            have = window[i, c][valid[i, c]].tolist()
            assert len(have) == len(set(have)), (i, c)  # no curb twice
            assert set(have) <= set(ids.tolist()), (i, c)  # only real curbs
            assert need <= set(have), (i, c, sorted(need - set(have)))
            needed += len(need)
    assert needed > 10 * n  # the windows are not trivially empty


def test_windows_are_smaller_than_the_chain(episodes):
    """The windows cut work: on average a stretch's window holds well under the chain's
    curbs (a window of every curb would pass the test above)."""
    _, state = episodes
    per_window = state["window_valid"].sum(-1).float().mean()
    per_chain = state["mask"].sum(-1).float().mean()
    assert per_window < 0.75 * per_chain
