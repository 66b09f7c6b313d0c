"""Gear-sequence plans for tasks that reverse: legs of one gear each, tracked along planned paths.

``planner.search=gears`` (:class:`GearPlanner`) plans a scene as a short sequence of **legs**.
Leg ``k`` has a gear (``+1`` forward, ``-1`` reverse), a cruise speed and a **path**: a polyline
``[M, 2]`` [m] in the world frame that the leg's *tracked point* follows, the tractor rear axle
forwards and the trailer axle backwards (the point that leads). A leg ends where its path ends:
the speed set-point is capped by a braking profile to rest at the path's end, and the next leg
starts once the tracked point is within :data:`SWITCH_DISTANCE` of it (or past it) and the truck
is at rest (``|v| <= SWITCH_SPEED``). The last leg ends at the goal, at rest. The path's end is
thus the leg's switch point, and a leg whose path has no length is skipped.

Where the legs and their paths come from: the task's expert (``gear_legs`` in the task folder's
``expert.py``, the contract in :mod:`truckrl.planning`) builds them from the start state and the
candidate's task parameters, ``x[:, NUM_GEAR_PARAMS:]`` in ``[-1, 1]``; its ``gear_prior()``
gives the means the search starts from (one per attempt, in turn): the scripted driver's
settings, so the search begins at the scripted driver's path and switch points and perturbs
them. This module holds only the generic part: the leg tracking, the rollout and the parameters
shared by every task, ``x[:, :NUM_GEAR_PARAMS]`` (:data:`GEAR_PARAMS`).

Tracking (per step, batched over candidates, no host sync)
    The tracked point's progress is its nearest path vertex among the next
    :data:`PROGRESS_WINDOW` metres of path (the whole path at a leg's first step), refined by
    the projection on that vertex's segment; the progress never goes back, so a path that
    doubles back is followed in order. The target is the path point ``lookahead`` metres
    further (beyond the end: along the last segment).

    * Forward: pure pursuit of the target by the tractor rear axle, ``delta = atan(2 L_t
      sin(alpha) / d)``.
    * Reverse: the trailer axle, which leads, aims at the target: the trailer heading error
      sets an articulation set-point ``phi_d = clamp(k_psi * (psi_d - psi), +-phi_max)``
      (``psi_d`` the heading from the target to the trailer axle) and the steering makes the
      articulation follow it at ``k_phi`` per metre by inverting the hitch kinematics
      (``d phi / d|s| = tan(delta) / L_t (1 + a / L_ka cos phi) + sin(phi) / L_ka`` backwards,
      :func:`truckrl.sim.vehicle.kinematics_step`). The articulation is open-loop unstable
      backwards, so feedback, not an open-loop steering profile, keeps the trailer in hand; the
      same law as the ``uturn`` scripted driver's reverse leg.

    A deadbeat tracker (:func:`truckrl.planning.controller.track`) turns the speed and steering
    set-points into the control mode's action, clamped to ``[-1, 1]``, so every limit of the
    truck shapes the plan; the applied actions are the plan, replayed open loop
    (:mod:`truckrl.planning.episodes`).

Search: the cross-entropy method of :mod:`truckrl.planning.search`, an attempt's mean starting at
the expert's prior (attempt ``j`` at row ``j`` of ``gear_prior()``, in turn) with the std
``planner.gears_init_std``; candidates are scored as the knot planner's (the closest approach to
the goal while intact, every success first).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import Tensor

from truckrl.config.fields import ConfigError, build
from truckrl.planning.config import PlannerConfig
from truckrl.planning.experts import task_expert
from truckrl.planning.rollout import (
    ALIVE_CHECK_EVERY,
    bookkeep,
    control_orders,
    flat_state,
    score,
    track,
)
from truckrl.planning.search import cem
from truckrl.sim.control import CONTROL_KEYS
from truckrl.sim.geometry import wrap_angle
from truckrl.tasks import EnvConfig, make_task

#: Expert attribute: ``gear_legs(start, x [N, P]) -> {"gear" [N, K], "speed" [N, K] (m/s,
#: positive), "path" [N, K, M, 2] (m, world frame)}``.
GEAR_LEGS = "gear_legs"
#: Expert attribute: ``gear_prior() -> [A, P]`` means of the task parameters in ``[-1, 1]``.
GEAR_PRIOR = "gear_prior"

#: The generic parameters ``x[:, :NUM_GEAR_PARAMS]``: (name, value at x = -1, at x = 0, at
#: x = +1). Piecewise linear, so the mean candidate (x = 0) drives the nominal law, which is
#: the ``uturn`` scripted driver's reverse law (its gains 1.5 and 0.8 per metre, 0.4 rad below
#: the articulation limit, a look-ahead of about 5 m).
GEAR_PARAMS: tuple[tuple[str, float, float, float], ...] = (
    ("forward_lookahead", 3.0, 8.0, 16.0),  # m
    ("reverse_lookahead", 2.0, 5.0, 10.0),  # m
    ("heading_gain", 0.5, 1.5, 3.0),  # k_psi, -
    ("articulation_gain", 0.3, 0.8, 1.6),  # k_phi, 1/m
    ("articulation_margin", 0.8, 0.4, 0.15),  # phi_max = max_articulation - this, rad
    ("brake", 0.2, 0.4, 0.8),  # deceleration to a leg's end / max_accel
    ("end_shift", -0.3, 0.0, 0.3),  # m along the last leg's path end (past the goal: +)
)
NUM_GEAR_PARAMS = len(GEAR_PARAMS)
#: Metres of path ahead of the current progress searched for the nearest vertex.
PROGRESS_WINDOW = 6.0
#: A leg ends once its tracked point is within this [m] of its path's end (or past it) ...
SWITCH_DISTANCE = 0.05
#: ... at rest: ``|speed| <=`` this [m/s].
SWITCH_SPEED = 0.05
#: Speed [m/s] the braking profile never caps below before a leg's end: the truck creeps
#: onto it instead of stalling short (below the ``dock`` task's rest speed of 0.1 m/s).
CREEP_SPEED = 0.08


def piecewise(u: Tensor, lo: float, mid: float, hi: float) -> Tensor:
    """``u`` in ``[-1, 1]`` mapped linearly onto ``[lo, mid]`` (``u <= 0``) and ``[mid, hi]``
    (``u >= 0``): a planned value whose mean candidate (``u = 0``) is the nominal ``mid``."""
    return torch.where(u < 0, mid + u * (mid - lo), mid + u * (hi - mid))


def piecewise_inverse(v: float, lo: float, mid: float, hi: float) -> float:
    """The ``u`` in ``[-1, 1]`` that :func:`piecewise` maps onto ``v`` (clamped to the range)."""
    if v < mid:
        return max(-1.0, (v - mid) / (mid - lo)) if mid > lo else 0.0
    return min(1.0, (v - mid) / (hi - mid)) if hi > mid else 0.0


def gear_values(x: Tensor) -> dict[str, Tensor]:
    """The generic parameters ``{name: [N]}`` of candidates ``x [N, >= NUM_GEAR_PARAMS]`` in
    ``[-1, 1]`` (:data:`GEAR_PARAMS`, :func:`piecewise`)."""
    return {
        name: piecewise(x[:, j], lo, mid, hi) for j, (name, lo, mid, hi) in enumerate(GEAR_PARAMS)
    }


def path_lengths(path: Tensor) -> tuple[Tensor, Tensor]:
    """``(cumulative arc length [..., M] [m], unit tangents [..., M, 2])`` of polylines
    ``path [..., M, 2]``; vertex ``i``'s tangent is its segment to ``i + 1`` (the last vertex
    repeats the last segment's; a zero-length segment gives a zero tangent)."""
    seg = path[..., 1:, :] - path[..., :-1, :]
    length = seg.norm(dim=-1)
    cum = torch.cat((torch.zeros_like(length[..., :1]), length.cumsum(-1)), -1)
    tan = seg / length.clamp_min(1e-9)[..., None]
    tan = torch.cat((tan, tan[..., -1:, :]), -2)
    return cum, tan


def path_point(path: Tensor, cum: Tensor, tan: Tensor, s: Tensor) -> Tensor:
    """The point ``[N, 2]`` at arc length ``s [N]`` of polylines ``path [N, M, 2]`` (linear
    between vertices; before the start / past the end along the first / last segment)."""
    m = path.shape[1]
    i = torch.searchsorted(cum.contiguous(), s[:, None].contiguous(), right=True)[:, 0] - 1
    i = i.clamp(0, max(m - 2, 0))
    rows = torch.arange(path.shape[0], device=path.device)
    return path[rows, i] + (s - cum[rows, i])[:, None] * tan[rows, i]


def trailer_axle_point(pose: Tensor, params: dict[str, Tensor]) -> Tensor:
    """Trailer axle ``[N, 2]`` [m] of rear-axle poses ``pose [N, 4]`` (x, y, heading,
    articulation): the kingpin ``kingpin_offset`` behind the rear axle, the axle
    ``trailer_wheelbase`` behind the kingpin along the trailer heading ``theta + phi``."""
    theta, psi = pose[:, 2], pose[:, 2] + pose[:, 3]
    king = pose[:, :2] - params["kingpin_offset"][:, None] * torch.stack(
        (theta.cos(), theta.sin()), -1
    )
    return king - params["trailer_wheelbase"][:, None] * torch.stack((psi.cos(), psi.sin()), -1)


def leg_steer(s: dict[str, Any], target: Tensor, backward: Tensor, g: dict[str, Tensor]) -> Tensor:
    """Steering angle set-point [rad] ``[N]`` towards ``target [N, 2]``: pure pursuit of the
    tractor rear axle forwards, the trailer-axle law backwards (module doc), within
    ``+-max_steer``."""
    pose, p = s["pose"], s["params"]
    theta, phi = pose[:, 2], pose[:, 3]
    l_t, a, l_ka = p["wheelbase"], p["kingpin_offset"], p["trailer_wheelbase"]
    # forward: pure pursuit by the rear axle
    d = target - pose[:, :2]
    alpha = torch.atan2(d[:, 1], d[:, 0]) - theta
    fwd = torch.atan(2.0 * l_t * torch.sin(alpha) / d.norm(dim=-1).clamp_min(1e-3))
    # backward: the trailer axle leads; its heading error sets the articulation set-point
    psi = theta + phi
    d = target - trailer_axle_point(pose, p)
    psi_d = torch.atan2(d[:, 1], d[:, 0]) + math.pi  # the trailer faces away from its motion
    lim = (p["max_articulation"] - g["articulation_margin"]).clamp_min(0.05)
    phi_d = torch.maximum(torch.minimum(g["heading_gain"] * wrap_angle(psi_d - psi), lim), -lim)
    rate = g["articulation_gain"] * (phi_d - phi) - torch.sin(phi) / l_ka
    bwd = torch.atan(l_t * rate / (1.0 + a / l_ka * phi.cos()))
    steer = torch.where(backward, bwd, fwd)
    return torch.maximum(torch.minimum(steer, p["max_steer"]), -p["max_steer"])


def expert_hooks(name: str) -> tuple[Callable, Callable]:
    """``(gear_legs, gear_prior)`` of task ``name``'s expert.

    Raises:
        ConfigError: the task's folder has no expert, or its expert lacks either.
    """
    expert = task_expert(name)
    hooks = tuple(getattr(expert, a, None) for a in (GEAR_LEGS, GEAR_PRIOR))
    if hooks[0] is None or hooks[1] is None:
        raise ConfigError(
            f"planner.search = 'gears' needs {GEAR_LEGS}() and {GEAR_PRIOR}() in the expert.py "
            f"of task {name!r}, which has none: use planner.search=knots"
        )
    return hooks  # type: ignore[return-value]


class GearPlanner:
    """Gear-sequence planner on the task core of ``env_cfg`` (module doc); the same interface
    as :class:`~truckrl.planning.rollout.Planner` (``rollout``, ``plan``, ``initial``).

    Raises:
        ConfigError: the task does not reverse, its expert has no gear hooks, or
            ``steer_prior`` is set; a jerk or steering-acceleration control mode.
    """

    def __init__(
        self,
        env_cfg: EnvConfig | dict | None = None,
        config: PlannerConfig | dict | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        self.env_cfg = dataclasses.replace(build(EnvConfig, env_cfg, "env"), compile=False)
        self.config = pc = build(PlannerConfig, config, "planner")
        self.device = torch.device(device)
        name = self.env_cfg.task.name
        if pc.steer_prior != "none":
            raise ConfigError(
                f"planner.steer_prior = {pc.steer_prior!r} is for search=knots; "
                "search=gears takes its prior from the task's expert: use steer_prior=none"
            )
        self.task = make_task(self.env_cfg).to(self.device)
        if not self.task.reverse:
            raise ConfigError(
                f"planner.search = 'gears' plans reversing; task {name!r} drives forward only: "
                "use planner.search=knots"
            )
        self.legs_of, prior = expert_hooks(name)
        self.prior = torch.as_tensor(prior(), dtype=torch.float32).to(self.device)
        self.num_params = NUM_GEAR_PARAMS + self.prior.shape[1]
        cfg = self.env_cfg
        self.horizon = cfg.max_steps
        self.orders = control_orders(cfg)
        self.state_keys = ("pose", "goal", "segments", "mask", "step_count", *CONTROL_KEYS)
        self.state_keys += self.task.error_keys

    def initial(self, attempt: int, arc: bool = False) -> tuple[Tensor, Tensor]:
        """``(mean [P], std [P])`` of attempt ``attempt`` (0-based) of a scene: the generic
        parameters at their nominal values (0), the task's at prior row ``attempt mod A``."""
        mean = torch.zeros(self.num_params, device=self.device)
        mean[NUM_GEAR_PARAMS:] = self.prior[attempt % self.prior.shape[0]]
        std = torch.full((self.num_params,), self.config.gears_init_std, device=self.device)
        return mean, std

    def _score(self, s: dict[str, Any], difficulty: Tensor) -> tuple[Tensor, Tensor]:
        """``(score, worst)`` ``[N]`` as :meth:`Planner._score`."""
        return score(self.task, s, difficulty, self.config.mean_weight)

    def legs(self, start: TensorDictBase, x: Tensor) -> dict[str, Tensor]:
        """The expert's legs of candidates ``x [N, P]`` from ``start [N]``, checked: ``gear``,
        ``speed`` ``[N, K]``, ``path`` ``[N, K, M, 2]``; the last leg's path end moved by the
        planned ``end_shift`` along its last segment."""
        legs = self.legs_of(start, x[:, NUM_GEAR_PARAMS:])
        gear, speed, path = legs["gear"], legs["speed"], legs["path"].clone()
        n = x.shape[0]
        if gear.shape[0] != n or path.shape[:2] != gear.shape or path.shape[-1] != 2:
            raise ValueError(
                f"gear_legs: gear {list(gear.shape)}, path {list(path.shape)} do not fit "
                f"{n} candidates ([N, K] and [N, K, M, 2])"
            )
        shift = gear_values(x)["end_shift"]
        last = path[:, -1]
        d = last[:, -1] - last[:, -2]
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        path[:, -1, -1] = last[:, -1] + shift[:, None] * d
        return {"gear": gear.float(), "speed": speed.float(), "path": path}

    @torch.no_grad()
    def rollout(
        self, start: TensorDictBase, x: Tensor, difficulty: float, arc_on: Tensor | None = None
    ) -> tuple[dict[str, Tensor], Tensor]:
        """Roll candidates ``x [N, P]`` out from ``start [N]`` (one state row per candidate;
        ``arc_on`` is ignored). Returns ``(acc, actions [T, N, 2])`` as
        :meth:`Planner.rollout`, ``acc`` also with ``leg [N]`` (the leg each candidate ended
        in) and, per step ``[T, N]``, ``speed_trace`` (the speed after the step [m/s]),
        ``leg_trace`` (the leg that chose its action) and ``pose_trace`` ``[T, N, 4]``."""
        n, dev, dt = x.shape[0], self.device, self.env_cfg.dt
        s = flat_state(start, self.state_keys, reverse=True)
        p = s["params"]
        g = gear_values(x)
        legs = self.legs(start, x)
        gear, vmax, paths = legs["gear"], legs["speed"], legs["path"]
        num_legs = gear.shape[1]
        cum, tan = path_lengths(paths)  # [N, K, M], [N, K, M, 2]
        rows = torch.arange(n, device=dev)
        diff = torch.full((n,), float(difficulty), device=dev)
        score0, worst0 = self._score(s, diff)
        acc = {
            "best": score0,
            "worst": worst0,
            "success": torch.zeros(n, dtype=torch.bool, device=dev),
            "length": torch.zeros(n, dtype=torch.int64, device=dev),
            "alive": torch.ones(n, dtype=torch.bool, device=dev),
        }
        leg = torch.zeros(n, dtype=torch.long, device=dev)
        fresh = torch.ones(n, dtype=torch.bool, device=dev)
        prog = torch.zeros(n, device=dev)  # arc length of the current progress [m]
        actions = torch.zeros(self.horizon, n, 2, device=dev)
        speeds = torch.zeros(self.horizon, n, device=dev)
        trace = torch.zeros(self.horizon, n, dtype=torch.long, device=dev)
        poses = torch.zeros(self.horizon, n, 4, device=dev)
        decel = g["brake"] * p["max_accel"]
        for t in range(self.horizon):
            path, c, tg = paths[rows, leg], cum[rows, leg], tan[rows, leg]
            backward = gear[rows, leg] < 0
            point = torch.where(
                backward[:, None], trailer_axle_point(s["pose"], p), s["pose"][:, :2]
            )
            # progress: nearest vertex in the window ahead (anywhere at a leg's first step)
            d2 = (path - point[:, None]).square().sum(-1)
            ahead = (c >= prog[:, None] - 1e-6) & (c <= prog[:, None] + PROGRESS_WINDOW)
            d2 = torch.where(ahead | fresh[:, None], d2, math.inf)
            i = d2.argmin(1)
            proj = c[rows, i] + ((point - path[rows, i]) * tg[rows, i]).sum(-1)
            prog = torch.where(fresh, proj, torch.maximum(prog, proj))
            total = c[:, -1]
            remaining = total - prog
            target = path_point(path, c, tg, prog + torch.where(
                backward, g["reverse_lookahead"], g["forward_lookahead"]))  # fmt: skip
            steer_ref = leg_steer(s, target, backward, g)
            cap = (2.0 * decel * remaining.clamp_min(0.0)).sqrt() + CREEP_SPEED
            cap = torch.where(remaining > 0.0, cap, 0.0)
            speed_ref = gear[rows, leg] * torch.minimum(vmax[rows, leg], cap)
            action = track(self.task, s, speed_ref, steer_ref, self.orders, dt)
            s = {**s, **self.task.step(s, action)}
            flags = self.task.outcome(s, diff)
            acc = bookkeep(acc, flags, s, *self._score(s, diff))
            actions[t], speeds[t], trace[t], poses[t] = action, s["speed"], leg, s["pose"]
            # the next leg once this one's end is reached at rest
            switch = (remaining <= SWITCH_DISTANCE) & (s["speed"].abs() <= SWITCH_SPEED)
            switch &= leg < num_legs - 1
            leg = leg + switch.long()
            fresh = switch
            prog = torch.where(switch, 0.0, prog)
            if (t + 1) % ALIVE_CHECK_EVERY == 0 and not bool(acc["alive"].any()):
                break
        acc["leg"] = leg
        acc["speed_trace"], acc["leg_trace"], acc["pose_trace"] = speeds, trace, poses
        return acc, actions

    def plan(
        self,
        states: TensorDictBase,
        difficulty: float,
        progress: Callable[[int, int], None] | None = None,
    ) -> dict[str, Any]:
        """Plan every scene of ``states [E]`` by CEM (:func:`truckrl.planning.search.cem`)."""
        return cem(self, states, difficulty, progress)
