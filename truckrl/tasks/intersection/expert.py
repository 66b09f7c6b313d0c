"""The intersection's expert: the planner's steering prior for a turn from one lane into another.

:mod:`truckrl.planning` reads :func:`steering_prior` from here for ``planner.steer_prior=arc``
(and ``alternate``): the mean candidate then drives the turn on a circular arc tangent to the
start lane and the goal lane, and the planner's steering knots are corrections to it.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from truckrl.sim.geometry import wrap_angle
from truckrl.tasks.intersection.task import lane_corner


def steering_prior(pose: Tensor, goal: Tensor, params: Mapping[str, Tensor], f: Tensor) -> Tensor:
    """``[N, 3]`` arc prior: the travel [m] where the arc starts and ends, and its steering angle
    [rad], for start poses ``pose [N, 3]`` and goals ``goal [N, 3]`` (rear axle x, y [m], heading
    [rad]), trucks ``params {key: [N]}`` and the planned radius fraction ``f [N]`` in ``[0, 1]``.

    The start lane is the line through the start rear axle along its heading, the goal lane
    likewise; where they meet at a corner ahead of the start and before the goal
    (:func:`~truckrl.tasks.intersection.task.lane_corner`, as the lane route), the prior is the
    circle of radius ``R`` tangent to both lanes, driven by the tractor rear axle at steering
    ``atan(wheelbase / R)``: straight for ``a - R tan(turn / 2)``, then the arc for ``R |turn|``
    (``a``, ``b``: start-corner and corner-goal distances). ``R`` runs from ``R_lo =
    max(wheelbase / tan(max_steer), trailer wheelbase)`` (the tractor's tightest circle, and the
    kingpin circle below which the articulation grows to the jack-knife limit) to the largest
    circle that fits both legs, ``min(a, b) / tan(turn / 2)``, at ``f``. Elsewhere (parallel
    lanes: a straight road, straight on) the prior is 0 and the knots steer alone.
    """
    p = params
    a, b, real = lane_corner(pose, goal)  # start -> corner, corner -> goal [m]
    turn = wrap_angle(goal[:, 2] - pose[:, 2])
    half = (0.5 * turn.abs()).tan().clamp_min(1e-6)
    r_lo = torch.maximum(p["wheelbase"] / p["max_steer"].tan(), p["trailer_wheelbase"])
    r_fit = torch.minimum(a, b) / half
    r = r_lo + f * (r_fit - r_lo).clamp_min(0.0)
    begin = (a - r * half).clamp_min(0.0)
    steer = torch.where(real, turn.sign() * torch.atan(p["wheelbase"] / r), 0.0)
    return torch.stack((begin, begin + r * turn.abs(), steer), -1)
