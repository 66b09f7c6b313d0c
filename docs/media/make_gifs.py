"""Animated GIFs of the shipped policies, one per task, for the README.

    python docs/media/make_gifs.py                 # all three, into docs/media/
    python docs/media/make_gifs.py uturn --png     # one task, plus its middle frame as PNG

Each GIF is one episode of ``truckrl play headless=true checkpoint=pretrained:<task>
seed=<seed> view.panel_px=0``: the same config composition (:func:`truckrl.cli.compose_config`),
runner (:func:`truckrl.play.build_runner`) and frame loop (:func:`truckrl.viewer.runner.run_loop`)
as the command, with a sink that keeps the frames instead of an mp4 writer, so no lossy codec
sits between the renderer and the GIF palette. The bird's-eye view only (no HUD panel) keeps
the files small. The script fails unless the episode ends in SUCCESS: the seeds below are scenes
the shipped policy solves at its checkpoint's difficulty (uturn: seed 0 times out, seed 1 leaves the fixed camera).
The drive through a road network (``network.gif``, no trained network policy yet) has its own
script: ``docs/media/make_network_gif.py``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

# task -> (scene seed, keep every k-th frame, scale of the 640 px view)
SCENES: dict[str, tuple[int, int, float]] = {
    "intersection": (0, 1, 0.5),  # a short forward drive: every frame
    "dock": (0, 2, 0.5),  # a long reversing manoeuvre: every second frame (2x speed)
    "uturn": (4, 3, 0.5),  # forward, reverse into the branch, forward out: every third (3x)
}


def episode_frames(task: str, seed: int) -> tuple[list[np.ndarray], float, str]:
    """The RGB frames ``[H, W, 3]`` of one headless play episode, its fps and its outcome."""
    from truckrl.cli import compose_config
    from truckrl.config.schemas import PlayConfig
    from truckrl.play import build_runner
    from truckrl.viewer.runner import run_loop

    pc = compose_config(
        "play",
        PlayConfig,
        [
            f"checkpoint=pretrained:{task}",
            "headless=true",
            f"seed={seed}",
            "episodes=1",
            "view.panel_px=0",
        ],
    )
    runner, inputs, fps, _ = build_runner(pc)
    frames: list[np.ndarray] = []
    result = run_loop(
        runner, inputs, fps=fps, episodes=1, sinks=(lambda r: frames.append(r.frame.copy()),)
    )
    return frames, fps, result.outcomes[-1] if result.outcomes else "none"


def make_gif(task: str, out_dir: Path, png: bool) -> Path:
    """Write ``<out_dir>/<task>.gif`` (and ``<task>.png``, its middle frame, when ``png``)."""
    from truckrl.viz.video import gif_bytes, write_png

    seed, every, scale = SCENES[task]
    frames, fps, outcome = episode_frames(task, seed)
    if outcome != "SUCCESS":
        sys.exit(f"{task} seed {seed}: the episode ended in {outcome}, not SUCCESS; pick a seed")
    kept = frames[::every]
    if kept[-1] is not frames[-1]:
        kept.append(frames[-1])  # the final frame with the outcome banner
    kept += [frames[-1]] * 10  # hold the end a moment before the loop restarts
    path = out_dir / f"{task}.gif"
    path.write_bytes(gif_bytes(kept, fps=fps, scale=scale))
    print(
        f"{path}: seed {seed}, {len(frames)} frames, {len(kept)} kept, "
        f"{path.stat().st_size / 1e6:.2f} MB"
    )
    if png:
        print(f"{write_png(out_dir / f'{task}.png', frames[len(frames) // 2])}")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("tasks", nargs="*", help=f"some of {', '.join(SCENES)} (default: all)")
    ap.add_argument("--out", type=Path, default=HERE, help="folder for the GIFs")
    ap.add_argument("--png", action="store_true", help="also write each episode's middle frame")
    args = ap.parse_args()
    unknown = sorted(set(args.tasks) - set(SCENES))
    if unknown:
        ap.error(f"unknown task {', '.join(unknown)}; choose from {', '.join(SCENES)}")
    import torch

    torch.set_num_threads(1)
    for task in args.tasks or SCENES:
        make_gif(task, args.out, args.png)


if __name__ == "__main__":
    main()
