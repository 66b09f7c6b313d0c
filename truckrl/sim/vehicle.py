"""Tractor-trailer geometry: per-episode randomized parameters and body contours.

Conventions (see the paper's Fig. 1):

* The tractor pose is its **rear-axle centre** ``(x, y)`` [m] and heading ``theta`` [rad].
* ``phi`` [rad] is the articulation; the trailer heading is ``theta + phi``.
* ``kingpin_offset`` is the paper's ``a_tk``: distance from the tractor rear axle to the kingpin,
  **positive when the kingpin is behind the rear axle** (this is the sign that makes the paper's
  ``phi_dot`` equation hold).
* ``trailer_wheelbase`` is the paper's ``L_ka``: kingpin to trailer axle.
* The cab is the front part of the tractor; its back wall sits ``cab_gap`` metres ahead of the
  trailer's front face at ``phi = 0``. Jack-knife = trailer body touching the cab.

Randomized parameters: every key of :data:`PARAM_KEYS` is drawn uniformly from its ``[min, max]``
per episode. Lengths are in metres, angles in radians, and the ``max_*`` limits bound speed [m/s],
acceleration [m/s^2], jerk [m/s^3], steering rate [rad/s] and steering acceleration [rad/s^2]
(all but speed symmetric in sign). Speed is signed (``v < 0`` = reversing): forward-only tasks
bound it below by the fixed ``min_speed`` [m/s] (0, not randomized); a task that reverses also
draws :data:`REVERSE_KEYS` (``max_reverse_speed`` [m/s], the bound ``v >= -max_reverse_speed``)
and its control (:class:`truckrl.sim.control.Control` with ``reverse=True``) lets the speed go
down to it. The defaults,
allowed ranges, units and meanings live in the fields of :class:`VehicleConfig` only; ``python -m
truckrl.config.schemas`` prints them as a table.

Kinematics (:func:`kinematics_step`): kinematic bicycle for the tractor plus a trailer on a hitch,

    theta_dot = v / L_t * tan(delta)
    phi_dot   = -v / L_t * tan(delta) * (1 + a_tk / L_ka * cos(phi)) - v / L_ka * sin(phi)

with ``v`` the rear-axle speed [m/s] and ``delta`` the steering angle [rad]. With ``a_tk``
positive behind the rear axle this is exact no-slip hitch kinematics (the trailer axle moves
along the trailer heading), not a small-angle approximation. The same equations hold for
``v < 0`` (reversing), where the trailer axle leads: with ``delta = 0``, ``phi_dot = -v / L_ka
sin(phi)`` gives ``tan(phi / 2) = tan(phi0 / 2) exp(-v t / L_ka)``, which decays forward and
*grows* in reverse. The articulation is open-loop unstable when reversing: without steering
corrections it runs to ``max_articulation`` (:func:`jackknifed`), and a steady steering angle
does so from ``phi = 0`` within ``max_articulation / (|v| k (1 - |a_tk| / L_ka))`` seconds
(``k = tan(delta) / L_t``). ``tests/sim/test_reverse.py`` checks reversing against these answers
and a fine RK4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, check_range, param, validate
from truckrl.sim.geometry import (
    rectangle_corners,
    rectangle_segments,
    segment_box_overlap,
    wrap_angle,
)

#: Randomized parameter keys, in the fixed order used by observations and docs.
PARAM_KEYS: tuple[str, ...] = (
    "wheelbase",
    "front_overhang",
    "rear_overhang",
    "tractor_width",
    "kingpin_offset",
    "cab_gap",
    "trailer_wheelbase",
    "trailer_front_overhang",
    "trailer_rear_overhang",
    "trailer_width",
    "max_steer",
    "max_articulation",
    "max_speed",
    "max_accel",
    "max_jerk",
    "max_steer_rate",
    "max_steer_accel",
)

#: Randomized keys drawn only for trucks that may reverse (:func:`sample_vehicle_params` with
#: ``reverse=True``), after the :data:`PARAM_KEYS` draw, so forward-only scenes are unchanged.
REVERSE_KEYS: tuple[str, ...] = ("max_reverse_speed",)


def _range(default: tuple[float, float], hi: float, unit: str, doc: str) -> tuple[float, float]:
    """A randomized ``[min, max]`` pair whose values must lie in ``(0, hi]``."""
    return param(default, lo=0.0, lo_open=True, hi=hi, unit=unit, doc=doc)


@dataclass
class VehicleConfig:
    """Ranges ``(min, max)`` of the per-episode randomized truck parameters (``env.vehicle.*``).

    Typical articulated-truck dimensions (EU semi-trailer class); the paper randomizes nearly all
    geometry per episode (Sec. "Kinematics of a tractor-trailer") without stating ranges.
    """

    wheelbase: tuple[float, float] = _range((3.4, 4.2), 20.0, "m", "L_t, front axle to rear axle")
    front_overhang: tuple[float, float] = _range((1.2, 1.6), 5.0, "m", "front axle to front bumper")
    rear_overhang: tuple[float, float] = _range(
        (0.6, 1.2), 5.0, "m", "rear axle to tractor rear end"
    )
    tractor_width: tuple[float, float] = _range((2.3, 2.55), 5.0, "m", "tractor body width")
    kingpin_offset: tuple[float, float] = param(
        (-0.5, 0.3),
        lo=-3.0,
        hi=3.0,
        unit="m",
        doc="a_tk, rear axle to kingpin, positive = behind the axle; max < rear_overhang min",
    )
    # >= 0.7 m so the widest, shortest-overhang trailer corner (sqrt(0.9^2 + 1.3^2) - 0.9 = 0.68 m
    # swing) clears the cab up to 90 deg: jack-knife contact then only happens near phi_max.
    cab_gap: tuple[float, float] = _range(
        (0.7, 1.2), 5.0, "m", "trailer front face to cab back wall at zero articulation"
    )
    trailer_wheelbase: tuple[float, float] = _range(
        (6.0, 11.0), 30.0, "m", "L_ka, kingpin to trailer axle"
    )
    trailer_front_overhang: tuple[float, float] = _range(
        (0.9, 1.6), 5.0, "m", "kingpin to trailer front face"
    )
    trailer_rear_overhang: tuple[float, float] = _range(
        (1.0, 3.5), 10.0, "m", "trailer axle to trailer rear end"
    )
    trailer_width: tuple[float, float] = _range((2.4, 2.6), 5.0, "m", "trailer body width")
    max_steer: tuple[float, float] = _range(
        (0.55, 0.70), 1.5, "rad", "steering angle limit |delta|"
    )
    max_articulation: tuple[float, float] = _range(
        (1.2, 1.4), 3.1, "rad", "articulation stop phi_max (reaching it = jack-knife)"
    )
    max_speed: tuple[float, float] = _range((6.0, 10.0), 50.0, "m/s", "forward speed limit")
    max_accel: tuple[float, float] = _range(
        (1.5, 3.0), 20.0, "m/s^2", "acceleration limit (both signs)"
    )
    max_jerk: tuple[float, float] = _range((2.0, 5.0), 100.0, "m/s^3", "jerk limit (both signs)")
    max_steer_rate: tuple[float, float] = _range(
        (0.4, 0.8), 10.0, "rad/s", "steering rate limit (both signs)"
    )
    max_steer_accel: tuple[float, float] = _range(
        (1.0, 3.0), 100.0, "rad/s^2", "steering acceleration limit (both signs)"
    )
    max_reverse_speed: tuple[float, float] = _range(
        (1.5, 3.0),
        20.0,
        "m/s",
        "reverse speed limit (speed >= -max_reverse_speed); drawn only for tasks that reverse",
    )
    min_speed: float = param(
        0.0,
        lo=-50.0,
        hi=50.0,
        unit="m/s",
        doc="fixed lower speed bound, at most max_speed min; 0 = forward driving only",
        source="paper",
    )

    def __post_init__(self) -> None:
        validate(self, "env.vehicle")
        if self.kingpin_offset[1] >= self.rear_overhang[0]:
            raise ConfigError(
                f"env.vehicle.kingpin_offset max ({self.kingpin_offset[1]}) must be below "
                f"env.vehicle.rear_overhang min ({self.rear_overhang[0]}): the kingpin sits on "
                "the tractor"
            )
        if self.min_speed > self.max_speed[0]:
            raise ConfigError(
                f"env.vehicle.min_speed = {self.min_speed} must not exceed "
                f"env.vehicle.max_speed min ({self.max_speed[0]})"
            )

    def bounds(self) -> dict[str, tuple[float, float]]:
        """``{key: (min, max)}`` for every randomized key in :data:`PARAM_KEYS`."""
        return {k: getattr(self, k) for k in PARAM_KEYS}


def sample_vehicle_params(
    cfg: VehicleConfig,
    n: int,
    generator: torch.Generator | None = None,
    device=None,
    reverse: bool = False,
) -> dict[str, Tensor]:
    """Draw ``n`` trucks uniformly from the configured ranges.

    Args:
        reverse: also draw :data:`REVERSE_KEYS` (a second draw after the first, so the
            :data:`PARAM_KEYS` values of a seed do not depend on it).

    Returns:
        ``{key: Tensor[n]}`` for every key of :data:`PARAM_KEYS` (and :data:`REVERSE_KEYS` with
        ``reverse``), float32, units in the module doc.
    """
    out = {}
    groups = [(PARAM_KEYS, cfg.bounds())]
    if reverse:
        groups.append((REVERSE_KEYS, {k: getattr(cfg, k) for k in REVERSE_KEYS}))
    for keys, bounds in groups:
        u = torch.rand(len(keys), n, generator=generator, device=device)
        for i, key in enumerate(keys):
            lo, hi = bounds[key]
            out[key] = lo + (hi - lo) * u[i]
    return out


def normalized_params(params: dict[str, Tensor], cfg: VehicleConfig) -> Tensor:
    """Parameters mapped affinely from their configured range to ``[-1, 1]``.

    Returns:
        ``[N, len(PARAM_KEYS)]``; a parameter with ``min == max`` maps to 0.
    """
    cols = []
    for key, (lo, hi) in cfg.bounds().items():
        span = hi - lo
        cols.append(
            (params[key] - 0.5 * (lo + hi)) * (2.0 / span) if span > 0 else params[key] * 0.0
        )
    return torch.stack(cols, dim=-1)


def trailer_axle(pose: Tensor, params: dict[str, Tensor]) -> Tensor:
    """Trailer axle centre ``[N, 2]`` [m] for ``pose [N, 4] = (x, y, theta, phi)``."""
    x, y, theta, phi = pose.unbind(-1)
    a, l_ka = params["kingpin_offset"], params["trailer_wheelbase"]
    psi = theta + phi
    kx = x - a * torch.cos(theta)
    ky = y - a * torch.sin(theta)
    return torch.stack((kx - l_ka * torch.cos(psi), ky - l_ka * torch.sin(psi)), dim=-1)


def truck_extents(params: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """The truck at articulation 0 relative to its tractor rear axle [m], each ``[N]``.

    Returns:
        ``(front, rear, half_width)``: tractor front bumper ahead of the axle; the rear end
        behind it (the trailer's rear, or the tractor's if that were farther); half the wider
        body. The trailer rear-centre is ``rear`` behind the axle when the trailer is the
        rearmost body (always, for the default vehicles; :func:`trailer_rear_offset`; scene generators place start and goal footprints with it).
    """
    front = torch.maximum(
        params["wheelbase"] + params["front_overhang"],
        params["trailer_front_overhang"] - params["kingpin_offset"],
    )
    rear = torch.maximum(params["rear_overhang"], trailer_rear_offset(params))
    half = 0.5 * torch.maximum(params["tractor_width"], params["trailer_width"])
    return front, rear, half


def trailer_rear_offset(params: dict[str, Tensor]) -> Tensor:
    """``[N]`` [m]: trailer rear-centre behind the tractor rear axle at articulation 0,
    ``a_tk + L_ka + trailer_rear_overhang``."""
    return params["kingpin_offset"] + params["trailer_wheelbase"] + params["trailer_rear_overhang"]


def _bodies(pose: Tensor, params: dict[str, Tensor], fn):
    x, y, theta, phi = pose.unbind(-1)
    p = params
    tractor_front = p["wheelbase"] + p["front_overhang"]
    tractor = fn(x, y, theta, tractor_front, p["rear_overhang"], 0.5 * p["tractor_width"])
    axle = trailer_axle(pose, p)
    trailer = fn(
        axle[..., 0],
        axle[..., 1],
        theta + phi,
        p["trailer_wheelbase"] + p["trailer_front_overhang"],
        p["trailer_rear_overhang"],
        0.5 * p["trailer_width"],
    )
    # cab back wall: trailer front face + gap, measured forward of the rear axle
    cab_back = -p["kingpin_offset"] + p["trailer_front_overhang"] + p["cab_gap"]
    cab = fn(x, y, theta, tractor_front, -cab_back, 0.5 * p["tractor_width"])
    return tractor, trailer, cab


def truck_corners(pose: Tensor, params: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """Corners of tractor, trailer and cab, each ``[N, 4, 2]`` [m] (counter-clockwise)."""
    return _bodies(pose, params, rectangle_corners)


def truck_segments(pose: Tensor, params: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """Contours of tractor, trailer and cab as segments, each ``[N, 4, 4]`` [m].

    ``pose [N, 4] = (x, y, theta, phi)``: tractor rear-axle centre, heading, articulation.
    The tractor and trailer contours together are the vehicle outline used for collision and
    rendering; the cab contour is the tractor part the trailer must never touch (jack-knife).
    """
    return _bodies(pose, params, rectangle_segments)


def truck_boxes(pose: Tensor, params: dict[str, Tensor]) -> tuple[tuple[Tensor, ...], ...]:
    """Tractor, trailer and cab as rectangle parameters for :func:`geometry.segment_box_overlap`.

    Returns:
        Three tuples ``(cx, cy, heading, front, rear, half_width)``, each entry ``[N]``.
    """
    return _bodies(pose, params, lambda *box: box)


def vehicle_outline(pose: Tensor, params: dict[str, Tensor]) -> Tensor:
    """Tractor and trailer contours concatenated: ``[N, 8, 4]`` segments [m]."""
    tractor, trailer, _ = truck_segments(pose, params)
    return torch.cat((tractor, trailer), dim=-2)


#: Margin [rad] under ``max_articulation`` at which the hitch counts as at its stop (jack-knife);
#: covers float32 round-off of the clamp in :func:`kinematics_step`.
ARTICULATION_STOP_EPS = 1e-6


def check_dt(dt: float) -> float:
    """Validate a time step ``dt`` [s] (finite, ``> 0``) and return it as float.

    Raises:
        ConfigError: naming ``dt``.
    """
    return check_range("dt", dt, 0.0, math.inf, lo_open=True, hi_open=True)


def kinematics_step(
    pose: Tensor,
    speed: Tensor,
    steer: Tensor,
    params: dict[str, Tensor],
    dt: float,
    substeps: int = 1,
) -> tuple[Tensor, Tensor]:
    """Advance the tractor-trailer by ``dt`` with speed and steering held constant.

    Explicit (forward) Euler on ``substeps`` equal sub-steps of ``dt / substeps``. Each
    sub-step evaluates ``theta_dot`` and ``phi_dot`` at its start, moves the rear axle by the
    body-frame displacement ``[v h, 0]`` rotated by the start heading, wraps ``theta`` and
    ``phi`` to ``[-pi, pi)`` and clamps ``|phi| <= max_articulation``. ``substeps=1`` is the
    paper's scheme (one Euler step per control step, paper: dt = 0.1 s); the global error is
    first order, i.e. shrinks linearly with ``dt / substeps``.

    Args:
        pose: ``[N, 4]`` = ``(x [m], y [m], theta [rad], phi [rad])``, tractor rear-axle centre.
        speed: ``[N]`` rear-axle speed ``v`` [m/s] (negative = reversing).
        steer: ``[N]`` steering angle ``delta`` [rad], ``|delta| < pi / 2``.
        params: per-env parameters ``{key: Tensor[N]}`` (uses ``wheelbase``,
            ``kingpin_offset``, ``trailer_wheelbase``, ``max_articulation``).
        dt: step [s], ``> 0``.
        substeps: Euler sub-steps per ``dt``, ``>= 1``.

    Returns:
        ``(pose [N, 4], clamped [N] bool)``: the new pose and whether the articulation stop
        was hit (``|phi|`` would have exceeded ``max_articulation``) in any sub-step.

    Raises:
        ConfigError: ``dt <= 0`` or ``substeps < 1``.
    """
    h = check_dt(dt)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ConfigError(f"substeps = {substeps!r} must be an integer >= 1")
    h /= substeps
    l_t, a = params["wheelbase"], params["kingpin_offset"]
    l_ka, phi_max = params["trailer_wheelbase"], params["max_articulation"]
    yaw_rate = speed * torch.tan(steer) / l_t  # constant over the step: v and delta are held
    x, y, theta, phi = pose.unbind(-1)
    clamped = torch.zeros_like(phi, dtype=torch.bool)
    for _ in range(substeps):
        phi_rate = -yaw_rate * (1.0 + a / l_ka * torch.cos(phi)) - speed / l_ka * torch.sin(phi)
        x = x + speed * h * torch.cos(theta)
        y = y + speed * h * torch.sin(theta)
        theta = wrap_angle(theta + yaw_rate * h)
        phi = wrap_angle(phi + phi_rate * h)
        clamped = clamped | (phi.abs() > phi_max)
        phi = torch.minimum(torch.maximum(phi, -phi_max), phi_max)
    return torch.stack((x, y, theta, phi), dim=-1), clamped


def jackknifed(pose: Tensor, params: dict[str, Tensor]) -> Tensor:
    """Whether the trailer is jack-knifed.

    True where the trailer contour touches the cab (any trailer edge meets the filled cab
    rectangle, :func:`truck_boxes`), or the articulation is at its stop:
    ``|phi| >= max_articulation - ARTICULATION_STOP_EPS``.

    Args:
        pose: ``[N, 4]`` = ``(x, y, theta, phi)`` [m, m, rad, rad].
        params: per-env parameters ``{key: Tensor[N]}``.

    Returns:
        ``[N]`` bool.
    """
    _, trailer, _ = truck_segments(pose, params)
    _, _, cab = truck_boxes(pose, params)
    touching = segment_box_overlap(trailer, *cab).any(-1)
    at_stop = pose[..., 3].abs() >= params["max_articulation"] - ARTICULATION_STOP_EPS
    return touching | at_stop


def steady_state_articulation(steer: Tensor, params: dict[str, Tensor]) -> Tensor:
    """Articulation [rad] the trailer settles to under a constant steering angle (forward driving;
    in reverse the same point is an unstable equilibrium, see below).

    With ``k = tan(delta) / L_t`` [1/m] the equilibria of ``phi_dot`` (independent of ``v``) solve

        L_ka k + a k cos(phi) + sin(phi) = 0.

    Write ``sin(phi) + a k cos(phi) = R sin(phi + beta)`` with ``R = sqrt(1 + (a k)^2)`` and
    ``beta = atan(a k)``; then ``sin(phi + beta) = -L_ka k / R``, whose two solutions are
    ``phi_1 = asin(-L_ka k / R) - beta`` and ``phi_2 = pi - asin(-L_ka k / R) - beta``. Since
    ``d(phi_dot)/d(phi) = -(v / L_ka) R cos(phi + beta)``, the equilibrium with
    ``cos(phi + beta) > 0`` is stable for ``v > 0``: that is ``phi_1``, returned here (in reverse,
    ``v < 0``, the same point is the unstable one). It exists only when
    ``|k| <= 1 / sqrt(L_ka^2 - a^2)``, i.e. the kingpin's turning radius is at least ``L_ka``;
    beyond that no steady state exists (the trailer folds until the stop) and the result is NaN.

    Args:
        steer: steering angle ``delta`` [rad], shape ``[...]`` broadcasting with the params.
        params: uses ``wheelbase``, ``kingpin_offset``, ``trailer_wheelbase``.

    Returns:
        ``phi_ss`` [rad] in ``(-pi, pi)``, NaN where no steady state exists.
    """
    k = torch.tan(steer) / params["wheelbase"]
    ak = params["kingpin_offset"] * k
    return torch.asin(-params["trailer_wheelbase"] * k / torch.sqrt(1.0 + ak * ak)) - torch.atan(ak)


#: Trailer parameters whose sum is the trailer length [m].
TRAILER_KEYS = ("trailer_front_overhang", "trailer_wheelbase", "trailer_rear_overhang")


def trailer_length(params: dict[str, Tensor]) -> Tensor:
    """Trailer body length [m] ``[E]``: front overhang + wheelbase + rear overhang."""
    return sum((params[k] for k in TRAILER_KEYS[1:]), params[TRAILER_KEYS[0]])
