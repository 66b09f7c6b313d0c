"""Figures for the float32 LiDAR fix: mismatch rates against the oracle of test_lidar_float32.py.

Run from the repository root (``PYTHONPATH`` picks the ``truckrl`` measured, e.g. an old checkout
first to measure the code before the fix)::

    PYTHONPATH=. python tests/reliability/measure_lidar_float32.py

Prints, on fixed seeds: near-parallel and general float32 beams failing the acceptance rule (and,
for reference, how they compare with the exact float64 ray), span-vs-dense mismatches
(> 1e-3 m) for env-like scenes with fov = pi and 16 beams, and the time of a dense float32 scan of
1024 env scenes (eager, one thread, median of 5).
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch
from test_lidar_float32 import (
    MAX_RANGE,
    accepted,
    beam_layout,
    near_parallel_cases,
    oracle_bounds,
    random_segment_scenes,
    rules,
    scan,
)

from truckrl.sim import SceneConfig, VehicleConfig, generate_scenes, sample_vehicle_params


def report(name, got, bounds, rows=None):
    phantom, early, late = (~x for x in rules(got, bounds))
    exact = bounds[0]
    if rows is not None:  # only the aimed beam of each scene
        phantom, early, late, got, exact = (
            phantom[rows],
            early[rows],
            late[rows],
            got[rows],
            exact[rows],
        )
    bad = phantom | early | late
    hit = exact < MAX_RANGE
    far = hit & (np.abs(got - exact) > 1e-3)
    graze = ~hit & (got < MAX_RANGE)
    print(
        f"  {name:22s} rule violations {int(bad.sum()):5d} / {bad.size}"
        f" ({100 * bad.mean():.2f} %) [phantom {int(phantom.sum())}, early {int(early.sum())},"
        f" late {int(late.sum())}]; exact ray hits {int(hit.sum())}: |r - exact| > 1e-3"
        f" {int(far.sum())}; exact ray misses {int((~hit).sum())}: reported hit {int(graze.sum())}"
    )


def near_parallel():
    origin, heading, segs, rel, beam, kind = near_parallel_cases(20_000, seed=1)
    bounds = oracle_bounds(origin, heading, segs, None, rel)
    rows = (np.arange(beam.size), beam)
    print("near-parallel beams (20,000 scenes, seed 1, the aimed beam of each):")
    for method in ("dense", "span"):
        got = scan(origin, heading, segs, None, rel, method)
        report(method, got, bounds, rows)
        ok = accepted(got, bounds)[rows]
        for k, label in enumerate(("collinear", "shifted", "turned")):
            sel = kind == k
            print(f"      {label:10s} violations {int((~ok[sel]).sum()):5d} / {int(sel.sum())}")
        report(method + " (all 16 beams)", got, bounds)


def general():
    origin, heading, segs, mask = random_segment_scenes(4000, 24, seed=5)
    rel = beam_layout(16, 2 * math.pi)
    bounds = oracle_bounds(origin, heading, segs, mask, rel)
    print("general beams (4000 scenes x 24 segments x 16 beams, seed 5):")
    for method in ("dense", "span"):
        report(method, scan(origin, heading, segs, mask, rel, method), bounds)


def env_scenes(n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    return generate_scenes(SceneConfig(), sample_vehicle_params(VehicleConfig(), n, g), g), g


def span_vs_dense_env():
    batch, g = env_scenes(2048, 21)
    rel = beam_layout(16, math.pi)
    n_bad = n_all = 0
    worst = 0.0
    viol = {"dense": 0, "span": 0}
    for k in range(25):  # start poses, then poses scattered around them
        jitter = (
            (torch.rand(2048, 3, generator=g) - 0.5) * torch.tensor([20.0, 20.0, 6.0]) * (k > 0)
        )
        pose = (batch.start + jitter).numpy()
        origin, heading = pose[:, :2], pose[:, 2]
        segs, mask = batch.segments.numpy(), batch.mask.numpy()
        dense = scan(origin, heading, segs, mask, rel, "dense")
        span = scan(origin, heading, segs, mask, rel, "span")
        diff = np.abs(span - dense)
        n_bad += int((diff > 1e-3).sum())
        n_all += diff.size
        worst = max(worst, float(diff.max()))
        bounds = oracle_bounds(origin, heading, segs, mask, rel)
        viol["dense"] += int((~accepted(dense, bounds)).sum())
        viol["span"] += int((~accepted(span, bounds)).sum())
    print(
        f"env scenes, fov = pi, 16 beams (2048 scenes x 25 poses, seed 21): span vs dense"
        f" > 1e-3 m: {n_bad} / {n_all} (max {worst:.3f} m); rule violations dense"
        f" {viol['dense']}, span {viol['span']}"
    )


def timing():
    torch.set_num_threads(1)
    batch, _ = env_scenes(1024, 3)
    rel = torch.tensor(beam_layout(16, 2 * math.pi))
    origin, heading = batch.start[:, :2].contiguous(), batch.start[:, 2].contiguous()
    for method in ("dense", "span"):
        times = []
        for _ in range(6):  # the first call warms up
            t = time.perf_counter()
            lidar_out = torch_scan(origin, heading, batch.segments, batch.mask, rel, method)
            times.append(time.perf_counter() - t)
        assert lidar_out.shape == (1024, 16)
        print(
            f"lidar_scan {method}, N=1024 env scenes (E={batch.segments.shape[1]}), 16 beams,"
            f" float32, eager, 1 thread: median of 5 = {1e3 * np.median(times[1:]):.2f} ms"
        )


def torch_scan(origin, heading, segs, mask, rel, method):
    from truckrl.sim.lidar import lidar_scan

    return lidar_scan(origin, heading, segs, mask, rel, MAX_RANGE, method=method)


if __name__ == "__main__":
    near_parallel()
    general()
    span_vs_dense_env()
    timing()
