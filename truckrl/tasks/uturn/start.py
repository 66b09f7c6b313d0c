"""The uturn task's start curriculum (``env.task.start``): early in training the truck starts
part-way through the manoeuvre, on a reference path of its trailer axle that reverses from the
road past the branch into it (:class:`ReversePath`), or on the forward leg before it
(:func:`curriculum_start`, called by :meth:`truckrl.tasks.uturn.task.UTurnTask.on_reset`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.config.fields import param, validate
from truckrl.sim.collision import truck_collides, widened
from truckrl.sim.geometry import rotate, wrap_angle
from truckrl.sim.roads import uniform
from truckrl.sim.vehicle import truck_extents
from truckrl.tasks.uturn.scene import START_ARC, START_BRANCH, START_LEG, START_PAST, START_ROAD

if TYPE_CHECKING:
    from collections.abc import Callable

    from tensordict import TensorDict


@dataclass
class UTurnStartConfig:
    """Start curriculum (``env.task.start.*``; :func:`curriculum_start`): early in training the
    truck starts part-way through the manoeuvre, somewhere on a reference path of its trailer
    axle that reverses from the road past the branch into it."""

    enabled: bool = param(True, doc="false: every episode starts where the generator put it")
    stage_difficulty: tuple[float, float] = param(
        (0.0, 4.0),
        lo=0.0,
        hi=30.0,
        unit="-",
        doc="difficulties over which starts move from the end of the reference path (in the "
        "branch) back along it to the generator's road start (all, from the second on)",
    )
    branch_end_gap: tuple[float, float] = param(
        (0.5, 2.0),
        lo=0.0,
        hi=50.0,
        unit="m",
        doc="end of the path: the trailer's rear corners this far short of the branch end wall "
        "(drawn per episode)",
    )
    past_gap: tuple[float, float] = param(
        (1.0, 6.0),
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="start of the path: the trailer rear this far beyond the mouth's far chamfer (drawn "
        "per episode; at most the room before a dead end less 1 m)",
    )
    arc_radius: tuple[float, float] = param(
        (9.0, 13.0),
        lo=1.0,
        hi=100.0,
        unit="m",
        doc="radius of the path's arc from the road into the branch axis (drawn per episode)",
    )
    clearance: float = param(
        0.2,
        lo=0.0,
        hi=5.0,
        unit="m",
        doc="a start on the path keeps this much room to every segment, else it moves further "
        "along the path towards the branch",
    )

    def __post_init__(self) -> None:
        validate(self, "env.task.start")


def pulled_past(pose: Tensor, s: Mapping[str, Any]) -> Tensor:
    """``[N]`` bool: the tractor rear axle of ``pose [N, 4]`` is level with or beyond the pull
    point ``s["pull_point"]`` along the start heading ``s["start_heading"]``."""
    h = s["start_heading"]
    ahead = (pose[:, 0] - s["pull_point"][:, 0]) * h.cos() + (
        pose[:, 1] - s["pull_point"][:, 1]
    ) * h.sin()
    return ahead >= 0.0


@dataclass
class ReversePath:
    """The start curriculum's reference path of the trailer axle, per scene: built in the
    scene's local frame with the branch mirrored to the left (``side``), posed in the world
    through ``frame``.

    Three pieces by arc length: straight back along the road centreline from ``p0`` (motion
    heading ``road + pi``), an arc of radius ``radius`` turning onto the branch axis, then up
    the axis. ``arc_from`` / ``arc_to`` ``[N]`` are the path fractions where the arc starts and
    ends. :meth:`pose` gives the truck whose trailer axle is at a fraction: straight off the
    arc, in the steady turn on it.
    """

    p0: Tensor  # [N, 2] start of the path, local left-branch frame [m]
    back: Tensor  # [N] length of the straight piece [m]
    radius: Tensor  # [N] [m]
    turn: Tensor  # [N] signed turn of the motion heading over the arc [rad]
    up: Tensor  # [N] length along the branch axis [m]
    side: Tensor  # [N] +1 left branch, -1 right
    frame: Tensor  # [N, 3] mouth centre x, y and road heading (local -> world)
    trailer_wheelbase: Tensor  # [N] trailer axle to kingpin [m]
    kingpin_offset: Tensor  # [N] kingpin behind the tractor rear axle [m]
    max_phi: Tensor  # [N] articulation cap on the arc [rad]

    @property
    def length(self) -> Tensor:
        return self.back + self.radius * self.turn.abs() + self.up

    @property
    def arc_from(self) -> Tensor:
        return self.back / self.length

    @property
    def arc_to(self) -> Tensor:
        return (self.back + self.radius * self.turn.abs()) / self.length

    def pose(self, sigma: Tensor) -> Tensor:
        """``[N, 4]`` world pose ``(x, y, theta, phi)`` of the truck whose trailer axle is at path
        fraction ``sigma [N]``, the trailer facing against the direction of travel along the
        path: articulation 0 off the arc, the steady turn (capped at ``max_phi``) on it."""
        s = sigma * self.length
        arc_len = self.radius * self.turn.abs()
        # left-branch local frame (right branches mirrored by side at the end)
        s1 = s.clamp(max=self.back)
        s2 = (s - self.back).clamp(0.0, None).minimum(arc_len)
        s3 = (s - self.back - arc_len).clamp(0.0, None)
        a0 = torch.full_like(s, math.pi)  # motion heading on the straight piece
        start_arc = self.p0 + torch.stack((-self.back, torch.zeros_like(s)), -1)
        frac = s2 / arc_len.clamp_min(1e-6)
        ang = a0 + self.turn * frac  # motion heading on the arc (turn < 0: clockwise)
        centre = start_arc + self.radius[:, None] * torch.stack(
            (torch.zeros_like(s), torch.ones_like(s)), -1
        )
        on_arc = centre + self.radius[:, None] * torch.stack((-ang.sin(), ang.cos()), -1)
        end_ang = a0 + self.turn
        up_dir = torch.stack((end_ang.cos(), end_ang.sin()), -1)
        xy = torch.where(
            (s <= self.back)[:, None],
            self.p0 + torch.stack((-s1, torch.zeros_like(s)), -1),
            on_arc + s3[:, None] * up_dir,
        )
        motion = torch.where(s <= self.back, a0, torch.where(s3 > 0, end_ang, ang))
        psi = motion + math.pi  # the trailer faces against its travel (reversing)
        # tractor: straight behind the hitch off the arc; on the arc the steady turn, every
        # axle circling the arc's centre C, so the rear axle X = K + a u(theta) (K the kingpin)
        # moves perpendicular to X - C: (K - C) . u(theta) = -a
        u_psi = torch.stack((psi.cos(), psi.sin()), -1)
        kingpin = xy + self.trailer_wheelbase[:, None] * u_psi
        rel = kingpin - centre
        beta = torch.atan2(rel[:, 1], rel[:, 0])
        spread = torch.acos((-self.kingpin_offset / rel.norm(dim=-1)).clamp(-1.0, 1.0))
        t1, t2 = beta + spread, beta - spread
        near = wrap_angle(t1 - psi).abs() <= wrap_angle(t2 - psi).abs()
        steady = torch.where(near, t1, t2)
        phi = wrap_angle(psi - steady).clamp(-self.max_phi, self.max_phi)
        phi = torch.where((s > self.back) & (s3 <= 0), phi, torch.zeros_like(phi))
        theta = psi - phi
        axle = kingpin + self.kingpin_offset[:, None] * torch.stack((theta.cos(), theta.sin()), -1)
        local_xy = torch.stack((axle[:, 0], self.side * axle[:, 1]), -1)
        world = rotate(local_xy, self.frame[:, 2]) + self.frame[:, :2]
        h = wrap_angle(self.side * theta + self.frame[:, 2])
        return torch.stack((world[:, 0], world[:, 1], h, self.side * phi), -1)


#: Cap of the steady-turn articulation of a start on the arc, as a share of ``max_articulation``
#: (a start at the stop would be a jack-knife at step 0).
ARC_ARTICULATION = 0.8


def reverse_path(
    info: Mapping[str, Tensor], params: Mapping[str, Tensor], cur: UTurnStartConfig
) -> ReversePath:
    """The start curriculum's :class:`ReversePath` of each scene (:func:`curriculum_start`):
    ``place_draw`` fixes the arc radius, the past-branch gap and the branch end gap."""
    front, rear, half_w = truck_extents(params)
    l_axle = params["kingpin_offset"] + params["trailer_wheelbase"]  # rear axle to trailer axle
    overhang = rear - l_axle  # trailer axle to the trailer rear
    a, half = info["branch_angle"], 0.5 * info["road_width"]
    sin_a, cos_a = a.sin(), a.cos()
    place = info["place_draw"]

    # start: trailer rear past_gap beyond the far chamfer's foot, the front 1 m short of x_far
    rear_x = 0.5 * info["branch_width"] / sin_a + info["mouth_chamfer"]
    room = info["x_far"] - rear_x - (front + rear) - 1.0
    gap = torch.minimum(uniform(cur.past_gap, place), room).clamp_min(0.0)
    x0 = rear_x + gap + overhang  # the trailer axle
    # arc (left-branch frame): motion heading pi -> a, clockwise by pi - a, from (x_arc, 0)
    radius = uniform(cur.arc_radius, place)
    turn = a - math.pi
    dy = radius * (1.0 - torch.cos(turn))
    x_end = (dy - half) * cos_a / sin_a  # the arc ends on the branch axis
    x_arc = x_end - radius * torch.sin(turn)
    back = (x0 - x_arc).clamp_min(0.0)
    p0 = torch.stack((torch.maximum(x0, x_arc), torch.zeros_like(x0)), -1)
    # end: the trailer's rear corners branch_end_gap short of the end wall, which runs along
    # the road: on the axis at angle a the deeper corner lies half_w |cos a| deeper (across
    # the road) than the rear's centre
    skew = half_w * cos_a.abs()
    depth_axle = (
        info["branch_depth"] - uniform(cur.branch_end_gap, place) - skew
    ) / sin_a - overhang
    up = (depth_axle - (dy - half) / sin_a).clamp_min(0.0)
    frame = torch.stack((info["mouth_x"], info["mouth_y"], info["road_heading"]), -1)
    return ReversePath(
        p0,
        back,
        radius,
        turn,
        up,
        info["branch_side"],
        frame,
        params["trailer_wheelbase"],
        params["kingpin_offset"],
        ARC_ARTICULATION * params["max_articulation"],
    )


def first_free_on_path(
    path: ReversePath, sigma: Tensor, state: TensorDict, clearance: float
) -> tuple[Tensor, Tensor, Tensor]:
    """The first free start on ``path`` at or after fraction ``sigma [N]``: the drawn fraction,
    then eight evenly spaced on to 1; free where the truck widened by ``clearance`` [m] touches
    no segment of ``state``.

    Returns:
        ``any_free [N]`` (bool), the first free pose ``[N, 4]`` and its fraction ``[N]`` (the
        drawn candidate where none is free).
    """
    pose, params = state["pose"], state["params"]
    k = 9  # the drawn sigma, then evenly on to 1
    steps = torch.linspace(0.0, 1.0, k, device=pose.device)
    sig = sigma[None] + (1.0 - sigma[None]) * steps[:, None]  # [k, m]
    cand = torch.stack([path.pose(sg) for sg in sig.unbind(0)])  # [k, m, 4]
    wide = widened(params, clearance)
    m = pose.shape[0]
    hit = truck_collides(
        cand.reshape(k * m, 4),
        {key: v.repeat(k) for key, v in wide.items()},
        state["segments"].repeat(k, 1, 1),
        state["mask"].repeat(k, 1),
    ).view(k, m)
    free = ~hit
    first = free.to(torch.int8).argmax(0)  # first free candidate [m]
    moved = cand.gather(0, first.view(1, m, 1).expand(1, m, 4))[0]
    sigma = sig.gather(0, first.view(1, m))[0]
    return free.any(0), moved, sigma


def curriculum_start(
    state: TensorDict,
    info: TensorDict,
    difficulty: Tensor,
    cur: UTurnStartConfig,
    errors: Callable[[TensorDict], dict[str, Tensor]],
) -> TensorDict:
    """The start curriculum (``env.task.start``) applied to ``state`` in place, at each
    episode's ``difficulty [N]``, with the scene metadata ``info`` (``state["route"]``) and the
    task's ``errors`` (recomputed for moved starts).

    **The reference path** (:func:`reverse_path`) of the trailer axle: from a pose on the
    road centreline past the branch (the trailer rear ``past_gap`` beyond the mouth's far
    chamfer), straight back, an arc of ``arc_radius`` onto the branch axis, and up the axis
    until the trailer's rear corners are ``branch_end_gap`` short of the end wall. A start at
    path fraction ``sigma`` (by arc length) is the truck at rest with its trailer axle there,
    the trailer facing against the direction of travel along the path (on the road at
    ``sigma = 0`` it faces the start heading, at ``sigma = 1`` out of the branch); straight
    off the arc, and on the arc articulated as in the steady turn round the arc's centre
    (capped at :data:`ARC_ARTICULATION` of ``max_articulation``).

    **The forward leg** before it: from the road start, straight ahead to the pull point
    ``P`` (the tractor rear axle of the path's first pose), where the truck has pulled far
    enough past the branch to reverse into it.

    **The schedule.** With ``p = clamp((d - d0) / (d1 - d0), 0, 1)`` at difficulty ``d``
    (``stage_difficulty = (d0, d1)``) and the episode's ``stage_draw`` ``r``,
    ``z = 3 p + r``: where ``z < 2`` the truck starts on the path at ``sigma = 1 - z / 2``;
    where ``2 <= z < 3`` on the forward leg, at rest facing the start heading, ``z - 2`` of
    the way from ``P`` back to the road start; otherwise at the generator's road start. So
    difficulty ``d0`` draws ``sigma`` in ``(1/2, 1]``, the window slides back along the
    path and the leg, and from ``d1`` on every start is the road start.

    **Free by test.** A path start whose truck, widened by ``clearance``, touches a segment
    moves on along the path (eight evenly spaced fallbacks to ``sigma = 1``; where none is
    free, the road start). The end pose, straight on the branch axis with
    ``branch_side_clearance`` each side, is free in every default scene. The tests check
    every kind of start on 10,000 scenes with independent geometry.

    ``start_heading`` (route shaping's ``theta_0``) keeps the road heading, so the shaping
    is one potential for every start; ``pulled`` is 1 on the path and on the leg from ``P``
    on. ``info["start_kind"]`` records road / past branch / on the arc / in the branch /
    pulling past (:data:`~truckrl.tasks.uturn.scene.START_ROAD` ...) and
    ``info["start_sigma"]`` the path fraction (on the leg minus its fraction, -1 on the
    road).
    """
    pose, params = state["pose"], state["params"]
    d = difficulty.to(pose.dtype)
    d0, d1 = cur.stage_difficulty
    prog = ((d - d0) / (d1 - d0)).clamp(0.0, 1.0) if d1 > d0 else (d >= d0).to(d)
    z = 3.0 * prog + info["stage_draw"]
    on_path = z < 2.0
    on_leg = (z >= 2.0) & (z < 3.0)
    sigma = (1.0 - 0.5 * z).clamp(0.0, 1.0)

    path = reverse_path(info, params, cur)
    free_any, moved, sigma = first_free_on_path(path, sigma, state, cur.clearance)
    on_path = on_path & free_any  # none free (never seen): the road start
    # the forward leg: straight, facing the start heading, (z - 2) of the way from P back
    # to the road start (both on the straight road, the truck in its half: free)
    frac = (z - 2.0).clamp(0.0, 1.0)
    pp = state["pull_point"]
    leg_xy = pp + frac[:, None] * (pose[:, :2] - pp)
    leg = torch.cat((leg_xy, pose[:, 2:3], torch.zeros_like(frac)[:, None]), -1)

    new_pose = torch.where(on_path[:, None], moved, torch.where(on_leg[:, None], leg, pose))
    state["pose"] = new_pose
    state.update(errors(state))
    state["pulled"] = (on_path | pulled_past(new_pose, state)).to(state["pulled"])
    kind = torch.where(
        sigma < path.arc_from,
        START_PAST,
        torch.where(sigma < path.arc_to, START_ARC, START_BRANCH),
    )
    kind = torch.where(on_path, kind, torch.where(on_leg, START_LEG, START_ROAD))
    info["start_kind"] = kind.to(info["start_kind"])
    info["start_sigma"] = torch.where(on_path, sigma, torch.where(on_leg, -frac, -1.0))
    return state
