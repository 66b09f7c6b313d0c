"""What the tools that report results (``aggregate``, ``pretrained``) share: the interquartile mean
across seeds and its bootstrap interval, a checkpoint's held-out success per scene bin, and
where a figure comes from (machine, commit).

The interquartile mean (IQM) is the mean of the middle 50 % of the values: each of the ``n``
sorted values owns ``1/n`` of the quantile axis ``[0, 1]`` and counts with the share of it that
lies in ``[1/4, 3/4]``, so a value straddling a quartile counts in part (:func:`iqm_weights`).
For ``n`` divisible by 4 this is the mean of the middle ``n/2`` values, as rliable's
``aggregate_iqm`` (``scipy.stats.trim_mean(x, 0.25)``); for other ``n`` that one drops
``floor(n/4)`` whole values from each end instead (``n = 5``: the middle three, here weights
0.75, 1, 0.75). Source of the weighting: the interquartile mean of a data set whose size is
not divisible by four (Wikipedia, "Interquartile mean"). An infinite value (a seed that never
reached a level, in a time-to-level metric) makes the IQM infinite only where it gets weight.

:func:`bootstrap_ci` is the percentile bootstrap of rliable (Agarwal et al., 2021, "Deep RL at
the edge of the statistical precipice"), stratified over the runs of one task: each resample
draws ``n`` seeds with replacement, and the interval is the ``(1 - level) / 2`` and
``(1 + level) / 2`` quantiles of the resampled IQMs, from a fixed generator seed.
"""

from __future__ import annotations

import math
import os
import platform
from collections.abc import Sequence
from typing import Any

import numpy as np

#: Resamples of :func:`bootstrap_ci`: each tail of a 95 % interval rests on 50 of them.
RESAMPLES = 2000
#: Seed of the bootstrap generator: the same values give the same interval.
BOOTSTRAP_SEED = 0


def iqm_weights(n: int) -> np.ndarray:
    """Weights ``[n]`` of the sorted values in the IQM: ``n`` times the length of
    ``[(i - 1)/n, i/n] ∩ [1/4, 3/4]`` for value ``i`` (1-based); they sum to ``n / 2``."""
    if n < 1:
        raise ValueError("iqm_weights: n must be at least 1")
    edges = np.arange(n + 1) / n
    overlap = np.clip(np.minimum(edges[1:], 0.75) - np.maximum(edges[:-1], 0.25), 0.0, None)
    return overlap * n


def _iqm_sorted(x: np.ndarray) -> np.ndarray:
    """IQM of each row of ``x [..., n]`` sorted ascending (infinite values allowed)."""
    w = iqm_weights(x.shape[-1])
    terms = np.where(w > 0, x * np.where(w > 0, w, 1.0), 0.0)  # 0 * inf would be nan
    return terms.sum(-1) / w.sum()


def iqm(values: Sequence[float]) -> float:
    """Interquartile mean of ``values`` (module doc): ``[1, 2, 3, 4]`` -> 2.5."""
    x = np.sort(np.asarray(values, dtype=np.float64))
    if x.size == 0:
        raise ValueError("iqm: no values")
    return float(_iqm_sorted(x))


def percentile(sorted_values: np.ndarray, q: float) -> float:
    """The ``q``-quantile (``q`` in [0, 1]) of ascending ``sorted_values``, interpolated linearly
    between the two nearest order statistics (numpy's default); infinite where it touches an
    infinite value."""
    h = (len(sorted_values) - 1) * q
    lo, hi = math.floor(h), math.ceil(h)
    a, b = float(sorted_values[lo]), float(sorted_values[hi])
    if lo == hi or a == b:
        return a
    return math.inf if math.isinf(b) else a + (h - lo) * (b - a)


def bootstrap_ci(
    values: Sequence[float],
    level: float = 0.95,
    resamples: int = RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[float, float]:
    """Percentile bootstrap interval ``(lo, hi)`` of the IQM of ``values`` (one per seed).

    Args:
        values: one value per seed (``n >= 1``; infinite values allowed).
        level: coverage in (0, 1): 0.95 gives the 2.5 % and 97.5 % quantiles.
        resamples: bootstrap resamples, each ``n`` seeds drawn with replacement.
        seed: the generator's seed (numpy's ``default_rng``).
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        raise ValueError("bootstrap_ci: no values")
    if not 0.0 < level < 1.0:
        raise ValueError(f"bootstrap_ci: level = {level} must lie in (0, 1)")
    rng = np.random.default_rng(seed)
    draws = x[rng.integers(0, x.size, size=(resamples, x.size))]
    stats = np.sort(_iqm_sorted(np.sort(draws, axis=1)))
    return percentile(stats, (1.0 - level) / 2), percentile(stats, (1.0 + level) / 2)


def finite_or_none(x: float | None) -> float | None:
    """``x`` where finite, else None (JSON has no infinity)."""
    return x if x is not None and math.isfinite(x) else None


def summary(values: Sequence[float | None], missing: float | None = None) -> dict[str, Any]:
    """``{"iqm": float | None, "ci95": [lo, hi] | None}`` of the per-seed ``values``.

    ``missing``: what a None stands for: ``math.inf`` for a level never reached (a censored
    time), None to leave those seeds out. A result that is infinite, or has no values, is None.
    """
    xs = [missing if v is None else v for v in values]
    xs = [v for v in xs if v is not None]
    if not xs:
        return {"iqm": None, "ci95": None}
    lo, hi = bootstrap_ci(xs)
    ci = [lo, hi] if math.isfinite(lo) and math.isfinite(hi) else None
    return {"iqm": finite_or_none(iqm(xs)), "ci95": ci}


# ------------------------------------------------------------------------------- held-out checks
def heldout_by_bin(
    checkpoint: str, difficulty: float, episodes: int, seed: int, device: str = "cpu"
) -> dict[str, Any]:
    """A checkpoint's mean action on the ``episodes`` scenes of scene seed ``seed`` at
    ``difficulty``, as ``truckrl eval checkpoint=... difficulty=... episodes=... seed=...`` runs
    them (its env config, one episode per scene).

    Returns:
        ``{"success": fraction, "episodes": int, "tolerance": [m, deg], "bins": {"<dimension>
        <bin>": {"success": fraction | None, "count": int}}}``: the success tolerances at
        ``difficulty``, and every bin of the task's ``category_bins`` in its order, named as
        ``truckrl eval`` prints them (``route left``; an empty bin's success is None).

    Raises:
        CheckpointError: the checkpoint cannot be used.
    """
    from truckrl.evaluation.categories import summarize_by_category, task_bins
    from truckrl.evaluation.rollout import evaluate_policy, summarize
    from truckrl.rl.policy import load_policy

    policy = load_policy(checkpoint, device)
    results, tolerance, errors = evaluate_policy(
        policy.actor, policy.env_config, difficulty, episodes, seed, device
    )
    bins = task_bins(policy.env_config.task.name, results) or {}
    rows = {(r["dimension"], r["bin"]): r for r in summarize_by_category(results, bins, errors)}
    named = {}
    for dim, group in bins.items():
        for b in group:
            row = rows.get((dim, b))
            named[f"{dim} {b}"] = {
                "success": row["success_rate"] if row else None,
                "count": row["count"] if row else 0,
            }
    return {
        "success": summarize(results, errors)["success_rate"],
        "episodes": episodes,
        "tolerance": [float(tolerance[0]), float(tolerance[1])],
        "bins": named,
    }


# ------------------------------------------------------------------------------- provenance
def machine() -> str:
    """What the figures were measured on: OS, CPU, core count and torch version."""
    import torch

    cpu = platform.processor() or platform.machine()
    return (
        f"{platform.system()} {platform.release()}, {cpu}, {os.cpu_count()} CPUs, "
        f"Python {platform.python_version()}, torch {torch.__version__}"
    )


def commit_of(source: dict | None) -> str | None:
    """A run's recorded source (``{"commit", "dirty"}``, :func:`truckrl.cli.git_revision`) as
    ``<commit>`` or ``<commit>-dirty``; None where it records none."""
    if not source or not source.get("commit"):
        return None
    return str(source["commit"]) + ("-dirty" if source.get("dirty") else "")
