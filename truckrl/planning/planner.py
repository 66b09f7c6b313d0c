"""Sampling-based planner baseline: the cross-entropy method (CEM) over smooth action sequences,
rolled out on the task core with the dynamics, collision, jack-knife and success test of training.

It answers "can this scene be solved within the episode?" independently of any learned policy,
and it is scored like a policy: :func:`plan_episodes` returns the per-episode results of
:func:`truckrl.evaluation.rollout.evaluate_policy` (same keys; the same scenes for the same
``episodes`` and ``seed``), plus each scene's route and vehicle parameters for
:mod:`truckrl.evaluation.categories`.

Parameterisation (``5 + steer_knots + speed_knots`` numbers in ``[-1, 1]`` per candidate, one
more with the arc prior)
    * ``steer_knots`` steering set-points (fractions of ``max_steer``) spread over the distance
      driven, ``0 .. path_stretch x start-goal distance + path_extra`` (``steer_axis=distance``;
      the path then hardly depends on the speed), or over the horizon's steps;
    * ``speed_knots`` speed set-points (``-1`` = ``min_speed``, ``+1`` = ``max_speed``; reversing
      below) over the
      horizon's steps (``speed_axis``), linearly interpolated like the steering;
    * a switch distance after which the steering set-point comes from a pursuit of the goal line
      instead (``pursuit``: pure pursuit of the tractor rear axle, pure pursuit of the trailer axle
      through an articulation cascade, or a planned blend of the two), with its planned
      look-ahead, gain and blend weight. Feedback on the goal line gives the precision that the
      tolerances of difficulty 6 (0.47 m, 0.94 deg for tractor *and* trailer) need;
    * an arrival speed: the speed set-point is capped by a braking profile to it at the goal
      (``arrival``): at 0.1 s per step a truck passing the goal faster than about 2 x 0.47 m /
      0.1 s can step over the tolerance circle.

    Reversing (a task with ``Task.reverse``): the speed knots map piecewise linearly through
    standstill, ``-1 = -max_reverse_speed``, ``0 = 0``, ``+1 = max_speed`` (so a sampled plan
    drives forwards, backwards, or both in turn, e.g. a three-point turn), the arrival cap
    bounds the reverse speed too and brakes over the tractor's distance to the goal measured
    mostly along the goal line (:meth:`Planner._arrival_distance`; with ``arrival_speed`` near
    0 the truck comes to rest at the goal, as docking needs), and the pursuit is direction
    aware (:meth:`Planner._pursuit_signed`): while the speed set-point is negative it steers
    the trailer axle, which then leads, onto the goal line through the articulation cascade;
    forwards it is the planned blend. The goal line is the line through the goal position
    along the goal heading, so any goal point on the trailer's final axis works. Forward-only
    tasks are planned exactly as before (bit-identical).

    With ``steer_prior=arc`` (forward tasks) one more parameter plans the radius of a circular arc
    tangent to the start lane and the goal lane (:meth:`Planner._arc`), whose steering is added to
    the knots': the mean candidate then drives the turn on that arc, and the knots are
    corrections to it (initial std ``arc_init_std``), instead of a straight line that CEM must
    first bend into a turn. ``steer_prior=alternate`` gives a scene's attempts the arc and the
    knots alone in turn (the first attempt the arc): the arc finds left turns that the knots
    miss, the knots' wider search the wide swings of sharp right turns.

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

CEM
    An *attempt* at a scene samples a diagonal Gaussian over the parameters (mean 0, speeds at
    ``speed_mean``, std ``init_std``), clamped to ``[-1, 1]``; the best ``elite_frac`` of its
    population (which always holds its best candidate so far) give the next mean and std, blended
    with the old ones by ``smoothing`` and floored at ``min_std``. An attempt ends after
    ``iterations`` iterations; a scene gets up to ``attempts`` independent attempts (restarts
    escape local minima) and stops as soon as a candidate succeeds with every error within
    ``stop_margin`` of its tolerance. Attempts are queued through the batch's slots: first
    attempts, then restarts; when the queue runs dry, idle slots start the remaining attempts of
    the scenes still running, then join their populations.

Replay
    The best ``replay_candidates`` successful sequences of each scene (or its lowest-cost one when
    none succeeded) are replayed open loop through a fresh eager :class:`~truckrl.env.TruckEnv`
    started with ``set_state`` from the scene's start state. A scene is solved when a replay
    succeeds; the reported outcome, length and errors are those of that replay (else of the
    replay of the lowest-cost sequence), recorded at its first ``done`` as in ``evaluate_policy``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor

from truckrl.config.fields import ConfigError, build, check_range, param, validate
from truckrl.env import TruckEnv
from truckrl.evaluation.rollout import SCENE_INFO_ENTRIES, policy_actions
from truckrl.sim.compiled import compile_sim
from truckrl.sim.control import CONTROL_KEYS, LATERAL_MODES, LONGITUDINAL_MODES, MODE_TABLE
from truckrl.sim.geometry import wrap_angle
from truckrl.sim.vehicle import PARAM_KEYS, REVERSE_KEYS, trailer_length
from truckrl.tasks import MAX_DIFFICULTY, OUTCOMES, EnvConfig, Quantity, make_task, shown
from truckrl.tasks.intersection.task import lane_corner

#: Cost subtracted from a successful candidate: every success ranks before every failure.
SUCCESS_BONUS = 1.0e6
#: Planned scalars after the knots: pursuit switch distance, look-ahead, gain, trailer-law
#: weight, arrival speed (always sampled; unused ones do not matter).
NUM_EXTRA = 5
#: Steps between checks whether every candidate of a batch has ended (each check syncs).
ALIVE_CHECK_EVERY = 20


@dataclass
class PlannerConfig:
    """Budget and shape of the CEM planner (module doc)."""

    samples: int = param(256, lo=2, hi=1_000_000, unit="candidates", doc="per scene per iteration")
    iterations: int = param(12, lo=1, hi=100_000, unit="-", doc="CEM iterations per attempt")
    attempts: int = param(
        3, lo=1, hi=1000, unit="-", doc="independent CEM attempts per scene until one succeeds"
    )
    elite_frac: float = param(
        0.1, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="fraction of the population kept as elites"
    )
    steer_knots: int = param(8, lo=1, hi=1000, unit="-", doc="steering set-points over the horizon")
    speed_knots: int = param(4, lo=1, hi=1000, unit="-", doc="speed set-points over the horizon")
    steer_axis: str = param(
        "distance",
        choices=("distance", "time"),
        doc="steering set-points spread over the distance driven (up to path_stretch x the "
        "start-goal distance) or over the horizon's steps",
    )
    speed_axis: str = param(
        "time", choices=("distance", "time"), doc="speed set-points: as steer_axis"
    )
    path_stretch: float = param(
        1.6, lo=0.1, hi=100.0, unit="-", doc="steer_axis=distance: knots span this x goal distance"
    )
    path_extra: float = param(
        10.0, lo=0.0, hi=1e4, unit="m", doc="steer_axis=distance: plus this many metres"
    )
    pursuit: str = param(
        "blend",
        choices=("blend", "trailer", "tractor", "none"),
        doc="after a planned switch distance, steer by pure pursuit of the goal line: of the "
        "trailer axle (articulation cascade), of the tractor rear axle, or a planned blend of "
        "the two; none: knots only",
    )
    lookahead: tuple[float, float] = param(
        (3.0, 30.0), lo=0.1, hi=1e4, unit="m", doc="pursuit: range of the planned look-ahead"
    )
    gain: tuple[float, float] = param(
        (0.05, 1.0),
        lo=0.0,
        lo_open=True,
        hi=100.0,
        unit="1/m",
        doc="pursuit=trailer: range of the planned articulation gain (per metre driven)",
    )
    arrival: bool = param(
        True,
        doc="cap the speed set-point by a braking profile (brake x max_accel) down to a planned "
        "arrival speed at the goal",
    )
    arrival_speed: tuple[float, float] = param(
        (0.05, 1.0), lo=0.0, hi=1.0, unit="-", doc="arrival: range of the planned speed / max_speed"
    )
    arrival_slack: float = param(
        0.5,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="arrival, a task that reverses: offset across the goal line the braking distance "
        "ignores",
    )
    brake: float = param(
        0.5, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="arrival: deceleration / max_accel"
    )
    steer_prior: str = param(
        "none",
        choices=("none", "arc", "alternate"),
        doc="arc: the steering knots are residuals on the steering of a circular arc tangent to "
        "the start and goal heading lines, of planned radius (module doc; forward tasks only); "
        "alternate: a scene's attempts alternate between the arc (first) and the knots alone",
    )
    arc_init_std: float = param(
        0.3,
        lo=0.0,
        lo_open=True,
        hi=10.0,
        unit="-",
        doc="initial std of an attempt with the arc prior (the knots are corrections to it)",
    )
    speed_mean: float = param(
        0.0,
        lo=-1.0,
        hi=1.0,
        unit="-",
        doc="initial mean of the speed knots (-1 min, +1 max speed; a task that reverses: "
        "-1 -max_reverse_speed, 0 standstill)",
    )
    init_std: float = param(0.6, lo=0.0, lo_open=True, hi=10.0, unit="-", doc="initial knot std")
    min_std: float = param(0.002, lo=0.0, hi=10.0, unit="-", doc="floor of the knot std")
    smoothing: float = param(
        0.2, lo=0.0, hi=1.0, hi_open=True, unit="-", doc="weight of the old mean/std in an update"
    )
    mean_weight: float = param(
        0.5, lo=0.0, hi=100.0, unit="-", doc="weight of the mean error ratio in the score"
    )
    stop_margin: float = param(
        0.99,
        lo=0.0,
        hi=1.0,
        unit="-",
        doc="stop a scene once a success has every error / tolerance <= this (replay margin)",
    )
    scenes_per_batch: int = param(
        16, lo=1, hi=100_000, unit="scenes", doc="scenes rolled out together"
    )
    replay_candidates: int = param(
        3, lo=1, hi=100, unit="-", doc="successful sequences per scene kept for the replay"
    )
    compile: bool = param(True, doc="torch.compile the rollout step (~15 s once per process)")
    seed: int = param(0, lo=0, hi=2**62, unit="-", doc="seed of the candidate sampling")

    def __post_init__(self) -> None:
        validate(self, "planner")

    @property
    def num_params(self) -> int:
        return self.steer_knots + self.speed_knots + NUM_EXTRA + (self.steer_prior != "none")


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


def _interp(knots: Tensor, frac: Tensor) -> Tensor:
    """Linear interpolation of ``knots [N, M]`` (evenly spread over ``[0, 1]``) at ``frac [N]``
    (clamped to ``[0, 1]``)."""
    m = knots.shape[1]
    pos = frac.clamp(0.0, 1.0) * (m - 1)
    left = pos.floor().clamp(max=max(m - 2, 0)).long()
    right = (left + 1).clamp(max=m - 1)
    w = (pos - left).clamp(0.0, 1.0)
    lo, hi = knots.gather(1, left[:, None])[:, 0], knots.gather(1, right[:, None])[:, 0]
    return lo + w * (hi - lo)


def _flat(state: TensorDictBase, keys: Sequence[str], reverse: bool = False) -> dict[str, Any]:
    out = {k: state[k] for k in keys}
    out["params"] = {k: state["params", k] for k in _param_keys(reverse)}
    return out


def _param_keys(reverse: bool) -> tuple[str, ...]:
    """The vehicle parameters of a task's trucks (:data:`REVERSE_KEYS` too if it reverses)."""
    return (*PARAM_KEYS, *REVERSE_KEYS) if reverse else PARAM_KEYS


class Planner:
    """CEM planner on the task core of ``env_cfg`` (module doc).

    Args:
        env_cfg: :class:`~truckrl.tasks.EnvConfig` or a mapping of its fields.
        config: :class:`PlannerConfig` or a mapping of its fields.
        device: where the rollouts run.
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
        if self.config.steer_prior != "none" and self.task.reverse:
            raise ConfigError(
                f"planner.steer_prior = {self.config.steer_prior!r} plans forward driving only; task "
                f"{self.env_cfg.task.name!r} reverses: use steer_prior=none"
            )
        cfg, pc = self.env_cfg, self.config
        self.horizon = cfg.max_steps
        self.w_steer = knot_matrix(self.horizon, pc.steer_knots, self.device)
        self.w_speed = knot_matrix(self.horizon, pc.speed_knots, self.device)
        self.lon_order = LONGITUDINAL_MODES.index(cfg.control.longitudinal)
        self.lat_order = LATERAL_MODES.index(cfg.control.lateral)
        self.lon_limits = [lim for _, lim in MODE_TABLE["longitudinal"].values()]
        self.lat_limits = [lim for _, lim in MODE_TABLE["lateral"].values()]
        self.state_keys = ("pose", "goal", "segments", "mask", "step_count", *CONTROL_KEYS)
        self.state_keys += self.task.error_keys
        self._step = compile_sim(self._step_fn, self.device) if pc.compile else self._step_fn

    # ------------------------------------------------------------------ one step
    def _track(self, ref: Tensor, q: Sequence[Tensor], hi: Sequence[Tensor], lo0, order: int):
        """Command in ``[-1, 1]`` that moves chain ``q = (q0, q1, q2)`` towards ``q0 = ref``."""
        dt = self.env_cfg.dt
        if order == 0:
            u = (2.0 * ref - (hi[0] + lo0)) / (hi[0] - lo0)
        elif order == 1:
            u = (ref - q[0]) / (dt * hi[1])
        else:
            rate = torch.minimum(torch.maximum((ref - q[0]) / (3.0 * dt), -hi[1]), hi[1])
            u = (rate - q[1]) / (dt * hi[2])
        return u.clamp(-1.0, 1.0)

    def _score(self, s: dict[str, Any], difficulty: Tensor) -> tuple[Tensor, Tensor]:
        """``(score, worst)`` ``[N]``: the largest error / tolerance ratio over the task's errors
        (``worst``; the goal test is ``worst <= 1``) plus ``mean_weight`` x their mean."""
        tol_pos, tol_ang = self.task.tolerances(difficulty)
        ratios = torch.stack(
            [
                s[q.key] / (tol_pos if q.unit == "m" else tol_ang)
                for q in self.task.error_quantities
            ],
            -1,
        )
        worst = ratios.amax(-1)
        return worst + self.config.mean_weight * ratios.mean(-1), worst

    def _pursuit(self, s: dict[str, Any], plan: Tensor) -> Tensor:
        """Steering angle [rad] that pursues the goal line; ``plan [N, 5]`` as :meth:`_extras`
        (uses the look-ahead [m], the gain [1/m] and the blend weight of the trailer law).

        Both laws aim ``look-ahead`` metres ahead of their point's projection on the goal line.
        Tractor: pure pursuit of the rear axle. Trailer: pure pursuit of the trailer axle gives a
        trailer curvature ``k_t``, hence an articulation set-point ``phi_d = asin(-k_t L_ka)``,
        which the tractor's curvature tracks at ``gain`` per metre driven (``phi' = gain (phi_d -
        phi)``, from the hitch kinematics of :func:`truckrl.sim.vehicle.kinematics_step`):
        driving the trailer onto the line lines up the tractor too, in less distance than a
        trailer settling behind a tractor on the line.
        """
        pose, goal, p = s["pose"], s["goal"], s["params"]
        theta, phi = pose[:, 2], pose[:, 3]
        psi = theta + phi
        a, l_ka = p["kingpin_offset"], p["trailer_wheelbase"]
        king = pose[:, :2] - a[:, None] * torch.stack((theta.cos(), theta.sin()), -1)
        axle = king - l_ka[:, None] * torch.stack((psi.cos(), psi.sin()), -1)
        d = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)

        def pursue(point: Tensor, heading: Tensor) -> Tensor:
            along = ((point - goal[:, :2]) * d).sum(-1)
            vec = goal[:, :2] + (along + plan[:, 1])[:, None] * d - point
            alpha = torch.atan2(vec[:, 1], vec[:, 0]) - heading
            return 2.0 * torch.sin(alpha) / vec.norm(dim=-1).clamp_min(1e-3)

        k_tractor = pursue(pose[:, :2], theta)
        phi_d = torch.asin((-pursue(axle, psi) * l_ka).clamp(-0.95, 0.95))
        phi_rate = plan[:, 2] * (phi_d - phi)  # per metre driven
        k_trailer = -(phi_rate + phi.sin() / l_ka) / (1.0 + a / l_ka * phi.cos())
        w = plan[:, 3]
        return torch.atan(((1.0 - w) * k_tractor + w * k_trailer) * p["wheelbase"])

    def _arrival_distance(self, s: dict[str, Any]) -> Tensor:
        """Distance [m] the arrival cap brakes over in a task that reverses: from the tractor
        rear axle to the goal (a rear-axle pose), ignoring the first ``arrival_slack`` metres
        across the goal line, ``sqrt(along^2 + max(|across| - slack, 0)^2)``. A truck that
        arrives slightly off the line still brakes to the arrival speed at the goal (a task
        whose success needs the truck at rest, e.g. docking) instead of passing it at the
        speed that the residual offset allows."""
        goal, rel = s["goal"], s["pose"][:, :2] - s["goal"][:, :2]
        c, sn = goal[:, 2].cos(), goal[:, 2].sin()
        along = rel[:, 0] * c + rel[:, 1] * sn
        across = (-rel[:, 0] * sn + rel[:, 1] * c).abs() - self.config.arrival_slack
        return torch.hypot(along, across.clamp_min(0.0))

    def _pursuit_signed(self, s: dict[str, Any], plan: Tensor, backward: Tensor) -> Tensor:
        """:meth:`_pursuit` for a task that reverses: where ``backward [N]`` (the speed set-point
        is negative) the laws pursue the goal line in the direction of motion, backwards.

        With ``sigma = -1`` backwards (``+1`` forwards), both laws aim ``look-ahead`` metres from
        their point's projection on the goal line (the line through the goal along its heading),
        in the direction the point moves along it, and pure pursuit runs on the motion heading
        (``heading + pi`` backwards); the
        signed path curvature (per metre of signed travel, as ``tan(delta) / L_t``) is ``sigma``
        times pure pursuit's. Backwards the trailer axle leads: its pursuit gives the trailer
        curvature ``k_t``, hence ``phi_d = asin(-k_t L_ka)`` (limited to ``asin(0.5)`` backwards,
        where the hitch is unstable), and the tractor curvature makes the articulation follow it
        at ``gain`` per metre driven, ``d phi / d|s| = gain (phi_d - phi)``, by inverting the hitch
        kinematics (``d phi / ds = -k (1 + a / L_ka cos phi) - sin(phi) / L_ka``, ``s`` signed
        travel). Backwards only the trailer law is used (steering the tractor onto the line
        folds the trailer); forwards it is :meth:`_pursuit`'s planned blend.
        """
        pose, goal, p = s["pose"], s["goal"], s["params"]
        theta, phi = pose[:, 2], pose[:, 3]
        psi = theta + phi
        a, l_ka = p["kingpin_offset"], p["trailer_wheelbase"]
        king = pose[:, :2] - a[:, None] * torch.stack((theta.cos(), theta.sin()), -1)
        axle = king - l_ka[:, None] * torch.stack((psi.cos(), psi.sin()), -1)
        d = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)
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
        k_trailer = -(phi_rate + phi.sin() / l_ka) / (1.0 + a / l_ka * phi.cos())
        w = torch.where(backward, 1.0, plan[:, 3])
        return torch.atan(((1.0 - w) * k_tractor + w * k_trailer) * p["wheelbase"])

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
        """One step of every candidate: build the set-points (from ``ref [N, 2]``, the time-indexed
        steer [rad] and speed [m/s], or from the distance-indexed ``knots [N, Ms]`` [rad] and
        ``vknots [N, Mv]`` [m/s] at the distance driven over ``span [N]`` [m]; then the pursuit
        and the arrival cap of ``plan [N, 5]``; plus the arc prior ``arc [N, 3]`` of
        :meth:`_arc`), track them, advance, test the outcome and update the bookkeeping ``acc``."""
        p = s["params"]
        speed_ref = (
            ref[:, 1] if self.config.speed_axis == "time" else _interp(vknots, acc["travel"] / span)
        )
        if self.config.arrival:
            if self.task.reverse:
                dist = self._arrival_distance(s)
            else:
                dist = (s["goal"][:, :2] - s["pose"][:, :2]).norm(dim=-1)
            decel = self.config.brake * p["max_accel"]
            cap = (plan[:, 4].square() + 2.0 * decel * dist).sqrt()
            speed_ref = torch.minimum(speed_ref, cap)
            if self.task.reverse:  # the same cap on the reverse speed
                speed_ref = torch.maximum(speed_ref, -cap)
        if self.config.steer_axis == "distance":
            steer_ref = _interp(knots, acc["travel"] / span)
        else:
            steer_ref = ref[:, 0]
        on_arc = (acc["travel"] >= arc[:, 0]) & (acc["travel"] < arc[:, 1])
        steer_ref = steer_ref + torch.where(on_arc, arc[:, 2], 0.0)
        if self.config.pursuit != "none":  # (switch = inf otherwise)
            if self.task.reverse:
                law = self._pursuit_signed(s, plan, speed_ref < 0)
            else:
                law = self._pursuit(s, plan)
            steer_ref = torch.where(acc["travel"] >= plan[:, 0], law, steer_ref)
        lon = self._track(
            speed_ref,
            [s[k] for k in ("speed", "accel", "jerk")],
            [p[k] for k in self.lon_limits],
            self.task.control.speed_floor(p),
            self.lon_order,
        )
        lat = self._track(
            steer_ref,
            [s[k] for k in ("steer", "steer_rate", "steer_accel")],
            [p[k] for k in self.lat_limits],
            -p["max_steer"],
            self.lat_order,
        )
        action = torch.stack((lon, lat), -1)
        new = self.task.step(s, action)
        after = {**s, **new}
        flags = self.task.outcome(after, difficulty)
        score, worst = self._score(after, difficulty)
        alive = acc["alive"]
        intact = alive & ~(flags["collision"] | flags["jackknife"])
        better = intact & (score < acc["best"])
        out = {
            "best": torch.where(better, score, acc["best"]),
            "worst": torch.where(better, worst, acc["worst"]),
            "success": acc["success"] | (alive & flags["success"]),
            "length": torch.where(alive, after["step_count"], acc["length"]),
            "alive": alive & ~flags["terminated"],
            "travel": acc["travel"] + new["speed"].abs() * self.env_cfg.dt,
        }
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
        w = (
            f[:, 3]
            if pc.pursuit == "blend"
            else torch.full_like(span, float(pc.pursuit == "trailer"))
        )
        arrive = (v0 + f[:, 4] * (v1 - v0)) * params["max_speed"]
        return torch.stack(
            (switch, l0 + f[:, 1] * (l1 - l0), g0 + f[:, 2] * (g1 - g0), w, arrive), -1
        )

    def _arc(self, s: dict[str, Any], x: Tensor) -> Tensor:
        """``[N, 3]`` arc prior of candidates ``x [N, P]`` (``steer_prior=arc``, else zeros): the
        travel [m] where the arc starts and ends, and its steering angle [rad].

        The start lane is the line through the start rear axle along its heading, the goal lane
        likewise; where they meet at a corner ahead of the start and before the goal
        (:func:`truckrl.tasks.intersection.task.lane_corner`, as the lane route), the prior is
        the circle of radius ``R`` tangent to both lanes, driven by the tractor rear axle at
        steering ``atan(wheelbase / R)``: straight for ``a - R tan(turn / 2)``, then the arc for
        ``R |turn|`` (``a``, ``b``: start-corner and corner-goal distances). ``R`` runs from
        ``R_lo = max(wheelbase / tan(max_steer), trailer wheelbase)`` (the tractor's tightest
        circle, and the kingpin circle below which the articulation grows to the jack-knife
        limit) to the largest circle that fits both legs, ``min(a, b) / tan(turn / 2)``, at the
        candidate's last parameter. Elsewhere (parallel lanes: a straight road, straight on) the
        prior is 0 and the knots steer alone."""
        n = x.shape[0]
        if self.config.steer_prior == "none":
            return torch.zeros(n, 3, device=x.device)
        pose, goal, p = s["pose"], s["goal"], s["params"]
        f = 0.5 * (x[:, -1] + 1.0)  # [0, 1]
        a, b, real = lane_corner(pose[:, :3], goal)  # start -> corner, corner -> goal [m]
        turn = wrap_angle(goal[:, 2] - pose[:, 2])
        half = (0.5 * turn.abs()).tan().clamp_min(1e-6)
        r_lo = torch.maximum(p["wheelbase"] / p["max_steer"].tan(), p["trailer_wheelbase"])
        r_fit = torch.minimum(a, b) / half
        r = r_lo + f * (r_fit - r_lo).clamp_min(0.0)
        begin = (a - r * half).clamp_min(0.0)
        steer = torch.where(real, turn.sign() * torch.atan(p["wheelbase"] / r), 0.0)
        return torch.stack((begin, begin + r * turn.abs(), steer), -1)

    @torch.no_grad()
    def rollout(
        self, start: TensorDictBase, x: Tensor, difficulty: float, arc_on: Tensor | None = None
    ) -> tuple[dict[str, Tensor], Tensor]:
        """Roll candidates ``x [N, P]`` out from ``start [N]`` (one state row per candidate).

        Returns:
            ``(acc, actions)``: per candidate ``best`` (lowest score while intact), ``worst``
            (the largest error / tolerance ratio at that step),
            ``success``, ``length`` (steps until its episode ended) and ``alive``; the applied
            actions ``[T, N, 2]`` (rows after the end of an episode are meaningless).
        """
        n, dev = x.shape[0], self.device
        s = _flat(start, self.state_keys, self.task.reverse)
        refs = self._references(x, s["params"])
        ks, kv = self.config.steer_knots, self.config.steer_knots + self.config.speed_knots
        knots = x[:, :ks] * s["params"]["max_steer"][:, None]
        vknots = self._speed_map(x[:, ks:kv], s["params"])
        start_goal = (s["goal"][:, :2] - s["pose"][:, :2]).norm(dim=-1)
        span = self.config.path_stretch * start_goal + self.config.path_extra
        plan = self._extras(x, s["params"], span)
        arc = self._arc(s, x)
        if arc_on is not None:  # candidates of knots-only attempts (steer_prior=alternate)
            arc[:, 2] = torch.where(arc_on, arc[:, 2], 0.0)
        diff = torch.full((n,), float(difficulty), device=dev)
        score0, worst0 = self._score(s, diff)
        zero_i = torch.zeros(n, dtype=torch.int64, device=dev)
        acc = {
            "best": score0,
            "worst": worst0,
            "success": torch.zeros(n, dtype=torch.bool, device=dev),
            "length": zero_i,
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

    # ------------------------------------------------------------------ CEM over scenes
    @torch.no_grad()
    def plan(
        self,
        states: TensorDictBase,
        difficulty: float,
        progress: Callable[[int, int], None] | None = None,
    ) -> dict[str, Any]:
        """Plan every scene of ``states [E]`` (start states as from ``TruckEnv.get_state()``).

        Returns:
            ``{"candidates": list per scene of (cost, score, actions [T, 2]) best first (the
            successful ones, up to ``replay_candidates``, or the lowest-cost one),
            "planned_success" [E] bool, "best_ratio" [E] (largest error / tolerance at the
            closest approach of the best candidate), "iterations" [E] int (all attempts),
            "attempts" [E] int, "rollouts" int, "seconds" float}``.
        """
        check_range("difficulty", difficulty, 0.0, MAX_DIFFICULTY)
        pc, dev = self.config, self.device
        e, k = states.batch_size[0], pc.samples
        states = states.to(dev)
        g = torch.Generator(device=dev)
        g.manual_seed(pc.seed)
        best_cost = torch.full((e,), math.inf)
        best_ratio = torch.full((e,), math.inf)
        iters = torch.zeros(e, dtype=torch.int64)
        started = torch.zeros(e, dtype=torch.int64)
        done = torch.zeros(e, dtype=torch.bool)
        cands: list[list[tuple[float, float, Tensor]]] = [[] for _ in range(e)]
        queue = list(range(e))  # scenes waiting for their first attempt
        jobs: list[_Job] = []
        slots = pc.scenes_per_batch
        rollouts, t0 = 0, time.perf_counter()
        while queue or jobs:
            # fill the slots: first attempts, then restarts of unsolved scenes, then share
            while len(jobs) < slots:
                if queue:
                    scene = queue.pop(0)
                    if done[scene]:
                        continue
                else:
                    running = dict.fromkeys(j.scene for j in jobs)
                    spare = [i for i in running if started[i] < pc.attempts]
                    if not spare:
                        break
                    scene = min(spare, key=lambda i: int(started[i]))
                started[scene] += 1
                arc = pc.steer_prior == "arc" or (
                    pc.steer_prior == "alternate" and int(started[scene]) % 2 == 1
                )
                jobs.append(_Job(scene, pc, dev, arc))
            owner = [jobs[j % len(jobs)] for j in range(slots)]
            mean = torch.stack([j.mean for j in owner])
            std = torch.stack([j.std for j in owner])
            xs = mean[:, None] + std[:, None] * torch.randn(
                slots, k, pc.num_params, generator=g, device=dev
            )
            xs = xs.clamp(-1.0, 1.0)
            for j, job in enumerate(owner):
                if job.iters > 0 and owner.index(job) == j:
                    xs[j, 0] = job.best_x  # elitism: the best candidate so far rides along
            x = xs.reshape(slots * k, pc.num_params)
            rows = torch.tensor([job.scene for job in owner], device=dev).repeat_interleave(k)
            arc_on = torch.tensor([job.arc for job in owner], device=dev).repeat_interleave(k)
            acc, actions = self.rollout(states[rows], x, difficulty, arc_on)
            rollouts += slots * k
            cost = (acc["best"] - SUCCESS_BONUS * acc["success"].float()).cpu()
            score = acc["best"].cpu()
            worst = acc["worst"].cpu()
            length = acc["length"].cpu()
            slot_of_row = torch.arange(slots).repeat_interleave(k)
            for job in dict.fromkeys(owner):
                mine = torch.tensor([o is job for o in owner])
                sel = mine[slot_of_row].nonzero().squeeze(-1)
                c, xi = cost[sel], x[sel.to(dev)]
                order = torch.argsort(c)
                job.update(xi[order.to(dev)[: max(2, math.ceil(pc.elite_frac * sel.numel()))]])
                i, top = job.scene, int(sel[order[0]])
                if cost[top] < job.best_cost:
                    job.best_cost, job.best_x = float(cost[top]), x[top].clone()
                if cost[top] < best_cost[i]:
                    best_cost[i], best_ratio[i] = cost[top], worst[top]
                new = [
                    (float(cost[r]), float(score[r]), actions[: int(length[r]), r].cpu())
                    for r in sel[order[: pc.replay_candidates]].tolist()
                ]
                merged = sorted(
                    {(z[0], z[1]): z for z in cands[i] + new}.values(), key=lambda z: z[0]
                )  # a rollout is deterministic: the elite carried over repeats its cost exactly
                succeeded = [z for z in merged if z[0] < 0]
                cands[i] = succeeded[: pc.replay_candidates] if succeeded else merged[:1]
                iters[i] += 1
                if best_cost[i] < 0 and best_ratio[i] <= pc.stop_margin:
                    done[i] = True  # solved with room to spare: stop every attempt
            ended = [j for j in jobs if j.iters >= pc.iterations]
            jobs = [j for j in jobs if not done[j.scene] and j.iters < pc.iterations]
            for job in ended:  # an attempt used up its iterations: restart later, or give up
                i = job.scene
                if done[i] or any(j.scene == i for j in jobs) or i in queue:
                    continue
                if started[i] < pc.attempts:
                    queue.append(i)
                else:
                    done[i] = True
            if progress is not None:
                progress(int(done.sum()), e)
        return {
            "candidates": cands,
            "planned_success": best_cost < 0,
            "best_ratio": best_ratio,
            "iterations": iters,
            "attempts": started,
            "rollouts": rollouts,
            "seconds": time.perf_counter() - t0,
        }


class _Job:
    """One CEM attempt at one scene: its Gaussian over the knots and its best candidate."""

    def __init__(
        self, scene: int, pc: PlannerConfig, device: torch.device, arc: bool = False
    ) -> None:
        self.scene, self.pc, self.iters, self.arc = scene, pc, 0, arc
        self.mean = torch.zeros(pc.num_params, device=device)
        self.mean[pc.steer_knots : pc.steer_knots + pc.speed_knots] = pc.speed_mean
        std = pc.arc_init_std if arc else pc.init_std
        self.std = torch.full((pc.num_params,), std, device=device)
        self.best_x = self.mean.clone()
        self.best_cost = math.inf

    def update(self, elites: Tensor) -> None:
        a = self.pc.smoothing
        self.mean = a * self.mean + (1.0 - a) * elites.mean(0)
        self.std = (a * self.std + (1.0 - a) * elites.std(0)).clamp_min(self.pc.min_std)
        self.iters += 1


@torch.no_grad()
def replay(
    env_cfg: EnvConfig | dict | None,
    states: TensorDictBase,
    actions: Tensor,
    difficulty: float,
    device: torch.device | str = "cpu",
) -> dict[str, Tensor]:
    """Replay open-loop ``actions [N, T, 2]`` from ``states [N]`` through a fresh eager
    :class:`TruckEnv`; record every episode at its first ``done`` (as ``evaluate_policy``).

    Returns:
        ``{flag: [N] bool for "success", "collision", "jackknife", "truncated"; "length" [N];
        the task's errors [N] in their shown units}``.
    """
    cfg = dataclasses.replace(build(EnvConfig, env_cfg, "env"), compile=False)
    n = states.batch_size[0]
    env = TruckEnv(num_envs=n, device=device, config=cfg, seed=0)
    env.set_difficulty(difficulty)
    env.set_state(states)
    errors = env.task.error_quantities
    flags = tuple(o.flag for o in OUTCOMES)
    keys = (*flags, *(q.key for q in errors), "step_count")
    rec = {k: torch.zeros(n, device=device) for k in keys}
    ended = torch.zeros(n, dtype=torch.bool, device=device)
    actions = actions.to(device)
    for t in range(cfg.max_steps):
        a = actions[:, t] if t < actions.shape[1] else torch.zeros(n, 2, device=device)
        nxt = env.step(TensorDict({"action": a}, batch_size=[n], device=device))["next"]
        new = nxt["done"].squeeze(-1) & ~ended
        for k in keys:
            rec[k] = torch.where(new, nxt[k].squeeze(-1).to(torch.float32), rec[k])
        ended |= new
        if bool(ended.all()):
            break
    env.close()
    out = {k: rec[k].bool().cpu() for k in flags}
    out["length"] = rec["step_count"].cpu()
    for q in errors:
        out[q.key] = shown(q, rec[q.key]).cpu()
    return out


def plan_states(
    env_cfg: EnvConfig | dict | None,
    states: TensorDictBase,
    difficulty: float,
    config: PlannerConfig | dict | None = None,
    device: torch.device | str = "cpu",
    progress: Callable[[int, int], None] | None = None,
    extra: Tensor | None = None,
) -> tuple[dict[str, Any], tuple[float, float], tuple[Quantity, ...]]:
    """Plan every start state of ``states [E]`` and confirm each plan by replay.

    With ``extra`` (``[E, T', 2]`` action sequences from another controller, e.g. a policy's
    mean actions from :func:`~truckrl.evaluation.rollout.policy_actions`), each scene's extra sequence
    is replayed in the same batch as the planner's candidates, and a scene counts as solved when
    either replay succeeds: the planner's result is reported where it succeeded, else the extra
    sequence's where that did, else the planner's. ``results["by_source"]`` then holds both
    replays (``{"planner": ..., "extra": ...}``, each with the outcome flags, "length" and the
    errors ``[E]``), so each controller can be scored alone on the same scenes.

    Returns:
        ``(results, (position tolerance [m], heading tolerance [deg]), errors)`` as
        :func:`~truckrl.evaluation.rollout.evaluate_policy`; ``results`` holds its per-episode keys
        (from the replay) plus "planned_success" (the planner's own rollout succeeded),
        "replay_mismatch" (it did, but no replay did), "best_ratio" (the largest error /
        tolerance ratio at the closest approach of the best candidate: <= 1 within the
        tolerances), "iterations" and "attempts" (CEM), "actions" ``[E, T, 2]`` (the reported
        sequence, zeros after its end), "params" (the vehicle parameters, ``{key: [E]}``) and
        the totals "rollouts", "plan_seconds"; with ``extra``, also "by_source" (above) and
        "solved_by_extra" ``[E]`` (the reported replay is the extra sequence's).
    """
    planner = Planner(env_cfg, config, device)
    cfg = planner.env_cfg
    e, horizon = states.batch_size[0], planner.horizon
    if extra is not None and (extra.dim() != 3 or extra.shape[0] != e or extra.shape[2] != 2):
        raise ValueError(f"extra must be [{e}, T, 2] action sequences, got {list(extra.shape)}")
    plan = planner.plan(states, difficulty, progress)
    # replay every kept candidate (and each scene's extra sequence) in one batch
    owner, seqs = [], []
    for i, cs in enumerate(plan["candidates"]):
        for _, _, a in cs:
            owner.append(i)
            pad = torch.zeros(horizon, 2)
            pad[: a.shape[0]] = a
            seqs.append(pad)
    n_planned = len(owner)
    if extra is not None:
        owner.extend(range(e))
        pad = torch.zeros(e, horizon, 2)
        t = min(horizon, extra.shape[1])
        pad[:, :t] = extra[:, :t].cpu()
        seqs.extend(pad)
    owner_t = torch.tensor(owner)
    acts = torch.stack(seqs)
    rep = replay(cfg, states[owner_t.to(states.device)], acts, difficulty, device)
    pick = torch.zeros(e, dtype=torch.long)
    for i in range(e):
        rows = (owner_t[:n_planned] == i).nonzero().squeeze(-1)
        ok = rep["success"][rows]
        pick[i] = rows[ok.nonzero()[0, 0]] if bool(ok.any()) else rows[0]
    by_source: dict[str, dict[str, Tensor]] = {"planner": {k: v[pick] for k, v in rep.items()}}
    if extra is not None:
        extra_rows = torch.arange(n_planned, n_planned + e)
        by_source["extra"] = {k: v[extra_rows] for k, v in rep.items()}
        use_extra = by_source["extra"]["success"] & ~by_source["planner"]["success"]
        pick = torch.where(use_extra, extra_rows, pick)
    results: dict[str, Any] = {k: v[pick] for k, v in rep.items()}
    if extra is not None:
        results["by_source"] = by_source
        results["solved_by_extra"] = use_extra
    length = results["length"].long()
    steps = torch.arange(horizon)
    results["actions"] = acts[pick] * (steps[None, :, None] < length[:, None, None])
    results["planned_success"] = plan["planned_success"]
    results["replay_mismatch"] = plan["planned_success"] & ~results["success"]
    results["best_ratio"] = plan["best_ratio"]
    results["iterations"] = plan["iterations"]
    results["attempts"] = plan["attempts"]
    results["rollouts"] = plan["rollouts"]
    results["plan_seconds"] = plan["seconds"]
    results["params"] = {k: states["params", k].cpu() for k in _param_keys(planner.task.reverse)}
    # The scene keys of evaluate_policy's results, flat and in its dtypes.
    results["trailer_length"] = trailer_length(results["params"])
    # the task's scene metadata (evaluation bins by it), as evaluate_policy records it
    keys: list[str] = []
    for entry in SCENE_INFO_ENTRIES:
        if entry in states.keys():
            for k in states[entry].keys():
                v = states[entry, k].cpu()
                results[k] = v.long() if k == "route" else v
                keys.append(k)
    results["scene_info_keys"] = tuple(keys)
    task = planner.task
    tol_pos, tol_ang = task.tolerances(torch.tensor([float(difficulty)]))
    tolerance = (float(tol_pos[0]), math.degrees(float(tol_ang[0])))
    return results, tolerance, task.error_quantities


def held_out_states(
    env_cfg: EnvConfig | dict | None,
    episodes: int,
    seed: int,
    device: torch.device | str = "cpu",
    difficulty: float | None = None,
) -> TensorDict:
    """The start states of the ``episodes`` scenes that ``evaluate_policy`` draws for ``seed``
    (at ``difficulty``, default the env's starting one: a task with a start curriculum,
    ``Task.on_reset``, places its starts by the difficulty, as ``evaluate_policy`` does)."""
    cfg = dataclasses.replace(build(EnvConfig, env_cfg, "env"), compile=False)
    env = TruckEnv(num_envs=episodes, device=device, config=cfg, seed=seed)
    if difficulty is not None:
        env.set_difficulty(difficulty)
    env.reset()
    states = env.get_state()
    env.close()
    return states


def plan_episodes(
    env_cfg: EnvConfig | dict | None,
    difficulty: float,
    episodes: int,
    seed: int,
    config: PlannerConfig | dict | None = None,
    device: torch.device | str = "cpu",
    indices: Sequence[int] | Tensor | None = None,
    progress: Callable[[int, int], None] | None = None,
    policy: Callable[[TensorDictBase], TensorDictBase] | None = None,
) -> tuple[dict[str, Any], tuple[float, float], tuple[Quantity, ...]]:
    """Plan the ``episodes`` seeded scenes that ``evaluate_policy(…, episodes, seed)`` scores.

    Args:
        env_cfg: env config (task, vehicle and scene ranges, ``max_steps``, control mode).
        difficulty: curriculum difficulty of the goal test.
        episodes, seed: which scenes (the same as ``evaluate_policy`` with these values).
        config: :class:`PlannerConfig` or a mapping of its fields.
        device: where the rollouts and replays run.
        indices: plan only these of the ``episodes`` scenes (``results["scene_index"]`` says
            which); default all.
        progress: called as ``progress(done, total)`` after every CEM iteration.
        policy: a policy (as ``evaluate_policy`` takes) whose mean actions on the same scenes
            are replayed beside the planner's candidates (``plan_states``'s ``extra``): a scene
            is then solved when the planner or the policy solves it.

    Returns:
        As :func:`plan_states`, plus ``results["scene_index"] [E]``.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError(f"episodes = {episodes!r} must be a whole number >= 1")
    states = held_out_states(env_cfg, episodes, seed, device, difficulty)
    index = torch.arange(episodes) if indices is None else torch.as_tensor(indices).long()
    if index.numel() and (index.min() < 0 or index.max() >= episodes):
        raise ConfigError(f"indices must lie in [0, {episodes - 1}]")
    states = states[index.to(states.device)]
    extra = None
    if policy is not None:
        extra = policy_actions(policy, build(EnvConfig, env_cfg, "env"), states, difficulty, device)
    results, tolerance, errors = plan_states(
        env_cfg, states, difficulty, config, device, progress, extra
    )
    results["scene_index"] = index
    return results, tolerance, errors


def category_info(results: dict[str, Any]) -> dict[str, Tensor]:
    """Per-episode inputs of :func:`truckrl.evaluation.categories.task_bins` from plan results: the
    trailer length and the scene metadata (intersection: the route keys; other tasks: theirs)."""
    keys = ("trailer_length", *results.get("scene_info_keys", ()))
    return {k: results[k] for k in keys if k in results}
