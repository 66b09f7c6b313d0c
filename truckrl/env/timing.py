"""Where a :class:`~truckrl.env.TruckEnv`'s step time goes: wall seconds spent in each part of
``step_and_maybe_reset``, for profiling (``truckrl bench env parts=true``).

The parts, each timed around the env's own call while :func:`timed_parts` is active:

* ``draw``: the task's scene generator filling the episode pool (``Task.sample``);
* ``prepare``: the pool's preparation of those episodes (the curriculum's ``on_reset`` and their
  first observation, for the whole refill);
* ``restart``: the rest of restarting the trucks whose episodes ended (rows copied into the
  state, the scene's compaction);
* ``transition``: the (compiled) step of every truck: physics, collision, LiDAR, reward,
  observation;
* ``other``: the rest of the wall time of the timed loop (TorchRL's step bookkeeping, the state
  update, the random actions), computed by the caller as total minus the parts.

The first four nest as ``restart ⊃ prepare, draw``; ``StepParts.restart`` excludes them, so
the parts add up. On a CUDA device every timed call synchronizes the device first and last
(queued kernels are charged to the part that launched them), which slows the step itself: the
parts are a profile, not a throughput figure.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any

import torch

from truckrl.env.truck_env import TruckEnv

#: The timed parts, in the order a table shows them.
PARTS = ("draw", "prepare", "restart", "transition")


@dataclass
class StepParts:
    """Wall seconds per part (module doc), summed over the calls while timing was active."""

    draw: float = 0.0
    prepare: float = 0.0
    restart: float = 0.0
    transition: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@contextmanager
def timed_parts(env: TruckEnv) -> Iterator[StepParts]:
    """Time the parts of ``env``'s steps and restarts while the block runs; yields the
    :class:`StepParts` it accumulates into. The env's own callables are restored on exit, and
    the values it computes are unchanged."""
    parts = StepParts()
    sync: Callable[[], None] = (
        (lambda: torch.cuda.synchronize(env.device)) if env.device.type == "cuda" else lambda: None
    )
    inner = {"draw": 0.0, "prepare": 0.0}

    def timed(fn: Callable[..., Any], name: str) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            sync()
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            sync()
            dt = time.perf_counter() - t0
            setattr(parts, name, getattr(parts, name) + dt)
            if name in inner:
                inner[name] += dt
            return out

        return call

    pool = env._pool
    saved = (pool._draw, pool._prepare, env._transition_fn, env.__dict__.get("_restart"))
    restart = env._restart

    def restart_only(idx: torch.Tensor) -> Any:
        before = inner["draw"] + inner["prepare"]
        sync()
        t0 = time.perf_counter()
        out = restart(idx)
        sync()
        nested = inner["draw"] + inner["prepare"] - before
        parts.restart += time.perf_counter() - t0 - nested
        return out

    pool._draw = timed(pool._draw, "draw")
    if pool._prepare is not None:
        pool._prepare = timed(pool._prepare, "prepare")
    env._transition_fn = timed(env._transition_fn, "transition")
    env._restart = restart_only  # type: ignore[method-assign]
    try:
        yield parts
    finally:
        pool._draw, pool._prepare, env._transition_fn = saved[:3]
        if saved[3] is None:
            del env._restart
        else:
            env._restart = saved[3]  # type: ignore[method-assign]
