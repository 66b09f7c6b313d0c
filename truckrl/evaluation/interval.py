"""The sampling uncertainty of a success rate: Wilson's score interval.

An evaluation scores a policy on a finite set of held-out scenes, so its success rate is an
estimate: at 95 % on 1,000 scenes the 95 % interval spans about ±1.4 points, at 5,000 about
±0.6. Every rate ``truckrl eval`` reports (overall and per scene category) carries this interval,
so a difference smaller than it is read as the noise it is. Wilson's interval rather than the
normal approximation ``p ± z sqrt(p (1 - p) / n)``: it stays inside [0, 1] and keeps its
coverage near rates of 0 or 1 and for small bins (E. B. Wilson, "Probable inference, the law of
succession, and statistical inference", JASA 22, 1927). Plain Python: the docs' renderer
computes the same interval from a result file's rate and episode count.
"""

from __future__ import annotations

import math
from statistics import NormalDist

#: Coverage of the intervals the evaluation reports.
LEVEL = 0.95


def wilson_interval(successes: float, n: int, level: float = LEVEL) -> tuple[float, float]:
    """Wilson score interval ``(lo, hi)`` (fractions in [0, 1]) of a success rate.

    Args:
        successes: successful episodes (a count; a rate times ``n`` is rounded to one).
        n: episodes, at least 1.
        level: coverage in (0, 1): 0.95 uses ``z = 1.96``.
    """
    if n < 1:
        raise ValueError(f"wilson_interval: n = {n} must be at least 1")
    if not 0.0 < level < 1.0:
        raise ValueError(f"wilson_interval: level = {level} must lie in (0, 1)")
    k = round(successes)
    if not 0 <= k <= n:
        raise ValueError(f"wilson_interval: successes = {successes} must lie in [0, {n}]")
    z = NormalDist().inv_cdf(0.5 + level / 2.0)
    p, z2 = k / n, z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    # at k = 0 (or n) the exact bound is 0 (or 1); the closed form can miss it by a rounding
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return lo, hi
