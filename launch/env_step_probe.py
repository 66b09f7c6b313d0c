"""Seeded env-steps/s of a compiled TruckEnv: the loop of ``bench env``, for side-by-side runs.

``bench env`` draws its random actions unseeded, so two checkouts see different episodes and,
through the compacted scene's width, may compile different graphs. This probe seeds the actions,
warms up past the widths that settle early, and reports the median of several timed windows. It
uses only the ``TruckEnv`` API, so it runs against any checkout of the project::

    PYTHONPATH=/path/to/checkout python launch/env_step_probe.py --label old
    PYTHONPATH=. python launch/env_step_probe.py --label now
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from truckrl.env import TruckEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label", default="", help="printed in front of the result")
    parser.add_argument("--envs", type=int, default=1024, help="trucks N")
    parser.add_argument("--warmup", type=int, default=300, help="untimed steps first")
    parser.add_argument("--steps", type=int, default=200, help="steps per timed window")
    parser.add_argument("--windows", type=int, default=5, help="timed windows (median)")
    parser.add_argument("--seed", type=int, default=0, help="env seed and action seed")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--eager", action="store_true", help="without env.compile")
    parser.add_argument("--beams", type=int, default=16, help="LiDAR beams (env.lidar.num_beams)")
    args = parser.parse_args()
    for name in ("envs", "steps", "windows", "threads", "beams"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} {getattr(args, name)}: must be >= 1")
    if args.warmup < 0:
        parser.error(f"--warmup {args.warmup}: must be >= 0")
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    config = {"compile": not args.eager, "lidar": {"num_beams": args.beams}}
    env = TruckEnv(num_envs=args.envs, config=config, seed=args.seed)
    td = env.reset()
    for _ in range(args.warmup):
        td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
    rates = []
    for _ in range(args.windows):
        t0 = time.perf_counter()
        for _ in range(args.steps):
            td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
        rates.append(args.envs * args.steps / (time.perf_counter() - t0))
    width = getattr(env, "_width", None)
    print(
        f"{args.label} N={args.envs} R={args.beams} compile={not args.eager} W={width} "
        f"threads={args.threads}: "
        f"median {statistics.median(rates):,.0f} env-steps/s "
        f"(windows: {', '.join(f'{r:,.0f}' for r in rates)})"
    )


if __name__ == "__main__":
    main()
