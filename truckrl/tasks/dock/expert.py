"""The ``dock`` task's expert: the legs of a gear plan (``planner.search=gears``).

A scripted docking in four legs (the contract is in :mod:`truckrl.planning`; the tracking of a
leg, forward by the tractor rear axle, backward by the trailer axle, in
:mod:`truckrl.planning.gears`):

1. Forward set-up: the tractor rear axle drives ``setup_straight`` metres straight on from the
   start, then an arc of ``setup_radius`` turning by ``setup_turn`` towards the bay axis's
   outward direction (the nose away from the dock face, so the trailer's rear swings towards the
   bay: the usual set-up of a 90 degree reverse into a bay).
2. Reverse: the trailer axle pursues the bay axis from ``reverse_from`` metres out down to
   ``stop_short`` metres short of its goal position.
3. Forward pull-out: the tractor rear axle ``pull`` metres along the bay axis (none at 0).
4. Reverse: the trailer axle down the bay axis to its goal position, at rest.

With ``stop_short = pull = 0`` (the prior's mean) legs 3 and 4 have no length and the plan is a
set-up and one reverse; positive values add a shunt that straightens the trailer. The mean
candidate of the first prior row, with :mod:`truckrl.planning.gears`'s nominal tracking, is the
task's scripted driver.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from tensordict import TensorDict

#: The task parameters of a gear plan: (name, value at x = -1, at x = 0, at x = +1), piecewise
#: linear (:func:`truckrl.planning.gears.piecewise`); lengths in m, angles in rad, speeds in m/s.
GEAR_TASK_PARAMS: tuple[tuple[str, float, float, float], ...] = (
    ("setup_straight", 0.0, 5.0, 20.0),
    ("setup_turn", -0.5, 0.4, 1.3),
    ("setup_radius", 8.0, 15.0, 30.0),
    ("reverse_from", 6.0, 18.0, 35.0),
    ("stop_short", 0.0, 0.0, 6.0),
    ("pull", 0.0, 0.0, 8.0),
    ("forward_speed", 0.8, 1.5, 3.0),
    ("reverse_speed", 0.5, 1.0, 2.0),
)
#: Vertices per leg path.
GEAR_PATH_POINTS = 120


def gear_prior() -> Tensor:
    """``[3, 8]`` prior means in ``[-1, 1]`` (:data:`GEAR_TASK_PARAMS`), one per attempt in turn:
    the nominal set-up; no straight and a slight turn; a longer, wider set-up."""
    return torch.tensor(
        [
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [-1.0, -0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.5, 0.6, 0.3, 0.3, 0.0, 0.0, 0.0, 0.0],
        ]
    )


def gear_legs(start: TensorDict, x: Tensor) -> dict[str, Tensor]:
    """The four legs (module doc) of candidates ``x [N, 8]`` from ``start [N]``
    (:meth:`~truckrl.env.TruckEnv.get_state` layout: ``pose``, ``goal``, ``params``).

    Returns:
        ``{"gear" [N, 4], "speed" [N, 4] (m/s), "path" [N, 4, GEAR_PATH_POINTS, 2] (m, world)}``.
    """
    from truckrl.planning.gears import piecewise

    v = {n: piecewise(x[:, j], lo, mid, hi) for j, (n, lo, mid, hi) in enumerate(GEAR_TASK_PARAMS)}
    n, dev, m = x.shape[0], x.device, GEAR_PATH_POINTS
    pose, goal, p = start["pose"], start["goal"], start["params"]
    hitch = p["kingpin_offset"] + p["trailer_wheelbase"]
    u = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)  # bay axis, out of the bay
    axle_goal = goal[:, :2] - hitch[:, None] * u  # trailer axle of the goal truck
    s = torch.linspace(0.0, 1.0, m, device=dev)[None, :, None]  # [1, M, 1]

    def line(a: Tensor, b: Tensor) -> Tensor:
        return a[:, None] + s * (b - a)[:, None]

    # 1: straight on, then an arc turning the heading towards u
    phi0 = pose[:, 2]
    h = torch.stack((phi0.cos(), phi0.sin()), -1)
    sigma = torch.sign(h[:, 0] * u[:, 1] - h[:, 1] * u[:, 0] + 1e-9)
    k = m // 3
    p1 = pose[:, :2] + v["setup_straight"][:, None] * h
    straight = pose[:, None, :2] + s[:, :k] / s[:, k - 1] * (p1 - pose[:, :2])[:, None]
    phi = phi0[:, None] + (sigma * v["setup_turn"])[:, None] * s[:, : m - k, 0] / s[:, m - k - 1, 0]
    r = (sigma * v["setup_radius"])[:, None]
    arc = p1[:, None] + torch.stack(
        (r * (phi.sin() - phi0.sin()[:, None]), -r * (phi.cos() - phi0.cos()[:, None])), -1
    )
    leg1 = torch.cat((straight, arc), 1)
    # 2-4: down the bay axis, an optional pull-out and the final reverse
    short, pull = v["stop_short"][:, None], v["pull"][:, None]
    leg2 = line(axle_goal + v["reverse_from"][:, None] * u, axle_goal + short * u)
    base = axle_goal + (short + hitch[:, None]) * u
    leg3 = line(base, base + pull * u)
    leg4 = line(axle_goal + (short + pull + 3.0) * u, axle_goal)
    ones = torch.ones(n, device=dev)
    fwd, rev = v["forward_speed"], v["reverse_speed"]
    return {
        "gear": torch.stack((ones, -ones, ones, -ones), -1),
        "speed": torch.stack((fwd, rev, fwd, rev), -1),
        "path": torch.stack((leg1, leg2, leg3, leg4), 1),
    }
