"""``torch.compile`` of the simulator's step functions, with the inductor options they need.

Every compiled env function (``TruckEnv``'s transition and observations, the planner's rollout
step, ``bench lidar``'s compiled row) goes through :func:`compile_sim`, so they all compile the
same way.

**Why an option on the CPU.** Inductor writes a pointwise result out to memory, instead of
inlining it into the kernel that reads it, once its loop body has more than
``realize_cpu_opcount_threshold`` (50) operations. The LiDAR's pair test
(:func:`~truckrl.sim.geometry.ray_distance_from_origin`, [N, R, E] distances reduced by a minimum
over the E segments) has 50-60. Above the threshold, the compiled LiDAR writes all ``N x R x E``
pair distances and reads them back to reduce them (``4 N R E`` bytes per step in float32); with
the threshold at :data:`CPU_OPCOUNT_THRESHOLD` the minimum is taken inside the pair loop, which
matters most at many beams. On CUDA, inductor's own default is kept.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

#: Inductor's ``realize_opcount_threshold`` for compiled sim functions on the CPU: above the
#: LiDAR pair test's 50-60 operations (module doc), with margin.
CPU_OPCOUNT_THRESHOLD = 100


def inductor_options(device: torch.device | str) -> dict[str, Any] | None:
    """The ``options`` :func:`compile_sim` passes to ``torch.compile`` on ``device``."""
    if torch.device(device).type == "cpu":
        return {"realize_opcount_threshold": CPU_OPCOUNT_THRESHOLD}
    return None


def compile_sim(fn: Callable, device: torch.device | str, dynamic: bool = False) -> Callable:
    """``torch.compile(fn, dynamic=dynamic)`` with :func:`inductor_options` for ``device``."""
    return torch.compile(fn, dynamic=dynamic, options=inductor_options(device))
