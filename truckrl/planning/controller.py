"""The planner's control law: set-point interpolation, the deadbeat tracker, the goal-line pursuit.

Every function is pure torch on batches of ``N`` candidates and runs inside the compiled rollout
step (:meth:`truckrl.planning.rollout.Planner._step_fn`). A state ``s`` is the flat dict of
:func:`truckrl.planning.rollout.flat_state`: ``pose [N, 4]`` (rear axle x, y [m], heading,
articulation [rad]), ``goal [N, 3]``, the control state and ``params {key: [N]}``.
:func:`setpoint_action` is the scripted drivers' tracker (the task experts' ``expert.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from truckrl.sim.control import ControlConfig


def knot_matrix(steps: int, knots: int, device: torch.device | str | None = None) -> Tensor:
    """``[steps, knots]`` weights of linear interpolation between ``knots`` evenly spread values
    (knot 0 at step 0, the last at step ``steps - 1``; one knot = a constant)."""
    if knots == 1:
        return torch.ones(steps, 1, device=device)
    pos = torch.linspace(0.0, knots - 1.0, steps, device=device)
    left = pos.floor().clamp(max=knots - 2).long()
    frac = pos - left
    w = torch.zeros(steps, knots, device=device)
    rows = torch.arange(steps, device=device)
    w[rows, left] = 1.0 - frac
    w[rows, left + 1] += frac
    return w


def interp(knots: Tensor, frac: Tensor) -> Tensor:
    """Linear interpolation of ``knots [N, M]`` (evenly spread over ``[0, 1]``) at ``frac [N]``
    (clamped to ``[0, 1]``)."""
    m = knots.shape[1]
    pos = frac.clamp(0.0, 1.0) * (m - 1)
    left = pos.floor().clamp(max=max(m - 2, 0)).long()
    right = (left + 1).clamp(max=m - 1)
    w = (pos - left).clamp(0.0, 1.0)
    lo, hi = knots.gather(1, left[:, None])[:, 0], knots.gather(1, right[:, None])[:, 0]
    return lo + w * (hi - lo)


def track(
    ref: Tensor, q: Sequence[Tensor], hi: Sequence[Tensor], lo0: Tensor, order: int, dt: float
) -> Tensor:
    """Command in ``[-1, 1]`` that moves chain ``q = (q0, q1, q2)`` towards ``q0 = ref``.

    ``order`` is the control mode's derivative order (0: the command sets ``q0`` within
    ``[lo0, hi[0]]``; 1: it sets ``q1`` up to ``hi[1]``; 2: it sets ``q2`` up to ``hi[2]``, with
    ``q1`` aimed at closing the gap in three steps of ``dt`` [s]): a deadbeat tracker, so the
    rate, acceleration and speed limits shape every candidate.
    """
    if order == 0:
        u = (2.0 * ref - (hi[0] + lo0)) / (hi[0] - lo0)
    elif order == 1:
        u = (ref - q[0]) / (dt * hi[1])
    else:
        rate = torch.minimum(torch.maximum((ref - q[0]) / (3.0 * dt), -hi[1]), hi[1])
        u = (rate - q[1]) / (dt * hi[2])
    return u.clamp(-1.0, 1.0)


def _hitch_points(s: dict[str, Any]) -> tuple[Tensor, Tensor, Tensor]:
    """``(trailer axle [N, 2] [m], trailer heading psi [N] [rad], goal direction [N, 2])``."""
    pose, goal, p = s["pose"], s["goal"], s["params"]
    theta, phi = pose[:, 2], pose[:, 3]
    psi = theta + phi
    a, l_ka = p["kingpin_offset"], p["trailer_wheelbase"]
    king = pose[:, :2] - a[:, None] * torch.stack((theta.cos(), theta.sin()), -1)
    axle = king - l_ka[:, None] * torch.stack((psi.cos(), psi.sin()), -1)
    d = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)
    return axle, psi, d


def _blend(s: dict[str, Any], k_tractor: Tensor, phi_rate: Tensor, w: Tensor) -> Tensor:
    """Steering angle [rad] of the blend ``(1 - w) k_tractor + w k_trailer`` of path curvatures
    [1/m], ``k_trailer`` the tractor curvature that makes the articulation change at
    ``phi_rate`` per metre (inverted hitch kinematics of
    :func:`truckrl.sim.vehicle.kinematics_step`)."""
    p, phi = s["params"], s["pose"][:, 3]
    a, l_ka = p["kingpin_offset"], p["trailer_wheelbase"]
    k_trailer = -(phi_rate + phi.sin() / l_ka) / (1.0 + a / l_ka * phi.cos())
    return torch.atan(((1.0 - w) * k_tractor + w * k_trailer) * p["wheelbase"])


def pursuit(s: dict[str, Any], plan: Tensor) -> Tensor:
    """Steering angle [rad] ``[N]`` that pursues the goal line (the line through the goal along
    its heading) driving forwards; ``plan [N, 5]`` as
    :meth:`truckrl.planning.rollout.Planner._extras` (uses the look-ahead [m], the gain [1/m] and
    the blend weight of the trailer law).

    Both laws aim ``look-ahead`` metres ahead of their point's projection on the goal line.
    Tractor: pure pursuit of the rear axle. Trailer: pure pursuit of the trailer axle gives a
    trailer curvature ``k_t``, hence an articulation set-point ``phi_d = asin(-k_t L_ka)``,
    which the tractor's curvature tracks at ``gain`` per metre driven (``phi' = gain (phi_d -
    phi)``): driving the trailer onto the line lines up the tractor too, in less distance than a
    trailer settling behind a tractor on the line.
    """
    pose, goal = s["pose"], s["goal"]
    theta, phi, l_ka = pose[:, 2], pose[:, 3], s["params"]["trailer_wheelbase"]
    axle, psi, d = _hitch_points(s)

    def pursue(point: Tensor, heading: Tensor) -> Tensor:
        along = ((point - goal[:, :2]) * d).sum(-1)
        vec = goal[:, :2] + (along + plan[:, 1])[:, None] * d - point
        alpha = torch.atan2(vec[:, 1], vec[:, 0]) - heading
        return 2.0 * torch.sin(alpha) / vec.norm(dim=-1).clamp_min(1e-3)

    k_tractor = pursue(pose[:, :2], theta)
    phi_d = torch.asin((-pursue(axle, psi) * l_ka).clamp(-0.95, 0.95))
    phi_rate = plan[:, 2] * (phi_d - phi)  # per metre driven
    return _blend(s, k_tractor, phi_rate, plan[:, 3])


def pursuit_signed(s: dict[str, Any], plan: Tensor, backward: Tensor) -> Tensor:
    """:func:`pursuit` for a task that reverses: where ``backward [N]`` (the speed set-point is
    negative) the laws pursue the goal line in the direction of motion, backwards.

    With ``sigma = -1`` backwards (``+1`` forwards), both laws aim ``look-ahead`` metres from
    their point's projection on the goal line, in the direction the point moves along it, and
    pure pursuit runs on the motion heading (``heading + pi`` backwards); the signed path
    curvature (per metre of signed travel, as ``tan(delta) / L_t``) is ``sigma`` times pure
    pursuit's. Backwards the trailer axle leads: its pursuit gives the trailer curvature ``k_t``,
    hence ``phi_d = asin(-k_t L_ka)`` (limited to ``asin(0.5)`` backwards, where the hitch is
    unstable), and the tractor curvature makes the articulation follow it at ``gain`` per metre
    driven, ``d phi / d|s| = gain (phi_d - phi)``, by inverting the hitch kinematics
    (``d phi / ds = -k (1 + a / L_ka cos phi) - sin(phi) / L_ka``, ``s`` signed travel).
    Backwards only the trailer law is used (steering the tractor onto the line folds the
    trailer); forwards it is :func:`pursuit`'s planned blend.
    """
    pose, goal = s["pose"], s["goal"]
    theta, phi, l_ka = pose[:, 2], pose[:, 3], s["params"]["trailer_wheelbase"]
    axle, psi, d = _hitch_points(s)
    sigma = torch.where(backward, -1.0, 1.0)
    turn = torch.where(backward, math.pi, 0.0)

    def pursue(point: Tensor, heading: Tensor) -> Tensor:
        along = ((point - goal[:, :2]) * d).sum(-1)
        # look ahead along the line in the direction the point moves (either goal heading)
        ahead = sigma * (heading.cos() * d[:, 0] + heading.sin() * d[:, 1])
        step = torch.where(ahead < 0, -plan[:, 1], plan[:, 1])
        vec = goal[:, :2] + (along + step)[:, None] * d - point
        alpha = torch.atan2(vec[:, 1], vec[:, 0]) - heading - turn
        return sigma * 2.0 * torch.sin(alpha) / vec.norm(dim=-1).clamp_min(1e-3)

    k_tractor = pursue(pose[:, :2], theta)
    limit = torch.where(backward, 0.5, 0.95)
    phi_d = torch.asin(torch.maximum(torch.minimum(-pursue(axle, psi) * l_ka, limit), -limit))
    phi_rate = sigma * plan[:, 2] * (phi_d - phi)  # per metre of signed travel
    return _blend(s, k_tractor, phi_rate, torch.where(backward, 1.0, plan[:, 3]))


def arrival_distance(s: dict[str, Any], slack: float) -> Tensor:
    """Distance [m] ``[N]`` the arrival cap brakes over in a task that reverses: from the tractor
    rear axle to the goal (a rear-axle pose), ignoring the first ``slack`` metres across the
    goal line, ``sqrt(along^2 + max(|across| - slack, 0)^2)``. A truck that arrives slightly off
    the line still brakes to the arrival speed at the goal (a task whose success needs the truck
    at rest, e.g. docking) instead of passing it at the speed that the residual offset allows."""
    goal, rel = s["goal"], s["pose"][:, :2] - s["goal"][:, :2]
    c, sn = goal[:, 2].cos(), goal[:, 2].sin()
    along = rel[:, 0] * c + rel[:, 1] * sn
    across = (-rel[:, 0] * sn + rel[:, 1] * c).abs() - slack
    return torch.hypot(along, across.clamp_min(0.0))


def setpoint_action(
    speed: Tensor,
    steer: Tensor,
    s: Mapping[str, Any],
    control: ControlConfig,
    dt: float,
) -> Tensor:
    """The action ``[n, 2]`` in ``[-1, 1]`` that moves speed and steering towards set-points.

    ``speed`` mode: the affine map of :mod:`truckrl.sim.control` onto
    ``[-max_reverse_speed, max_speed]``; ``angle``: ``steer / max_steer``. ``accel`` / ``rate``:
    the rate that reaches the set-point in one step of ``dt`` [s], clamped to the mode's bound
    (a dead-beat tracker). The second-order modes (jerk, steering acceleration) are not
    supported.

    Raises:
        ValueError: a jerk or steering-acceleration control mode.
    """
    p = s["params"]
    if control.longitudinal == "speed":
        lo, hi = -p["max_reverse_speed"], p["max_speed"]
        u_lon = 2 * (speed - lo) / (hi - lo) - 1
    elif control.longitudinal == "accel":
        u_lon = (speed - s["speed"]) / (dt * p["max_accel"])
    else:
        raise ValueError(
            f"control.longitudinal = {control.longitudinal!r}: the scripted driver supports "
            "speed and accel"
        )
    if control.lateral == "angle":
        u_lat = steer / p["max_steer"]
    elif control.lateral == "rate":
        u_lat = (steer - s["steer"]) / (dt * p["max_steer_rate"])
    else:
        raise ValueError(
            f"control.lateral = {control.lateral!r}: the scripted driver supports angle and rate"
        )
    return torch.stack((u_lon, u_lat), -1).clamp(-1.0, 1.0)
