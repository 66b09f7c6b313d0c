"""Control abstractions: which derivative of speed and steering the policy commands.

Paper Sec. "Control abstractions": the longitudinal axis is commanded as speed, acceleration or
jerk, the lateral axis as steering angle, rate or acceleration; any pairing is a config choice
(paper default: acceleration + steering rate). Each axis is a chain of three quantities

==========  ==============  ==============  ===============
axis        order 0         order 1         order 2
==========  ==============  ==============  ===============
long.       speed [m/s]     accel [m/s^2]   jerk [m/s^3]
lateral     steer [rad]     steer_rate      steer_accel
                            [rad/s]         [rad/s^2]
==========  ==============  ==============  ===============

with per-env bounds from the vehicle params: speed in ``[min_speed, max_speed]`` (a control built
with ``reverse=True``: ``[-max_reverse_speed, max_speed]``, per truck), every other
quantity in ``[-max_q, max_q]`` (``max_accel``, ``max_jerk``, ``max_steer``, ``max_steer_rate``,
``max_steer_accel``). An action component ``u`` is clamped to ``[-1, 1]`` and mapped affinely
onto the commanded quantity's bounds (``u * max_q``; speed: ``-1 -> min_speed``,
``+1 -> max_speed``). Speed is signed: with ``reverse=True`` the speed mode maps ``-1 ->
-max_reverse_speed`` and ``+1 -> max_speed``, still affinely, so ``u = 0`` is the middle of that
range (a slow forward speed), not standstill, which is ``u = (max_reverse_speed - max_speed) /
(max_reverse_speed + max_speed)``; the accel and jerk modes are unchanged (``u = 0`` holds the
speed or acceleration; a negative acceleration at rest drives backwards). A forward-only control
(``reverse=False``, ``min_speed = 0``) never goes below 0. Per mode, one step of length ``dt``
does:

=============  ===================================================================================
mode           update (``'`` = new value, ``clip`` = clamp to that quantity's bounds)
=============  ===================================================================================
speed (long.)  ``v' = command``; ``a' = clip((v' - v) / dt)``; ``j' = clip((a' - a) / dt)``
accel (long.)  ``a' = command``; ``v' = clip(v + a' dt)``; if ``v'`` was clipped,
               ``a' = clip((v' - v) / dt)``; ``j' = clip((a' - a) / dt)``
jerk (long.)   ``j' = command``; ``a' = clip(a + j' dt)``; ``v' = clip(v + a' dt)``; if ``v'`` was
               clipped, ``a' = clip((v' - v) / dt)``; if ``a'`` was clipped or rewritten,
               ``j' = clip((a' - a) / dt)``
angle (lat.)   as speed, with ``(steer, steer_rate, steer_accel)``
rate (lat.)    as accel, with ``(steer, steer_rate, steer_accel)``
accel (lat.)   as jerk, with ``(steer, steer_rate, steer_accel)``
=============  ===================================================================================

So the commanded quantity and everything below it are integrated with semi-implicit Euler
(``q' = q + q_dot' dt``, the new rate moves the lower quantity), and when a lower quantity
saturates the rates above it are replaced by what was actually realised: the state always
satisfies ``v' = v + a' dt`` (and likewise up the chain) unless a realised rate had to be
clipped to its own bound (e.g. an instant stop at the speed limit from full acceleration, which
would need more than ``max_jerk``). Quantities above the commanded one are finite differences
of what happened, clipped to their bounds; they feed the observation, not the motion. Speed
and angle commands take effect instantly (an ideal set-point), as in the paper.

Non-finite action entries are not sanitized here: NaN propagates into the state. Callers
(the environment) must reject or mask them before calling :meth:`Control.step`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import torch
from torch import Tensor

from truckrl.config.fields import (
    ConfigError,
    check_choice,
    check_range,
    from_mapping,
    param,
    validate,
)

#: The control-mode vocabulary, the one place it is spelled out: per axis, per mode (in chain
#: order 0, 1, 2), the state key the mode commands and the vehicle parameter that bounds it.
MODE_TABLE: Mapping[str, Mapping[str, tuple[str, str]]] = MappingProxyType(
    {
        "longitudinal": MappingProxyType(
            {
                "speed": ("speed", "max_speed"),
                "accel": ("accel", "max_accel"),
                "jerk": ("jerk", "max_jerk"),
            }
        ),
        "lateral": MappingProxyType(
            {
                "angle": ("steer", "max_steer"),
                "rate": ("steer_rate", "max_steer_rate"),
                "accel": ("steer_accel", "max_steer_accel"),
            }
        ),
    }
)

LONGITUDINAL_MODES: tuple[str, ...] = tuple(MODE_TABLE["longitudinal"])
LATERAL_MODES: tuple[str, ...] = tuple(MODE_TABLE["lateral"])

#: State keys, in the fixed order used by observations: longitudinal chain then lateral chain.
CONTROL_KEYS: tuple[str, ...] = tuple(
    key for axis in MODE_TABLE.values() for key, _ in axis.values()
)

_LONG_KEYS = tuple(key for key, _ in MODE_TABLE["longitudinal"].values())
_LAT_KEYS = tuple(key for key, _ in MODE_TABLE["lateral"].values())
_LONG_LIMITS = tuple(limit for _, limit in MODE_TABLE["longitudinal"].values())
_LAT_LIMITS = tuple(limit for _, limit in MODE_TABLE["lateral"].values())


def commanded(longitudinal: str, lateral: str) -> tuple[tuple[str, str], tuple[str, str]]:
    """What a mode pair commands: ``((lon_state_key, lon_limit_key), (lat_state_key,
    lat_limit_key))``, e.g. ``commanded("accel", "rate") == (("accel", "max_accel"),
    ("steer_rate", "max_steer_rate"))``.

    Raises:
        ConfigError: an unknown mode, naming ``control.longitudinal`` / ``control.lateral``.
    """
    check_choice("control.longitudinal", longitudinal, LONGITUDINAL_MODES)
    check_choice("control.lateral", lateral, LATERAL_MODES)
    return MODE_TABLE["longitudinal"][longitudinal], MODE_TABLE["lateral"][lateral]


@dataclass
class ControlConfig:
    """Which quantity each action component commands (presets ``control=<long>_<lat>``, ``truckrl/conf/control/``)."""

    longitudinal: str = param(
        "accel",
        choices=LONGITUDINAL_MODES,
        unit="-",
        doc="longitudinal command: speed, acceleration or jerk",
        source="paper",
    )
    lateral: str = param(
        "rate",
        choices=LATERAL_MODES,
        unit="-",
        doc="lateral command: steering angle, rate or acceleration",
        source="paper",
    )

    def __post_init__(self) -> None:
        validate(self, "control")


def _clip(x: Tensor, lo: Tensor, hi: Tensor) -> Tensor:
    return torch.minimum(torch.maximum(x, lo), hi)


class Control:
    """Maps normalized actions to the speed/steering state, integrating and clamping.

    Args:
        cfg: :class:`ControlConfig` or a mapping with its fields (e.g. a Hydra node).
        dt: control step [s], ``> 0`` (paper: 0.1 s).
        min_speed: lower speed bound [m/s] (``VehicleConfig.min_speed``; 0 = forward only).
        reverse: the lower speed bound is each truck's ``-max_reverse_speed`` param instead
            (tasks that reverse; ``min_speed`` must then be 0).

    Raises:
        ConfigError: unknown mode, ``dt <= 0``, non-finite ``min_speed``, or ``reverse`` with a
            nonzero ``min_speed``.
    """

    def __init__(
        self, cfg: ControlConfig, dt: float, min_speed: float = 0.0, reverse: bool = False
    ) -> None:
        self.cfg = from_mapping(ControlConfig, cfg, "control")
        self.dt = check_range("dt", dt, 0.0, math.inf, lo_open=True, hi_open=True)
        self.min_speed = check_range("min_speed", min_speed)
        self.reverse = bool(reverse)
        if self.reverse and self.min_speed != 0.0:
            raise ConfigError(
                f"env.vehicle.min_speed = {self.min_speed} must be 0 for a task that reverses "
                "(its lower bound is -env.vehicle.max_reverse_speed)"
            )
        self._long_order = LONGITUDINAL_MODES.index(self.cfg.longitudinal)
        self._lat_order = LATERAL_MODES.index(self.cfg.lateral)

    def zero_state(
        self, n: int, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32
    ) -> dict[str, Tensor]:
        """At-rest state ``{key: Tensor[n]}`` for every key of :data:`CONTROL_KEYS`.

        All zeros, except speed starts at ``min_speed`` when that is positive (0 must be inside
        the speed bounds to count as rest).
        """
        state = {k: torch.zeros(n, device=device, dtype=dtype) for k in CONTROL_KEYS}
        if self.min_speed > 0.0:
            state["speed"].fill_(self.min_speed)
        return state

    def speed_floor(self, params: Mapping[str, Tensor]) -> Tensor:
        """Lower speed bound ``[N]`` [m/s]: ``-max_reverse_speed`` with ``reverse``, else
        ``min_speed`` (``params``: per-truck vehicle parameters, uses ``max_speed`` for shape)."""
        if self.reverse:
            return -params["max_reverse_speed"]
        return torch.full_like(params["max_speed"], self.min_speed)

    def step(
        self, action: Tensor, state: dict[str, Tensor], params: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        """One control step.

        Args:
            action: ``[N, 2]`` normalized commands: ``[:, 0]`` longitudinal, ``[:, 1]`` lateral;
                clamped to ``[-1, 1]``.
            state: ``{key: Tensor[N]}`` for every key of :data:`CONTROL_KEYS` (units in module doc).
            params: per-env vehicle parameters ``{key: Tensor[N]}`` (uses the ``max_*`` limits).

        Returns:
            The new state ``{key: Tensor[N]}``, all six keys, each within its bounds.
        """
        u = action.clamp(-1.0, 1.0)
        hi_long = [params[k] for k in _LONG_LIMITS]
        lo_long = [self.speed_floor(params), -hi_long[1], -hi_long[2]]
        hi_lat = [params[k] for k in _LAT_LIMITS]
        lo_lat = [-h for h in hi_lat]
        new_long = self._chain(
            u[:, 0], self._long_order, [state[k] for k in _LONG_KEYS], lo_long, hi_long
        )
        new_lat = self._chain(
            u[:, 1], self._lat_order, [state[k] for k in _LAT_KEYS], lo_lat, hi_lat
        )
        return dict(zip(CONTROL_KEYS, new_long + new_lat, strict=True))

    def _chain(
        self, u: Tensor, order: int, old: list[Tensor], lo: list[Tensor], hi: list[Tensor]
    ) -> list[Tensor]:
        """Update one axis ``(q0, q1, q2)`` whose quantity ``q_order`` is commanded by ``u``."""
        dt = self.dt
        new: list[Tensor | None] = [None, None, None]
        # affine [-1, 1] -> [lo, hi]; exact u * hi for symmetric bounds (0.5 and 2 scale exactly)
        target = 0.5 * (hi[order] + lo[order]) + 0.5 * u * (hi[order] - lo[order])
        new[order] = _clip(target, lo[order], hi[order])
        saturated = [torch.zeros_like(u, dtype=torch.bool) for _ in range(3)]
        for i in range(order - 1, -1, -1):
            raw = old[i] + new[i + 1] * dt
            new[i] = _clip(raw, lo[i], hi[i])
            saturated[i] = new[i] != raw
        # Bottom-up: replace rates by what the level below actually did. `broken` marks envs
        # where new[i-1] != old[i-1] + new[i] * dt would otherwise hold.
        broken = torch.zeros_like(u, dtype=torch.bool)
        for i in (1, 2):
            realised = _clip((new[i - 1] - old[i - 1]) / dt, lo[i], hi[i])
            if i > order:
                new[i] = realised
            else:
                broken = broken | saturated[i - 1]
                new[i] = torch.where(broken, realised, new[i])
        return new
