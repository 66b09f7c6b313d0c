"""Where a ``uturn`` policy fails: its episodes split by branch side and outcome, how far each
got through the manoeuvre, and what the collided trucks touched.

``truckrl tools diagnose`` prints it (:mod:`truckrl.tools.diagnose`). Every episode runs in the
same seeded scenes as ``truckrl eval`` (same ``episodes`` and ``seed``), with the
mean action. Per episode it records, from the env's state at every step:

* ``pulled``: the truck pulled past the branch (the task's latched state entry);
* ``depth`` [m]: the deepest the trailer axle got beyond the branch-side curb line, measured
  across the road (negative: it never left the road);
* ``turned``: the tractor heading came more than 90 deg from the start heading;
* ``closest`` [m]: the closest the tractor's rear axle came to the goal after any step (the
  position error success reads), with the step and the tractor's and trailer's heading errors
  [rad] there, and ``reached``: whether that is within the position tolerance. A time-out that
  reached the goal's position failed on its headings, then drove on;
* for a collision, which segments each body touched at the last step before it, the bodies
  lengthened at both ends by that step's reach ``(|v| + max_accel dt) dt + margin`` and widened
  by ``margin`` plus a tenth of the reach (a turning body's corners move a little sideways), so
  what the step hits counts; rarely a neighbour within that reach counts too.

All of it reads states; nothing here steps the physics itself.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch
from torch import Tensor

from truckrl.env import TruckEnv
from truckrl.sim.collision import touching
from truckrl.sim.vehicle import trailer_axle
from truckrl.tasks import EnvConfig
from truckrl.tasks.uturn.scene import SEGMENT_NAMES

#: Outcome codes of :func:`diagnose`'s ``outcome`` entry.
OUTCOME_NAMES = ("timeout", "success", "collision", "jack-knife")


def trailer_depth(pose: Tensor, params: dict[str, Tensor], info: dict[str, Tensor]) -> Tensor:
    """``[N]`` [m]: the trailer axle's distance beyond the branch-side curb line, across the road
    (negative on the road). ``info``: the scene metadata (``mouth_x``, ``mouth_y`` = the road
    centreline at the branch, ``road_heading``, ``road_width``, ``branch_side``)."""
    axle = trailer_axle(pose, params)
    h = info["road_heading"]
    across = -(axle[:, 0] - info["mouth_x"]) * h.sin() + (axle[:, 1] - info["mouth_y"]) * h.cos()
    return info["branch_side"] * across - 0.5 * info["road_width"]


@torch.no_grad()
def diagnose(
    actor: Any,
    env_cfg: EnvConfig,
    difficulty: float,
    episodes: int,
    seed: int,
    margin: float = 0.05,
) -> dict[str, Tensor]:
    """Run each scene's first episode with ``actor``'s mean action; per-episode ``[E]`` tensors:
    ``outcome`` (long, :data:`OUTCOME_NAMES`), ``left`` (bool), ``pulled``, ``turned`` (bool),
    ``depth`` [m], ``length`` [steps], ``closest`` [m], ``closest_step`` (long, 1-based),
    ``closest_tractor``, ``closest_trailer`` [rad], ``reached`` (bool) (module doc), and
    ``tractor_hit``, ``trailer_hit`` ``[E, S]`` bool (segment slots,
    :data:`~truckrl.tasks.uturn.scene.SEGMENT_NAMES`; all False but for collisions)."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    if env_cfg.task.name != "uturn":
        raise ValueError(f"task {env_cfg.task.name!r}: the diagnosis is for task 'uturn'")
    env = TruckEnv(num_envs=episodes, config=dataclasses.replace(env_cfg, compile=False), seed=seed)
    env.set_difficulty(difficulty)
    td = env.reset()
    first = env.get_state()
    info = {k: first["route", k] for k in first["route"].keys()}
    params = {k: first["params", k] for k in first["params"].keys()}
    n, slots = episodes, first["segments"].shape[1]
    ended = torch.zeros(n, dtype=torch.bool)
    outcome = torch.zeros(n, dtype=torch.long)
    length = torch.zeros(n, dtype=torch.long)
    pulled = torch.zeros(n, dtype=torch.bool)
    turned = torch.zeros(n, dtype=torch.bool)
    depth = torch.full((n,), -math.inf)
    hits = torch.zeros(2, n, slots, dtype=torch.bool)
    closest = torch.full((n,), math.inf)
    closest_step = torch.zeros(n, dtype=torch.long)
    closest_heading = torch.zeros(2, n)
    s = first
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for t in range(env_cfg.max_steps):
            live = ~ended
            pose = s["pose"]
            depth = torch.where(
                live, torch.maximum(depth, trailer_depth(pose, params, info)), depth
            )
            back = torch.cos(pose[:, 2] - s["start_heading"]) < 0.0
            turned |= back & live
            nxt = env.step(actor(td))["next"]
            done = nxt["done"].squeeze(-1) & live
            # the state after the step, as success reads it (the terminal one included)
            pos = nxt["pos_error"].squeeze(-1)
            nearer = live & (pos < closest)
            closest = torch.where(nearer, pos, closest)
            closest_step = torch.where(nearer, t + 1, closest_step)
            heading = torch.stack(
                (nxt["tractor_heading_error"].squeeze(-1), nxt["trailer_heading_error"].squeeze(-1))
            )
            closest_heading = torch.where(nearer, heading, closest_heading)
            pulled |= (s["pulled"] > 0.5) & live
            code = _outcome_code(nxt)
            outcome = torch.where(done, code, outcome)
            length = torch.where(done, t + 1, length)
            crashed = done & (code == 2)
            if bool(crashed.any()):
                tr, tl = _touched(s, params, first, env_cfg.dt, margin)
                hits[0] |= tr & crashed[:, None]
                hits[1] |= tl & crashed[:, None]
            ended |= done
            if bool(ended.all()):
                break
            td = nxt
            s = env.get_state()
    tol_pos = env.tolerances()[0]
    env.close()
    return {
        "outcome": outcome,
        "left": info["branch_side"] > 0,
        "pulled": pulled,
        "turned": turned,
        "depth": depth,
        "length": length,
        "closest": closest,
        "closest_step": closest_step,
        "closest_tractor": closest_heading[0],
        "closest_trailer": closest_heading[1],
        "reached": closest <= tol_pos,
        "tractor_hit": hits[0],
        "trailer_hit": hits[1],
    }


def _outcome_code(nxt: Any) -> Tensor:
    """``[E]`` long: each env's outcome code after a step (:data:`OUTCOME_NAMES`; 0 also where
    the episode goes on)."""
    return torch.where(
        nxt["success"].squeeze(-1),
        1,
        torch.where(
            nxt["collision"].squeeze(-1), 2, torch.where(nxt["jackknife"].squeeze(-1), 3, 0)
        ),
    )


def _touched(
    s: Any, params: dict[str, Tensor], first: Any, dt: float, margin: float
) -> tuple[Tensor, Tensor]:
    """Which segment slots ``[E, S]`` the tractor and the trailer of state ``s`` touch, each body
    lengthened by the step's reach ``(|v| + max_accel dt) dt + margin`` and widened by ``margin``
    plus a tenth of it (module doc); the segments are those of the reset state ``first``."""
    travel = (s["speed"].abs() + params["max_accel"] * dt) * dt
    return touching(
        s["pose"],
        params,
        first["segments"],
        first["mask"],
        along=travel + margin,
        across=0.1 * travel + margin,
    )


def summarize_diagnosis(d: dict[str, Tensor]) -> list[dict[str, Any]]:
    """One row per (branch side, outcome) with episodes: count, shares pulled / turned round,
    median deepest trailer depth [m], median closest approach to the goal [m] and trailer
    heading error there [deg], share that reached the goal's position, and for collisions the
    count per (body, segment)."""
    rows = []
    for left, side in ((False, "right"), (True, "left")):
        for code, name in enumerate(OUTCOME_NAMES):
            m = (d["left"] == left) & (d["outcome"] == code)
            k = int(m.sum())
            if k == 0:
                continue
            row: dict[str, Any] = {
                "branch": side,
                "outcome": name,
                "episodes": k,
                "pulled": float(d["pulled"][m].float().mean()),
                "turned": float(d["turned"][m].float().mean()),
                "depth_median_m": float(d["depth"][m].median()),
                "closest_median_m": float(d["closest"][m].median()),
                "closest_trailer_median_deg": math.degrees(float(d["closest_trailer"][m].median())),
                "reached": float(d["reached"][m].float().mean()),
            }
            if name == "collision":
                row["touched"] = {
                    f"{body}: {SEGMENT_NAMES[e]}": int(hit[m, e].sum())
                    for body, hit in (("tractor", d["tractor_hit"]), ("trailer", d["trailer_hit"]))
                    for e in range(hit.shape[1])
                    if int(hit[m, e].sum()) > 0
                }
            rows.append(row)
    return rows


def format_diagnosis(rows: list[dict[str, Any]]) -> str:
    """The rows of :func:`summarize_diagnosis` as a text table (collisions' touches below)."""
    lines = [
        f"{'branch':7s}{'outcome':12s}{'episodes':>9s}{'pulled':>8s}{'turned':>8s}{'depth m':>9s}"
        f"{'closest m':>11s}{'trailer deg':>13s}{'reached':>9s}",
        "-" * 86,
    ]
    for r in rows:
        lines.append(
            f"{r['branch']:7s}{r['outcome']:12s}{r['episodes']:9d}{100 * r['pulled']:7.0f}%"
            f"{100 * r['turned']:7.0f}%{r['depth_median_m']:9.1f}{r['closest_median_m']:11.2f}"
            f"{r['closest_trailer_median_deg']:13.1f}{100 * r['reached']:8.0f}%"
        )
        for part, k in sorted(r.get("touched", {}).items(), key=lambda kv: -kv[1]):
            lines.append(f"{'':19s}touched {part}: {k}")
    return "\n".join(lines)
