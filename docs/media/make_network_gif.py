"""An animated drive through a road network for the docs (``docs/media/network.gif``).

    python docs/media/make_network_gif.py                       # pretrained:network
    python docs/media/make_network_gif.py --checkpoint pretrained:intersection --junctions 1

A policy trained on the ``network`` task (``--checkpoint``, default the shipped
``pretrained:network``) drives its own task. Any other checkpoint whose task observes the
intersection task's layout is rolled forward over the route's junction exits as sub-goals: the
sub-goal view of the network task (:mod:`truckrl.tasks.network.cells`, as the chain tool
:mod:`truckrl.tasks.network.tools` builds it: the policy's vehicle, LiDAR, control and ``dt``,
the sub-goal defaults, the chain tool's episode limit; docs/chaining.md). Either way at
difficulty 4, on routes through ``--junctions`` junctions with ``--traffic`` of the spawned
vehicles driving (every curriculum level set to that). The script plays held-out scenes (one
truck, env seeds ``--seed``, ``--seed + 1``, ...; no training uses them) until one ends in
SUCCESS, prints every outcome, and fails after ``--tries``; with ``--followed``, only scenes too
large to show whole (the viewer follows the truck). Each frame is the viewer's
(:func:`truckrl.viewer.runner.run_loop`, the runner of ``truckrl play``, no HUD panel): the
camera follows the truck through the network, the route a thin pink line, cars red, trucks
magenta; a current sub-goal is marked here as a green ring. The GIF keeps every k-th frame so
that it plays in at most ``--max-seconds``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: The chain tool's difficulty (docs/chaining.md): tolerances 1.88 m and 3.75 deg.
DIFFICULTY = 4.0


def levels_set(task, junctions: int, share: float):
    """``task`` (a network task config) with every curriculum level routing through
    ``junctions`` junctions with ``share`` of the spawned vehicles driving."""
    from dataclasses import replace

    levels = len(task.curriculum.difficulty)
    curriculum = replace(
        task.curriculum, junctions=(junctions,) * levels, traffic=(share,) * levels
    )
    return replace(task, curriculum=curriculum)


def network_env(base, junctions: int, share: float):
    """The network env of ``base`` (a network policy's config) with its levels set
    (:func:`levels_set`) and its own episode limit."""
    from dataclasses import replace

    return replace(base, compile=False, task=levels_set(base.task, junctions, share))


def subgoal_env(base, junctions: int, share: float):
    """The sub-goal network env of ``base`` (the policy's :class:`~truckrl.tasks.EnvConfig`):
    every curriculum level routes through ``junctions`` junctions with ``share`` of the spawned
    vehicles driving."""
    from dataclasses import replace

    from truckrl.tasks.network.cells.task import CellsTaskConfig
    from truckrl.tasks.network.tools import ChainConfig

    task = levels_set(CellsTaskConfig(), junctions, share)
    return replace(base, max_steps=ChainConfig().max_steps, compile=False, task=task)


def play_scene(
    policy, env_cfg, seed: int, size_px: int, followed: bool
) -> tuple[list[np.ndarray], str, int]:
    """One episode of ``policy`` in the env of ``env_cfg`` seeded ``seed``: the viewer's frames
    (with the current sub-goal ringed), the outcome and the steps; with ``followed``, a scene
    the viewer shows whole (fixed camera) is skipped: no frames, outcome "fixed camera"."""
    import cv2

    from truckrl.env import TruckEnv
    from truckrl.viewer.runner import PolicySource, Runner, run_loop
    from truckrl.viz.config import ViewConfig
    from truckrl.viz.draw import COLORS, make_view, world_to_pixel
    from truckrl.viz.keyboard import NoKeys
    from truckrl.viz.video import follow_half_extent

    env = TruckEnv(num_envs=1, config=env_cfg, seed=seed)
    env.set_difficulty(DIFFICULTY)
    view = ViewConfig(size_px=size_px, panel_px=0)
    runner = Runner(env, {"policy": PolicySource(policy.actor)}, "policy", view)
    frames: list[np.ndarray] = []
    if followed and runner._camera is not None:
        return frames, "fixed camera", 0

    def keep(r: Runner) -> None:
        s = r.env.get_state()[0]
        cam = r._camera
        if cam is None:
            half = follow_half_extent(view, env_cfg.lidar.max_range)
            v = make_view(size_px, s["pose"][:2].numpy(), view_half_extent=half)
        else:
            v = make_view(
                size_px, np.asarray(cam["center"]), view_half_extent=cam["view_half_extent"]
            )
        img = r.frame.copy()
        if "subgoals" in s.keys():
            sub = s["subgoals"][int(s["subgoal_index"])][:2].numpy()
            c = np.round(world_to_pixel(sub, v)).astype(int)
            cv2.circle(img, (int(c[0]), int(c[1])), 7, COLORS["goal"], 2, cv2.LINE_AA)
        frames.append(img)

    result = run_loop(runner, NoKeys(), episodes=1, sinks=(keep,))
    return frames, (result.outcomes[-1] if result.outcomes else "none"), result.steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default="pretrained:network", help="the driving policy")
    ap.add_argument("--junctions", type=int, default=2, help="junctions on the route")
    ap.add_argument("--traffic", type=float, default=1.0, help="share of vehicles that drive")
    ap.add_argument("--seed", type=int, default=12345, help="first env seed tried")
    ap.add_argument("--tries", type=int, default=200, help="scenes played before giving up")
    ap.add_argument("--size", type=int, default=640, help="view side [px] before --scale")
    ap.add_argument("--scale", type=float, default=0.5, help="GIF size over view size")
    ap.add_argument(
        "--followed", action="store_true", help="only scenes the viewer's camera follows"
    )
    ap.add_argument("--max-seconds", type=float, default=18.0, help="longest GIF [s]")
    ap.add_argument("--out", type=Path, default=HERE / "network.gif")
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    from truckrl.rl.policy import load_policy
    from truckrl.tasks.network.tools import check_policy
    from truckrl.viz.video import gif_bytes

    policy = load_policy(args.checkpoint)
    if policy.env_config.task.name == "network":
        env_cfg = network_env(policy.env_config, args.junctions, args.traffic)
    else:
        check_policy(policy, args.checkpoint)
        env_cfg = subgoal_env(policy.env_config, args.junctions, args.traffic)
    for seed in range(args.seed, args.seed + args.tries):
        frames, outcome, steps = play_scene(policy, env_cfg, seed, args.size, args.followed)
        print(f"seed {seed}: {outcome} after {steps} steps", flush=True)
        if outcome == "SUCCESS":
            break
    else:
        sys.exit(f"no SUCCESS in {args.tries} scenes from seed {args.seed}")
    fps = 1.0 / env_cfg.dt
    every = max(1, math.ceil(len(frames) / (args.max_seconds * fps)))
    kept = frames[::every]
    if kept[-1] is not frames[-1]:
        kept.append(frames[-1])  # the final frame with the outcome banner
    kept += [frames[-1]] * 10  # hold the end a moment before the loop restarts
    args.out.write_bytes(gif_bytes(kept, fps=fps, scale=args.scale))
    print(
        f"{args.out}: {args.checkpoint}, seed {seed}, {args.junctions} junction(s), traffic "
        f"{args.traffic}, {len(frames)} frames, every {every}, {len(kept)} kept "
        f"({len(kept) / fps:.1f} s), {args.out.stat().st_size / 1e6:.2f} MB"
    )


if __name__ == "__main__":
    main()
