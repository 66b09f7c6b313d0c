"""The planner's candidates and their batched rollout on the task core (:class:`Planner`).

Parameterisation (``5 + steer_knots + speed_knots`` numbers in ``[-1, 1]`` per candidate, one
more with a steering prior)
    * ``steer_knots`` steering set-points (fractions of ``max_steer``) spread over the distance
      driven, ``0 .. path_stretch x start-goal distance + path_extra`` (``steer_axis=distance``;
      the path then hardly depends on the speed), or over the horizon's steps;
    * ``speed_knots`` speed set-points (``-1`` = ``min_speed``, ``+1`` = ``max_speed``) over the
      horizon's steps (``speed_axis``), linearly interpolated like the steering;
    * a switch distance after which the steering set-point comes from a pursuit of the goal line
      instead (``pursuit=blend``: a planned blend of pure pursuit of the tractor rear axle and of
      the trailer axle through an articulation cascade, :mod:`truckrl.planning.controller`), with
      its planned look-ahead, gain and blend weight. Feedback on the goal line gives the
      precision that the tolerances of difficulty 6 (0.47 m, 0.94 deg for tractor *and* trailer)
      need;
    * an arrival speed: the speed set-point is capped by a braking profile to it at the goal
      (``arrival``): at 0.1 s per step a truck passing the goal faster than about 2 x 0.47 m /
      0.1 s can step over the tolerance circle.

    Reversing (a task with ``Task.reverse``): the speed knots map piecewise linearly through
    standstill, ``-1 = -max_reverse_speed``, ``0 = 0``, ``+1 = max_speed`` (so a sampled plan
    drives forwards, backwards, or both in turn, e.g. a three-point turn), the arrival cap
    bounds the reverse speed too and brakes over the tractor's distance to the goal measured
    mostly along the goal line (:func:`~truckrl.planning.controller.arrival_distance`; with
    ``arrival_speed`` near 0 the truck comes to rest at the goal, as docking needs), and the
    pursuit is direction aware (:func:`~truckrl.planning.controller.pursuit_signed`): while the
    speed set-point is negative it steers the trailer axle, which then leads, onto the goal line
    through the articulation cascade; forwards it is the planned blend. The goal line is the line
    through the goal position along the goal heading, so any goal point on the trailer's final
    axis works.

    With ``steer_prior=arc`` (forward tasks whose expert has a steering prior,
    :mod:`truckrl.planning.experts`) one more parameter in ``[0, 1]`` goes to the task's prior,
    a steering angle held over a stretch of travel that is added to the knots': the mean
    candidate then drives the prior's turn, and the knots are corrections to it (initial std
    ``arc_init_std``), instead of a straight line that CEM must first bend into a turn.
    ``steer_prior=alternate`` gives a scene's attempts the prior and the knots alone in turn
    (the first attempt the prior), so a scene gets both the prior's turn and the knots' wider
    search.

    At every step a deadbeat tracker turns the two set-points into the action the control mode
    expects (default: acceleration and steering rate), clamped to ``[-1, 1]``, so the steering-
    rate, acceleration and speed limits shape every candidate. The actions actually applied are
    recorded: the plan is an open-loop action sequence ``[T, 2]``.

Rollout and cost
    ``scenes_per_batch`` slots x ``samples`` candidates are one batch of task states; every step is
    :meth:`Task.step` + :meth:`Task.outcome` (what :meth:`Task.transition` does, without the LiDAR
    scan and reward terms), compiled with ``torch.compile`` when ``compile`` is set. A candidate's
    episode ends at success, collision, jack-knife or ``max_steps``. Its *score* at a step is the
    largest ratio error / tolerance over the task's errors (the goal test is that ratio ``<= 1``)
    plus ``mean_weight`` x the mean ratio; its cost is its lowest score over the steps before its
    episode ended in a failure (a crash after its closest approach does not spoil it: had it
    succeeded there, the episode would have ended), minus a large bonus on success. So every
    candidate is ranked by how close to the goal it came while intact.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import Tensor

from truckrl.config.fields import ConfigError, build
from truckrl.planning import controller
from truckrl.planning.config import NUM_EXTRA, PlannerConfig
from truckrl.planning.experts import steering_prior
from truckrl.planning.search import cem
from truckrl.sim.compiled import compile_sim
from truckrl.sim.control import CONTROL_KEYS, LATERAL_MODES, LONGITUDINAL_MODES, MODE_TABLE
from truckrl.sim.vehicle import PARAM_KEYS, REVERSE_KEYS
from truckrl.tasks import EnvConfig, make_task

#: Steps between checks whether every candidate of a batch has ended (each check syncs).
ALIVE_CHECK_EVERY = 20


#: The control-state bound keys of each axis, in order (speed, accel, jerk / steer, rate, accel).
LON_LIMITS = [lim for _, lim in MODE_TABLE["longitudinal"].values()]
LAT_LIMITS = [lim for _, lim in MODE_TABLE["lateral"].values()]


def control_orders(cfg: EnvConfig) -> tuple[int, int]:
    """``(longitudinal, lateral)`` order of the quantity ``cfg.control`` commands (0, 1 or 2)."""
    return (
        LONGITUDINAL_MODES.index(cfg.control.longitudinal),
        LATERAL_MODES.index(cfg.control.lateral),
    )


def track(
    task, s: dict[str, Any], speed_ref: Tensor, steer_ref: Tensor, orders, dt: float
) -> Tensor:
    """The action ``[N, 2]`` that tracks the set-points ``speed_ref`` [m/s] and ``steer_ref``
    [rad] ``[N]`` from the flat state ``s`` with the deadbeat tracker
    (:func:`truckrl.planning.controller.track`) in the control orders ``orders``."""
    p = s["params"]
    lon = controller.track(
        speed_ref,
        [s[k] for k in ("speed", "accel", "jerk")],
        [p[k] for k in LON_LIMITS],
        task.control.speed_floor(p),
        orders[0],
        dt,
    )
    lat = controller.track(
        steer_ref,
        [s[k] for k in ("steer", "steer_rate", "steer_accel")],
        [p[k] for k in LAT_LIMITS],
        -p["max_steer"],
        orders[1],
        dt,
    )
    return torch.stack((lon, lat), -1)


def score(task, s: dict[str, Any], difficulty: Tensor, mean_weight: float) -> tuple[Tensor, Tensor]:
    """``(score, worst)`` ``[N]``: the largest error / tolerance ratio over the task's errors
    (``worst``; the goal test is ``worst <= 1``) plus ``mean_weight`` x their mean."""
    tol_pos, tol_ang = task.tolerances(difficulty)
    ratios = torch.stack(
        [s[q.key] / (tol_pos if q.unit == "m" else tol_ang) for q in task.error_quantities], -1
    )
    worst = ratios.amax(-1)
    return worst + mean_weight * ratios.mean(-1), worst


def bookkeep(
    acc: dict[str, Tensor], flags: dict[str, Tensor], s: dict[str, Any], sc: Tensor, worst: Tensor
) -> dict[str, Tensor]:
    """The candidates' running record after a step: the best ``score`` ``sc`` of an intact
    (not collided, not jack-knifed) live candidate and its ``worst`` ratio, whether it has
    succeeded, its length [steps] and whether it is still alive."""
    alive = acc["alive"]
    intact = alive & ~(flags["collision"] | flags["jackknife"])
    better = intact & (sc < acc["best"])
    return {
        "best": torch.where(better, sc, acc["best"]),
        "worst": torch.where(better, worst, acc["worst"]),
        "success": acc["success"] | (alive & flags["success"]),
        "length": torch.where(alive, s["step_count"], acc["length"]),
        "alive": alive & ~flags["terminated"],
    }


def param_keys(reverse: bool) -> tuple[str, ...]:
    """The vehicle parameters of a task's trucks (:data:`REVERSE_KEYS` too if it reverses)."""
    return (*PARAM_KEYS, *REVERSE_KEYS) if reverse else PARAM_KEYS


def flat_state(state: TensorDictBase, keys: Sequence[str], reverse: bool = False) -> dict[str, Any]:
    """The plain dict of ``state``'s entries ``keys`` and its vehicle parameters (a compiled
    step takes plain dicts of tensors)."""
    out = {k: state[k] for k in keys}
    out["params"] = {k: state["params", k] for k in param_keys(reverse)}
    return out


class Planner:
    """CEM planner on the task core of ``env_cfg`` (:mod:`truckrl.planning`).

    Args:
        env_cfg: :class:`~truckrl.tasks.EnvConfig` or a mapping of its fields.
        config: :class:`PlannerConfig` or a mapping of its fields.
        device: where the rollouts run.

    Raises:
        ConfigError: ``steer_prior`` set for a task that reverses, or whose expert has no
            steering prior.
    """

    def __init__(
        self,
        env_cfg: EnvConfig | dict | None = None,
        config: PlannerConfig | dict | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        self.env_cfg = dataclasses.replace(build(EnvConfig, env_cfg, "env"), compile=False)
        self.config = build(PlannerConfig, config, "planner")
        self.device = torch.device(device)
        self.task = make_task(self.env_cfg).to(self.device)
        self.prior: Callable[..., Tensor] | None = None
        if self.config.steer_prior != "none":
            if self.task.reverse:
                raise ConfigError(
                    f"planner.steer_prior = {self.config.steer_prior!r} plans forward driving "
                    f"only; task {self.env_cfg.task.name!r} reverses: use steer_prior=none"
                )
            self.prior = steering_prior(self.env_cfg.task.name, self.config.steer_prior)
        cfg, pc = self.env_cfg, self.config
        self.horizon = cfg.max_steps
        self.w_steer = controller.knot_matrix(self.horizon, pc.steer_knots, self.device)
        self.w_speed = controller.knot_matrix(self.horizon, pc.speed_knots, self.device)
        self.orders = control_orders(cfg)
        self.state_keys = ("pose", "goal", "segments", "mask", "step_count", *CONTROL_KEYS)
        self.state_keys += self.task.error_keys
        self._step = compile_sim(self._step_fn, self.device) if pc.compile else self._step_fn

    @property
    def num_params(self) -> int:
        """Planned numbers per candidate (:attr:`PlannerConfig.num_params`)."""
        return self.config.num_params

    def initial(self, attempt: int, arc: bool = False) -> tuple[Tensor, Tensor]:
        """``(mean [P], std [P])`` an attempt starts from: 0, the speed knots at ``speed_mean``;
        std ``arc_init_std`` with the steering prior on (``arc``), else ``init_std``."""
        pc = self.config
        mean = torch.zeros(pc.num_params, device=self.device)
        mean[pc.steer_knots : pc.steer_knots + pc.speed_knots] = pc.speed_mean
        std = pc.arc_init_std if arc else pc.init_std
        return mean, torch.full((pc.num_params,), std, device=self.device)

    # ------------------------------------------------------------------ one step
    def _score(self, s: dict[str, Any], difficulty: Tensor) -> tuple[Tensor, Tensor]:
        """``(score, worst)`` ``[N]`` of :func:`score` with ``mean_weight``."""
        return score(self.task, s, difficulty, self.config.mean_weight)

    def _setpoints(
        self,
        s: dict[str, Any],
        ref: Tensor,
        travel: Tensor,
        knots: Tensor,
        vknots: Tensor,
        span: Tensor,
        plan: Tensor,
        arc: Tensor,
    ) -> tuple[Tensor, Tensor]:
        """``(speed [m/s], steer [rad])`` set-points ``[N]``: from ``ref [N, 2]`` (time-indexed) or
        the distance-indexed ``knots [N, Ms]`` / ``vknots [N, Mv]`` at ``travel / span``; then the
        arrival cap and the pursuit of ``plan [N, 5]`` and the prior's ``arc [N, 3]``."""
        pc, p = self.config, s["params"]
        speed_ref = (
            ref[:, 1] if pc.speed_axis == "time" else controller.interp(vknots, travel / span)
        )
        if pc.arrival:
            if self.task.reverse:
                dist = controller.arrival_distance(s, pc.arrival_slack)
            else:
                dist = (s["goal"][:, :2] - s["pose"][:, :2]).norm(dim=-1)
            decel = pc.brake * p["max_accel"]
            cap = (plan[:, 4].square() + 2.0 * decel * dist).sqrt()
            speed_ref = torch.minimum(speed_ref, cap)
            if self.task.reverse:  # the same cap on the reverse speed
                speed_ref = torch.maximum(speed_ref, -cap)
        if pc.steer_axis == "distance":
            steer_ref = controller.interp(knots, travel / span)
        else:
            steer_ref = ref[:, 0]
        on_arc = (travel >= arc[:, 0]) & (travel < arc[:, 1])
        steer_ref = steer_ref + torch.where(on_arc, arc[:, 2], 0.0)
        if pc.pursuit != "none":  # (switch = inf otherwise)
            if self.task.reverse:
                law = controller.pursuit_signed(s, plan, speed_ref < 0)
            else:
                law = controller.pursuit(s, plan)
            steer_ref = torch.where(travel >= plan[:, 0], law, steer_ref)
        return speed_ref, steer_ref

    def _step_fn(
        self,
        s: dict[str, Any],
        ref: Tensor,
        difficulty: Tensor,
        acc: dict[str, Tensor],
        knots: Tensor,
        vknots: Tensor,
        span: Tensor,
        plan: Tensor,
        arc: Tensor,
    ) -> tuple[dict[str, Tensor], Tensor, dict[str, Tensor]]:
        """One step of every candidate: build the set-points (:meth:`_setpoints`), track them,
        advance, test the outcome and update the bookkeeping ``acc``."""
        dt = self.env_cfg.dt
        speed_ref, steer_ref = self._setpoints(
            s, ref, acc["travel"], knots, vknots, span, plan, arc
        )
        action = track(self.task, s, speed_ref, steer_ref, self.orders, dt)
        new = self.task.step(s, action)
        after = {**s, **new}
        flags = self.task.outcome(after, difficulty)
        out = bookkeep(acc, flags, after, *self._score(after, difficulty))
        out["travel"] = acc["travel"] + new["speed"].abs() * dt
        return new, action, out

    # ------------------------------------------------------------------ one batch rollout
    def _speed_map(self, u: Tensor, params: dict[str, Tensor]) -> Tensor:
        """Speed set-points [m/s] of speed-knot values ``u [N, M]`` in ``[-1, 1]``.

        Forward task: affine, ``-1 -> speed floor (min_speed)``, ``+1 -> max_speed``. A task that
        reverses: piecewise linear through standstill at 0, ``-1 -> -max_reverse_speed``, ``+1 ->
        max_speed`` (half the sampled knots drive backwards)."""
        v_hi = params["max_speed"][:, None]
        if self.task.reverse:
            return torch.where(u < 0, u * params["max_reverse_speed"][:, None], u * v_hi)
        v_lo = self.task.control.speed_floor(params)[:, None]
        return v_lo + 0.5 * (u + 1.0) * (v_hi - v_lo)

    def _references(self, x: Tensor, params: dict[str, Tensor]) -> Tensor:
        """``[T, N, 2]`` steering [rad] and speed [m/s] set-points of candidates ``x [N, P]``."""
        ks = self.config.steer_knots
        kv = ks + self.config.speed_knots
        steer = x[:, :ks] @ self.w_steer.T * params["max_steer"][:, None]
        speed = self._speed_map(x[:, ks:kv] @ self.w_speed.T, params)
        return torch.stack((steer, speed), -1).transpose(0, 1).contiguous()

    def _extras(self, x: Tensor, params: dict[str, Tensor], span: Tensor) -> Tensor:
        """``[N, 5]`` planned scalars of candidates ``x``: pursuit switch distance [m],
        look-ahead [m], gain [1/m], trailer-law weight, arrival speed [m/s]."""
        pc = self.config
        k = pc.steer_knots + pc.speed_knots
        f = 0.5 * (x[:, k : k + NUM_EXTRA] + 1.0)  # [0, 1]
        (l0, l1), (g0, g1), (v0, v1) = pc.lookahead, pc.gain, pc.arrival_speed
        if pc.pursuit == "none":
            switch = torch.full_like(span, math.inf)
        else:
            switch = f[:, 0] * span
        arrive = (v0 + f[:, 4] * (v1 - v0)) * params["max_speed"]
        return torch.stack(
            (switch, l0 + f[:, 1] * (l1 - l0), g0 + f[:, 2] * (g1 - g0), f[:, 3], arrive), -1
        )

    def _arc(self, s: dict[str, Any], x: Tensor) -> Tensor:
        """``[N, 3]`` steering prior of candidates ``x [N, P]`` (zeros without one): the travel
        [m] where its steering starts and ends, and that steering angle [rad]; the candidate's
        last parameter, mapped to ``[0, 1]``, is the prior's free parameter
        (:func:`truckrl.planning.experts.steering_prior`)."""
        if self.prior is None:
            return torch.zeros(x.shape[0], 3, device=x.device)
        f = 0.5 * (x[:, -1] + 1.0)  # [0, 1]
        return self.prior(s["pose"][:, :3], s["goal"], s["params"], f)

    @torch.no_grad()
    def rollout(
        self, start: TensorDictBase, x: Tensor, difficulty: float, arc_on: Tensor | None = None
    ) -> tuple[dict[str, Tensor], Tensor]:
        """Roll candidates ``x [N, P]`` out from ``start [N]`` (one state row per candidate);
        ``arc_on [N]`` bool switches the steering prior off where False.

        Returns:
            ``(acc, actions)``: per candidate ``best`` (lowest score while intact), ``worst``
            (the largest error / tolerance ratio at that step),
            ``success``, ``length`` (steps until its episode ended) and ``alive``; the applied
            actions ``[T, N, 2]`` (rows after the end of an episode are meaningless).
        """
        n, dev = x.shape[0], self.device
        s = flat_state(start, self.state_keys, self.task.reverse)
        refs = self._references(x, s["params"])
        ks, kv = self.config.steer_knots, self.config.steer_knots + self.config.speed_knots
        knots = x[:, :ks] * s["params"]["max_steer"][:, None]
        vknots = self._speed_map(x[:, ks:kv], s["params"])
        start_goal = (s["goal"][:, :2] - s["pose"][:, :2]).norm(dim=-1)
        span = self.config.path_stretch * start_goal + self.config.path_extra
        plan = self._extras(x, s["params"], span)
        arc = self._arc(s, x)
        if arc_on is not None:  # candidates of knots-only attempts (steer_prior=alternate)
            arc = torch.cat((arc[:, :2], torch.where(arc_on, arc[:, 2], 0.0)[:, None]), -1)
        diff = torch.full((n,), float(difficulty), device=dev)
        score0, worst0 = self._score(s, diff)
        acc = {
            "best": score0,
            "worst": worst0,
            "success": torch.zeros(n, dtype=torch.bool, device=dev),
            "length": torch.zeros(n, dtype=torch.int64, device=dev),
            "alive": torch.ones(n, dtype=torch.bool, device=dev),
            "travel": torch.zeros(n, device=dev),
        }
        actions = torch.zeros(self.horizon, n, 2, device=dev)
        for t in range(self.horizon):
            new, actions[t], acc = self._step(s, refs[t], diff, acc, knots, vknots, span, plan, arc)
            s = {**s, **new}
            if (t + 1) % ALIVE_CHECK_EVERY == 0 and not bool(acc["alive"].any()):
                break
        return acc, actions

    def plan(
        self,
        states: TensorDictBase,
        difficulty: float,
        progress: Callable[[int, int], None] | None = None,
    ) -> dict[str, Any]:
        """Plan every scene of ``states [E]`` by CEM (:func:`truckrl.planning.search.cem`)."""
        return cem(self, states, difficulty, progress)
