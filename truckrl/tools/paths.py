"""``python -m truckrl.tools.paths``: draw where policies drive, side by side in the same scenes.

    python -m truckrl.tools.paths outputs/A outputs/B --route right --turn 110 180 --out paths.png

Runs each checkpoint's mean action on the scenes that ``python -m truckrl.evaluate
episodes=N seed=S`` scores (the same scenes for every checkpoint), picks ``--count`` of them
(those in ``--route`` and ``--turn`` that the first checkpoint ends with ``--outcome``), and
writes a PNG: one row per checkpoint, one column per scene, each the scene with the rear-axle
trace and the tractor and trailer outlines every ``--every`` steps (:mod:`truckrl.viz.paths`).
It prints each checkpoint's success on the chosen category and the scene indices drawn. Bad
options print one line and exit with code 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from truckrl.cli import OneLineArgParser, check_scene_options, run_or_fail

OUTCOME_CHOICES = ("failed", "solved", "any")


def parser() -> argparse.ArgumentParser:
    p = OneLineArgParser(prog="python -m truckrl.tools.paths", description=__doc__.split("\n")[0])
    p.add_argument("checkpoints", nargs="+", help="checkpoints (file, run dir or pretrained)")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--episodes", type=int, default=1000, help="scenes (default 1000)")
    p.add_argument("--seed", type=int, default=12345, help="scene seed (default 12345)")
    p.add_argument("--difficulty", type=float, help="default: the first checkpoint's")
    p.add_argument("--route", help="intersection route: 'straight road', 'straight on', "
                   "left or right (default: any)")  # fmt: skip
    p.add_argument("--turn", type=float, nargs=2, metavar=("LO", "HI"),
                   help="turn angle bin [LO, HI) in degrees (default: any)")  # fmt: skip
    p.add_argument("--outcome", default="failed", choices=OUTCOME_CHOICES,
                   help="what the first checkpoint did in the drawn scenes (default failed)")  # fmt: skip
    p.add_argument("--count", type=int, default=4, help="scenes drawn (default 4)")
    p.add_argument("--every", type=int, default=12, help="outlines every N steps (default 12)")
    p.add_argument("--labels", nargs="+", help="one row label per checkpoint")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    return p


def _check(args: argparse.Namespace) -> None:
    from truckrl.config.fields import ConfigError
    from truckrl.tasks.intersection.scene import ROUTE_NAMES

    check_scene_options(args)
    if not 1 <= args.count <= 64:
        raise ConfigError(f"--count = {args.count} must be in [1, 64]")
    if args.every < 1:
        raise ConfigError(f"--every = {args.every} must be >= 1")
    if args.route is not None and args.route not in ROUTE_NAMES:
        allowed = ", ".join(repr(r) for r in ROUTE_NAMES)
        raise ConfigError(f"--route = {args.route!r} must be one of {allowed}")
    if args.turn is not None and not 0 <= args.turn[0] < args.turn[1] <= 180:
        raise ConfigError(f"--turn = {args.turn[0]:g} {args.turn[1]:g} must be 0 <= LO < HI <= 180")
    if args.labels is not None and len(args.labels) != len(args.checkpoints):
        raise ConfigError(
            f"--labels: {len(args.labels)} given for {len(args.checkpoints)} checkpoints"
        )
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise ConfigError(f"--out = {args.out}: must end in .png")


def outcome_names(results: dict, episodes: list[int]) -> list[str]:
    """The outcome name (success, collision, jackknife or timeout) of each of ``episodes``."""
    from truckrl.tasks import OUTCOMES

    return [
        next((o.name for o in OUTCOMES if bool(results[o.flag][i])), "timeout") for i in episodes
    ]


def select(results: dict, route: str | None, turn: tuple[float, float] | None):
    """Bool ``[E]``: the episodes in ``route`` and the turn-angle bin ``[lo, hi)`` [deg]."""
    import torch

    from truckrl.config.fields import ConfigError

    keep = torch.ones_like(results["success"])
    if route is not None or turn is not None:
        if "route" not in results:
            raise ConfigError("--route / --turn: this task records no routes (intersection does)")
    if route is not None:
        from truckrl.tasks.intersection.scene import ROUTE_NAMES

        keep &= results["route"] == ROUTE_NAMES.index(route)
    if turn is not None:
        deg = results["turn_angle"].abs() * (180.0 / math.pi)
        keep &= (deg >= turn[0]) & (deg < turn[1])
    return keep


def run(args: argparse.Namespace) -> dict:
    _check(args)
    import cv2
    import torch

    from truckrl.config.fields import ConfigError
    from truckrl.evaluation.rollout import evaluate_policy
    from truckrl.planning.planner import held_out_states
    from truckrl.rl.policy import load_policy
    from truckrl.viz.paths import draw_path, grid

    torch.set_num_threads(args.threads)
    policies = [load_policy(c) for c in args.checkpoints]
    difficulty = policies[0].difficulty if args.difficulty is None else args.difficulty
    starts, runs = [], []
    for pol in policies:
        starts.append(held_out_states(pol.env_config, args.episodes, args.seed, "cpu", difficulty))
        res, _, _ = evaluate_policy(
            pol.actor, pol.env_config, difficulty, args.episodes, args.seed, record_paths=True
        )
        runs.append(res)
    for c, s in zip(args.checkpoints[1:], starts[1:], strict=True):
        if not torch.equal(s["goal"], starts[0]["goal"]) or not torch.equal(
            s["segments"], starts[0]["segments"]
        ):
            raise ConfigError(
                f"{c}: its scenes for seed {args.seed} differ from {args.checkpoints[0]}'s "
                "(their scene or vehicle configs differ)"
            )
    chosen = select(runs[0], args.route, args.turn)
    n = int(chosen.sum())
    if args.outcome != "any":
        chosen &= runs[0]["success"] if args.outcome == "solved" else ~runs[0]["success"]
    scenes = torch.nonzero(chosen).squeeze(-1)[: args.count].tolist()
    what = " ".join(
        x
        for x in (args.route, f"turn {args.turn[0]:g}-{args.turn[1]:g} deg" if args.turn else "")
        if x
    )
    print(f"{n} of {args.episodes} scenes (seed {args.seed}, difficulty {difficulty:g}) "
          f"{what or 'in all'}:")  # fmt: skip
    labels = args.labels or [str(p.path) for p in policies]
    for label, res in zip(labels, runs, strict=True):
        in_cat = select(res, args.route, args.turn)
        rate = res["success"][in_cat].float().mean().item() if n else float("nan")
        print(f"  {label}: success {100 * rate:.1f} %")
    if not scenes:
        raise ConfigError(
            f"no scene to draw: none of the {n} is {args.outcome} by {args.checkpoints[0]}"
        )
    print(f"drawn: scenes {scenes} ({args.outcome} by the first)")
    rows = []
    for label, res, start in zip(labels, runs, starts, strict=True):
        names = outcome_names(res, scenes)
        rows.append(
            [
                draw_path(start[i], res["path"][i], label=f"{label} #{i}: {name}", every=args.every)
                for i, name in zip(scenes, names, strict=True)
            ]
        )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), grid(rows)[:, :, ::-1]):
        raise ConfigError(f"--out = {out}: could not be written")
    print(f"wrote {out}")
    return {"scenes": scenes, "count_in_category": n}


def main(argv: list[str] | None = None) -> int:
    return run_or_fail(run, parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
