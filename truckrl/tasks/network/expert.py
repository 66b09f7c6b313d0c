"""A scripted route driver for task ``network``: demonstrations, and a lower bound on solvability.

:class:`RouteDriver` drives the route a network episode holds (``route_points``, the lane path
through the chain's junctions) forwards, with privileged knowledge of the traffic:

* **Steering**: pure pursuit of the tractor rear axle on the route point ``lookahead`` metres of
  arc length past the truck's projection (``route_s``), the steering angle
  ``atan(2 L_t sin(alpha) / d)`` for the bearing ``alpha`` of that point from the tractor's
  heading and its distance ``d`` (Coulter 1992, "Implementation of the Pure Pursuit Path
  Tracking Algorithm"). Before a right turn (the route's heading ``wide_ahead`` metres on
  turned right of its heading here) the aim moves up to ``wide`` metres left of the route, into
  the other lane: the rig swings wide, so its trailer, which cuts inside, clears the junction's
  inner curb corner (docs/networks.md, "A scripted driver").
* **Speed** (:func:`~truckrl.planning.controller.setpoint_action` tracks it): the least of the cruise speed, the speed that keeps the lateral acceleration
  below ``lateral_accel`` on the route's curvature ahead, the speed that stops ``stop_gap``
  metres before the first route sample covered by a vehicle (its box grown by the truck's half
  width and ``clearance``) where it is now or where it will be ``predict`` seconds on (moved
  along its lane at its present speed: a vehicle about to cross the route counts before it
  gets there), and, near the goal, the speed that arrives at ``arrive_speed``.

:func:`demonstrations` (``demos.source=driver``) drives held-out scenes with it in an eager env
and keeps the successful episodes: what :func:`truckrl.rl.imitation.bootstrap` clones.
:func:`labelled` (``demos.dagger_rounds``) lets a policy drive instead and keeps every state it
visits with the action the driver would have taken there (DAgger: Ross, Gordon and Bagnell 2011,
"A Reduction of Imitation Learning and Structured Prediction to No-Regret Online Learning"): the
clone then learns to recover from its own mistakes, which the driver's clean episodes never show.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict
from torch import Tensor

from truckrl.env import LIDAR_KEY, OBS_KEY, TruckEnv
from truckrl.planning.controller import setpoint_action
from truckrl.planning.scenes import held_out_states, kept_samples
from truckrl.sim.geometry import to_local, wrap_angle
from truckrl.sim.network.traffic import boxes
from truckrl.tasks import EnvConfig
from truckrl.tasks.network.scene import point_at
from truckrl.tasks.network.task import traffic_of


@dataclass(frozen=True)
class RouteDriver:
    """The driver's constants (lengths [m], speeds [m/s], accelerations [m/s^2])."""

    lookahead: float = 6.0  # pure-pursuit distance at standstill
    lookahead_per_speed: float = 0.3  # [s]: added per m/s of speed
    cruise: float = 6.0  # at most; the truck's own max_speed caps it too
    lateral_accel: float = 1.5  # on the curvature of the next preview metres
    preview: float = 25.0  # route ahead read for curvature and vehicles
    preview_samples: int = 26
    curvature_span: int = 6  # samples (5 m) over which a heading change counts as curvature
    brake: float = 1.5  # deceleration planned for stopping behind a vehicle and at the goal
    stop_gap: float = 3.0  # bumper gap kept to the first vehicle on the route
    clearance: float = 0.6  # added to the truck's half width round a vehicle's box
    arrive_speed: float = 1.0  # speed when crossing the goal
    wide: float = 4.5  # [m] left of the route the tractor aims before a right turn
    wide_ahead: float = 20.0  # [m] of route over which the coming turn is read
    wide_turn: float = 1.0  # [rad] of right turn over wide_ahead for the full offset
    predict: tuple[float, ...] = (0.0, 1.0, 2.0)  # [s]: each vehicle now and where it will be

    def setpoints(self, s: Mapping[str, Any]) -> tuple[Tensor, Tensor]:
        """``(speed [N] [m/s], steering angle [N] [rad])`` set-points for the state dict ``s``
        (``pose [N, 4]``, ``speed [N]``, ``params``, the network task's route and traffic
        keys)."""
        pose, p, v = s["pose"], s["params"], s["speed"]
        pts, cum, route_s, goal_s = s["route_points"], s["route_cum"], s["route_s"], s["goal_s"]
        end = cum[:, -1]
        # ---- steering: pure pursuit of the route by the tractor's rear axle
        ld = self.lookahead + self.lookahead_per_speed * v.clamp_min(0.0)
        at = torch.stack((route_s + ld, route_s + self.wide_ahead), -1).minimum(end.unsqueeze(-1))
        _, h0 = point_at(pts, cum, route_s.unsqueeze(-1))
        target, h = point_at(pts, cum, at)
        right = (-wrap_angle(h[:, 1] - h0[:, 0]) / self.wide_turn).clamp(0.0, 1.0)
        left = torch.stack((-h[:, 0].sin(), h[:, 0].cos()), -1)
        aim = target[:, 0] + (self.wide * right).unsqueeze(-1) * left
        rel = to_local(aim.unsqueeze(1), pose[:, :2], pose[:, 2]).squeeze(1)
        kappa_t = 2.0 * rel[:, 1] / (rel * rel).sum(-1).clamp_min(1e-6)
        steer = torch.atan(p["wheelbase"] * kappa_t)
        steer = torch.maximum(torch.minimum(steer, p["max_steer"]), -p["max_steer"])
        # ---- speed
        ahead = route_s.unsqueeze(-1) + torch.linspace(
            0.0, self.preview, self.preview_samples, device=pose.device
        )
        ahead = ahead.minimum(end.unsqueeze(-1))  # [N, S]
        xy, heading = point_at(pts, cum, ahead)  # [N, S, 2], [N, S]
        w = self.curvature_span
        turn = wrap_angle(heading[:, w:] - heading[:, :-w]).abs()
        step = (ahead[:, w:] - ahead[:, :-w]).clamp_min(1.0)
        kappa = (turn / step).amax(-1)
        speed = torch.minimum(p["max_speed"], torch.full_like(v, self.cruise))
        speed = speed.minimum((self.lateral_accel / kappa.clamp_min(1e-4)).sqrt())
        front = p["wheelbase"] + p["front_overhang"]  # rear axle to front bumper
        if "tr_active" in s and s["tr_active"].shape[1] > 0:
            tr = traffic_of(s)
            blocked = torch.zeros((), dtype=torch.bool, device=xy.device)
            for t in self.predict:  # along its lane at its present speed
                at_t = dataclasses.replace(tr, s=tr.s + t * tr.v)
                blocked = blocked | _covered(xy, boxes(at_t), s, p, self.clearance)  # [N, M, S]
            big = torch.full_like(ahead, math.inf)
            first = torch.where(blocked, ahead.unsqueeze(1), big.unsqueeze(1)).amin(-1).amin(-1)
            gap = (first - route_s - front - self.stop_gap).clamp_min(0.0)
            speed = speed.minimum((2.0 * self.brake * gap).sqrt())
        to_goal = (goal_s - route_s).clamp_min(0.0)
        speed = speed.minimum((self.arrive_speed**2 + 2.0 * self.brake * to_goal).sqrt())
        return speed, steer


def _covered(
    xy: Tensor, box: Tensor, s: Mapping[str, Any], p: Mapping[str, Tensor], clearance: float
) -> Tensor:
    """Whether route samples ``xy [N, S, 2]`` lie in vehicle boxes ``box [N, M, 6]`` grown by
    the truck's half width plus ``clearance`` [m]: ``[N, M, S]`` bool (empty and waiting slots
    never)."""
    grow = 0.5 * torch.maximum(p["tractor_width"], p["trailer_width"]) + clearance  # [N]
    d = xy.unsqueeze(1) - box[..., None, :2]  # [N, M, S, 2]
    c, sn = box[..., 2:3], box[..., 3:4]
    along = (d[..., 0] * c + d[..., 1] * sn).abs()
    across = (-d[..., 0] * sn + d[..., 1] * c).abs()
    g = grow.view(-1, 1, 1)
    inside = (along <= box[..., 4:5] + g) & (across <= box[..., 5:6] + g)
    on = (s["tr_active"] & ~s["tr_waiting"]).unsqueeze(-1)
    return inside & on


#: Per-episode outcome keys of :func:`drive` (the env's flags at the episode's end).
OUTCOMES = ("success", "collision", "jackknife", "truncated")
#: Final error keys of :func:`drive`: position [m], tractor and trailer heading [deg].
ERRORS = ("pos_error", "tractor_heading_error", "trailer_heading_error")


def drive(
    env_cfg: EnvConfig,
    states: TensorDict,
    difficulty: float,
    driver: RouteDriver | None = None,
    record: bool = True,
    act: Callable[[TensorDict], Tensor] | None = None,
) -> tuple[dict[str, Tensor], TensorDict | None]:
    """Drive ``states`` (``[E]`` network start states) through an eager env: with ``driver``,
    or with ``act`` where given (the driver then only labels).

    Args:
        act: ``act(td) -> [E, 2]`` actions in ``[-1, 1]`` from the env's tensordict
            (``observation``, ``lidar``), e.g. a policy's mean action; None: the driver drives.

    Returns:
        ``(result, samples)``: ``result`` ``[E]`` per episode: the :data:`OUTCOMES` (bool),
        the :data:`ERRORS` at its last step, ``steps`` and ``to_go`` (the route arc length [m]
        from the truck to the goal before its last step); ``samples`` ``[M]`` with
        "observation", "lidar" and the driver's "action" of every step: of every successful
        episode when the driver drives, of every episode when ``act`` does (None without
        ``record``).
    """
    driver = driver or RouteDriver()
    e = int(states.batch_size[0])
    cfg = dataclasses.replace(env_cfg, compile=False)
    env = TruckEnv(num_envs=e, config=cfg, seed=0)
    env.set_difficulty(difficulty)
    td = env.set_state(states.clone())
    alive = torch.ones(e, dtype=torch.bool)
    out = {k: torch.zeros(e, dtype=torch.bool) for k in OUTCOMES}
    err = {k: torch.zeros(e) for k in ERRORS}
    steps = torch.zeros(e, dtype=torch.long)
    to_go = torch.zeros(e)
    rows: list[tuple[Tensor, Tensor, Tensor, Tensor]] = []
    for _ in range(cfg.max_steps):
        s = env.get_state()
        label = setpoint_action(*driver.setpoints(s), s, cfg.control, cfg.dt)
        if record:
            rows.append((alive.clone(), td[OBS_KEY], td[LIDAR_KEY], label))
        action = label if act is None else act(td).clamp(-1.0, 1.0)
        nxt = env.step(td.set("action", action))["next"]
        done = nxt["done"].squeeze(-1)
        steps += alive.long()
        to_go = torch.where(alive, s["goal_s"] - s["route_s"], to_go)
        ending = alive & done
        for k in OUTCOMES:
            out[k] |= ending & nxt[k].squeeze(-1).bool()
        for k in ERRORS:
            err[k] = torch.where(ending, nxt[k].squeeze(-1), err[k])
        alive &= ~done
        td = nxt
        if not alive.any():
            break
    env.close()
    err["tractor_heading_error"] = err["tractor_heading_error"].rad2deg()
    err["trailer_heading_error"] = err["trailer_heading_error"].rad2deg()
    result = {**out, **err, "steps": steps, "to_go": to_go}
    if not record:
        return result, None
    samples = kept_samples(rows, out["success"] if act is None else torch.ones_like(alive))
    return result, samples


def demonstrations(
    env_cfg: EnvConfig, episodes: int, seed: int, difficulty: float
) -> tuple[Tensor, TensorDict]:
    """The expert's demonstrations (``demos.source=driver``): :func:`drive` on the ``episodes``
    held-out scenes of ``seed`` at ``difficulty`` (its curriculum level: route, traffic; and
    its tolerances for success).

    Returns:
        ``(solved [E] bool, samples [M])`` ("observation", "lidar", "action" of the solved
        scenes).
    """
    states = held_out_states(env_cfg, episodes, seed, "cpu", difficulty=difficulty)
    result, samples = drive(env_cfg, states, difficulty)
    return result["success"], samples


def labelled(
    env_cfg: EnvConfig,
    episodes: int,
    seed: int,
    difficulty: float,
    act: Callable[[TensorDict], Tensor],
) -> tuple[Tensor, TensorDict]:
    """The driver's labels on a policy's own states (``demos.dagger_rounds``): ``act`` drives
    the ``episodes`` held-out scenes of ``seed`` at ``difficulty`` (as :func:`drive`'s ``act``),
    and every state it visits, up to each episode's end, is kept with the driver's action.

    Returns:
        ``(solved [E] bool, samples [M])``: which episodes ``act`` solved, and "observation",
        "lidar" and the driver's "action" of every step of every episode.
    """
    states = held_out_states(env_cfg, episodes, seed, "cpu", difficulty=difficulty)
    result, samples = drive(env_cfg, states, difficulty, act=act)
    return result["success"], samples
