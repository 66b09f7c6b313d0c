"""Held-out evaluation during training: a fixed set of scenes the run never trains on.

Every ``log.eval_interval_frames`` training frames where that is set (else every
``log.eval_interval_min`` minutes of wall clock), ``truckrl train`` runs
:func:`~truckrl.evaluation.rollout.evaluate_policy` (mean action, one episode per scene, as
``truckrl eval``) on ``log.eval_episodes`` scenes drawn from :data:`HELDOUT_SEED`
at the current curriculum difficulty, and logs :func:`heldout_scalars` to TensorBoard:
``eval/<outcome>_rate`` overall and ``eval/<dimension>/<bin>/success`` per scene category
(:mod:`truckrl.evaluation.categories`). The same scenes, for a checkpoint:
``truckrl eval checkpoint=RUN_DIR seed=6949403065 episodes=200``.
"""

from __future__ import annotations

import re

from truckrl.evaluation.categories import summarize_by_category, task_bins
from truckrl.evaluation.rollout import Policy, evaluate_policy, summarize
from truckrl.tasks import OUTCOMES, EnvConfig

#: Scene seed of the held-out set (6,949,403,065). Training envs are seeded with
#: :func:`truckrl.rl.collection.env_seed`, ``SeedSequence([seed, iteration, worker])
#: .generate_state(1)[0]``: a uint32, so always below 2**32. This seed is 2**32 + 2,654,435,769,
#: so no training env of any run (any seed, iteration or worker) is ever given it. A generator
#: that uses all 64 bits of its seed (CUDA's Philox) therefore never draws the held-out scenes
#: in training. torch's CPU generator (mt19937) keeps only the low 32 bits of a seed, so on CPU
#: the held-out scenes are those of seed 2,654,435,769, which a training env gets with chance
#: 2**-32 per (session, worker) (below 1e-6 for 100 sessions x 24 workers), and even then only
#: that worker's first pool of episodes would repeat them.
HELDOUT_SEED = 2**32 + 2_654_435_769

#: Prefix of the TensorBoard tags.
PREFIX = "eval"


def heldout_due(interval_min: float, elapsed_s: float, window_s: float) -> bool:
    """Whether a multiple of ``interval_min`` minutes was passed in the last ``window_s`` seconds.

    ``elapsed_s`` is the wall clock since the session started. Called once per iteration with
    ``window_s`` = the time since the iteration started, it is true about every
    ``interval_min`` minutes (at the first iteration that ends after each multiple), with no state
    to keep. ``interval_min`` <= 0: never.
    """
    if interval_min <= 0:
        return False
    period = 60.0 * interval_min
    return elapsed_s // period > max(elapsed_s - window_s, 0.0) // period


def tag(name: str) -> str:
    """A category or bin name as a TensorBoard tag part: ``"turn [deg]"`` -> ``"turn_deg"``,
    ``"left 20-70"`` -> ``"left_20-70"``, ``"< 25"`` -> ``"lt_25"``."""
    name = name.replace("<", "lt").replace(">", "gt")
    return re.sub(r"[^\w.\-]+", "_", name).strip("_")


def heldout_scalars(
    actor: Policy,
    env_cfg: EnvConfig,
    difficulty: float,
    episodes: int,
    device,
    seed: int = HELDOUT_SEED,
) -> dict[str, float]:
    """Evaluate ``actor`` on the held-out scenes; return TensorBoard scalars.

    Returns:
        ``eval/difficulty``, ``eval/<outcome>_rate`` (success, collision, jackknife, timeout) and,
        for tasks with scene categories, ``eval/<dimension>/<bin>/success`` (success rate
        of every non-empty bin; names as :func:`tag`), all fractions in [0, 1].
    """
    results, _, errors = evaluate_policy(actor, env_cfg, difficulty, episodes, seed, device)
    summary = summarize(results, errors)
    out = {f"{PREFIX}/difficulty": float(difficulty)}
    out |= {f"{PREFIX}/{o.name}_rate": summary[f"{o.name}_rate"] for o in OUTCOMES}
    bins = task_bins(env_cfg.task.name, results)
    if bins:
        for row in summarize_by_category(results, bins, errors):
            key = f"{PREFIX}/{tag(row['dimension'])}/{tag(row['bin'])}/success"
            out[key] = row["success_rate"]
    return out
