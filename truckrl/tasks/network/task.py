"""Task ``network``: drive an articulated truck along a route through a road network's junctions,
among moving traffic, to a goal pose.

* Episodes: :func:`truckrl.tasks.network.scene.generate_episodes` (a chain of link and junction
  blocks from :mod:`truckrl.sim.network`, the route along it, start options and the goal on its
  lane centre-lines, traffic spawned clear of them; rules in that module).
* Curriculum (:meth:`NetworkTask.on_reset`, ``env.task.curriculum``): the level of a difficulty
  picks how many junctions the route passes (the start moves to the link ``L_{J-j}``; the blocks
  behind it are taken out of the scene: their curbs masked, their vehicles and junction zones
  removed, lanes into them end there) and what share of the spawned vehicles drives. The
  tolerances shrink with difficulty as in every task (``30 m * 2**-d``, ``60 deg * 2**-d``).
* Traffic (:mod:`truckrl.sim.network.traffic`) moves in :meth:`NetworkTask.step`, after the
  truck, with the truck's tractor and trailer as obstacles; the vehicles' outlines are appended
  to the scene's curbs where :meth:`~truckrl.tasks.base.Task.outcome` (collision) and
  :meth:`~truckrl.tasks.base.Task.scan` (LiDAR) read them, both unchanged: touching a vehicle is
  a collision.
* Errors and success: the goal pose's (:mod:`truckrl.tasks.goals`): tractor rear-axle position
  [m], tractor and trailer heading [rad], within the tolerances, without collision or jack-knife.
* Reward: the paper's terms and weights (+0.05 per metre of progress, +0.5 per radian of tractor
  and of trailer heading correction, +5 success, -7 collision or jack-knife, -8 timeout) with
  progress measured along the route: the distance to go is the route arc length from the
  truck's projection on the route to the goal's, plus the truck's distance from the route, and
  the heading terms are measured to the route's heading at the projection (the goal heading at
  the goal). Potential-based, as the intersection task's ``route`` shaping.
* Observation extras (``2 route.ahead + 6 tracks``): the route points ``spacing, 2 spacing,
  ...`` metres of arc length ahead of the truck's projection (held at the goal), in the tractor
  frame, over the sensor scale (50 m); then the ``tracks`` nearest vehicles within the LiDAR's
  range (:func:`observe_tracks`: present, position, heading and speed in the tractor frame), as
  an object tracker would report them. The LiDAR alone shows where a vehicle is, not where it
  is going: a truck that must cross a lane needs the speed of what comes along it.
* Evaluation bins (:mod:`truckrl.tasks.network.bins`): block types on the route, junctions,
  traffic density, turn directions.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from truckrl.config.fields import ConfigError, param, validate
from truckrl.sim.geometry import to_local, wrap_angle
from truckrl.sim.network.config import BLOCK_NAMES, ROUNDABOUT, NetworkConfig
from truckrl.sim.network.traffic import (
    Traffic,
    TrafficConfig,
    ego_boxes,
    lane_points,
    step_traffic,
    traffic_segments,
)
from truckrl.sim.vehicle import truck_boxes
from truckrl.tasks.base import Task
from truckrl.tasks.config import SENSOR_SCALE, TaskConfig
from truckrl.tasks.goals import PoseGoal, PoseRewardConfig, pose_reward_terms
from truckrl.tasks.network.bins import network_bins
from truckrl.tasks.network.scene import (
    INFO_KEYS,
    STRAIGHT_TURN,
    TRAFFIC_FIELDS,
    WINDOW_DTYPE,
    CurriculumConfig,
    NetworkSceneConfig,
    RouteConfig,
    chunk_pieces,
    generate_episodes,
    point_at,
    route_cumulative,
)

if TYPE_CHECKING:
    from tensordict import TensorDict

    from truckrl.tasks.config import EnvConfig

#: State key of the per-episode scene metadata (:data:`~truckrl.tasks.network.scene.INFO_KEYS`).
INFO_STATE_KEY = "route"
#: State keys of the traffic (``tr_`` + :data:`~truckrl.tasks.network.scene.TRAFFIC_FIELDS`).
TRAFFIC_KEYS: tuple[str, ...] = tuple(f"tr_{f}" for f in TRAFFIC_FIELDS)
#: Route state keys: ``route_points [N, R, 2]`` and ``route_cum [N, R]`` (the resampled route
#: and its arc length [m]), ``goal_s [N]`` (the goal's arc length [m]) and, updated every step,
#: ``route_s``, ``route_to_go`` [m], ``route_heading`` [rad] and ``route_chunk`` (long: the
#: stretch of the route, :func:`~truckrl.tasks.network.scene.route_windows`) of the truck's
#: projection.
ROUTE_KEYS: tuple[str, ...] = (
    "route_points",
    "route_cum",
    "goal_s",
    "route_s",
    "route_to_go",
    "route_heading",
    "route_chunk",
)
#: Key that marks a state dict whose ``segments`` and ``mask`` already hold the scene the
#: collision test and the LiDAR read (:meth:`NetworkTask.sensed`); never a state entry.
SENSED = "sensed"
#: Curb window state keys: each route stretch's window ``window [N, C, W]`` (int32 slots of the
#: scene's ``segments``: :data:`~truckrl.tasks.network.scene.WINDOW_DTYPE`) and
#: ``window_valid [N, C, W]``; the step's LiDAR and collision read the window of the truck's
#: stretch instead of every curb of the chain (the env hands the step the scene's slots as they
#: are: :attr:`NetworkTask.compact_scene`). Invariant: a valid slot holds a curb of ``mask``
#: (:meth:`NetworkTask.on_reset` folds the curriculum's cut into both), so the step reads one
#: mask instead of gathering ``mask`` through the window for every LiDAR beam.
WINDOW_KEYS: tuple[str, ...] = ("window", "window_valid")


def _default(cls: type, name: str) -> Any:
    f = next(f for f in fields(cls) if f.name == name)
    return f.default


@dataclass
class TaskNetworkConfig(NetworkConfig):
    """The chain's blocks as :class:`~truckrl.sim.network.config.NetworkConfig` draws them, with
    the network task's own defaults for two fields (a partial override keeps the others)."""

    #: the step's LiDAR and collision cost grows with the curbs in reach: a roundabout holds
    #: 116 curbs at 5 cm, 64 at 20 cm (docs/networks.md, "The network task")
    chord_error: float = param(
        0.2, lo=1e-4, hi=1.0, unit="m", doc="largest gap between an arc and its polyline"
    )
    #: a rig turning right round a junction's sharp curb corner sweeps more than its lane, and
    #: on the sim's narrower roads it cannot (docs/networks.md, "A scripted driver")
    road_width: tuple[float, float] = param(
        (12.0, 18.0), lo=2.0, hi=40.0, unit="m", doc="road width, curb to curb (two lanes)"
    )


@dataclass
class NetworkTaskConfig(TaskConfig):
    """Config of the network task: chain, route, traffic, curriculum and reward weights."""

    name: str = param("network", choices=("network",), doc="task folder")
    scene: NetworkSceneConfig = field(default_factory=NetworkSceneConfig)
    network: TaskNetworkConfig = field(default_factory=lambda: TaskNetworkConfig())
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    route: RouteConfig = field(default_factory=RouteConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    reward: PoseRewardConfig = field(default_factory=PoseRewardConfig)
    tracks: int = param(
        4, lo=0, hi=64, unit="-",
        doc="nearest vehicles observed (present, x, y, cos and sin of heading, speed; 6 each)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate(self, "env.task")
        blocks = self.network.num_blocks
        if tuple(blocks) != tuple(_default(NetworkConfig, "num_blocks")):
            k = 2 * self.curriculum.max_junctions + 1
            raise ConfigError(
                f"env.task.network.num_blocks = {list(blocks)}: not read by the network task, "
                f"whose chain has 2 max(curriculum.junctions) + 1 = {k} blocks"
            )


class NetworkTask(PoseGoal, Task):
    """A route through a network's junctions among traffic; see the module docstring."""

    name = "network"
    config_class = NetworkTaskConfig
    #: a refill draws its chains, routes and traffic in one batch whose rounds of small tensor
    #: ops are shared by all its episodes: the draw is the reset's largest cost, and a bigger
    #: batch costs less per episode (docs/networks.md, "Speed")
    episode_pool = 1024
    #: the step senses its curb windows, which index the scene's slots (WINDOW_KEYS)
    compact_scene = False
    extra_state_keys = (*TRAFFIC_KEYS, *ROUTE_KEYS, *WINDOW_KEYS)

    @classmethod
    def category_bins(cls, info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]] | None:
        """Block types, junctions, traffic and turns (:func:`~truckrl.tasks.network.bins.network_bins`)."""
        return network_bins(info)

    def __init__(self, cfg: EnvConfig) -> None:
        super().__init__(cfg)
        task = cfg.task
        self.num_extras = 2 * task.route.ahead + TRACK_FEATURES * task.tracks
        self.levels = task.curriculum.starts
        self.max_junctions = task.curriculum.max_junctions
        self._thresholds = torch.tensor(task.curriculum.difficulty)
        self._junctions = torch.tensor(task.curriculum.junctions)
        self._share = torch.tensor(task.curriculum.traffic)
        self._ahead = task.route.spacing * torch.arange(1, task.route.ahead + 1)

    def to(self, device: torch.device | str) -> NetworkTask:
        super().to(device)
        self._thresholds = self._thresholds.to(device)
        self._junctions = self._junctions.to(device)
        self._share = self._share.to(device)
        self._ahead = self._ahead.to(device)
        return self

    # ------------------------------------------------------------------ episodes
    def sample(self, m: int, rng: torch.Generator, device: torch.device) -> TensorDict:
        """``m`` episodes on the whole chain (the start on ``L_0``, every spawned vehicle);
        :meth:`on_reset` applies the curriculum level."""
        return self._episodes(self.sample_params(m, rng, device), rng, device)

    def level(self, difficulty: float) -> int:
        """The curriculum level of ``difficulty`` as :meth:`on_reset` finds it (in float32)."""
        d = np.float32(difficulty)
        return sum(bool(d >= np.float32(t)) for t in self.cfg.task.curriculum.difficulty) - 1

    def keeps_vehicles(self, level: int) -> bool:
        """Whether curriculum level ``level`` keeps any spawned vehicle."""
        return (
            self.cfg.task.curriculum.traffic[level] > 0.0 and self.cfg.task.traffic.max_vehicles > 0
        )

    def draw_key(self, difficulty: float) -> int:
        """The curriculum level: a pool's refill searches that level's start alone and places
        vehicles only where it keeps some (:meth:`sample_pool`)."""
        return self.level(difficulty)

    def sample_pool(
        self,
        m: int,
        rng: torch.Generator,
        device: torch.device,
        key: int,
        carry: dict[str, Tensor] | None,
    ) -> tuple[TensorDict, dict[str, Tensor] | None]:
        """A refill of episodes that start at the curriculum level ``key``: ``m`` trucks (those
        ``carry`` hands over first, then new ones; every carried one where they are more) each
        get one chain, and the episodes that pass the feasibility rule are kept; the trucks of
        the others go to the next refill, which draws them a new chain. Each truck so still
        gets the first chain of its own that passes, as in :meth:`sample`, whose further redraw
        rounds cost about as much as the first for a tenth of the rows; only where fewer than
        half pass do the rounds go on.

        Only level ``key``'s start is searched (the other levels get their link's start
        option, which is not their start), and no vehicle is placed where that level keeps
        none; vehicles keep clear of this level's start, the start options and the goal, not
        of the other levels' starts. So the episodes start only at that level."""
        carried = 0 if carry is None else next(iter(carry.values())).shape[0]
        fresh = self.sample_params(max(0, m - carried), rng, device)
        params = fresh if carry is None else {k: torch.cat((carry[k], v)) for k, v in fresh.items()}
        vehicles = self.keeps_vehicles(key)
        settle = max(1, max(m, carried) // 2)
        state = self._episodes(params, rng, device, key, vehicles, settle=settle)
        ok = state[INFO_STATE_KEY, "feasible"] > 0.5
        if int(ok.sum()) < settle:  # the rounds ran out: every row, the failing ones marked
            return state, None
        left = (~ok).nonzero().squeeze(-1)
        carry = {k: v[left] for k, v in params.items()} if left.numel() else None
        return state[ok], carry

    def _episodes(
        self,
        params: dict[str, Tensor],
        rng: torch.Generator,
        device: torch.device,
        level: int | None = None,
        vehicles: bool = True,
        settle: int | None = None,
    ) -> TensorDict:
        """Episodes for the trucks ``params`` (:func:`generate_episodes` with the arguments)."""
        from tensordict import TensorDict

        task = self.cfg.task
        m = next(iter(params.values())).shape[0]
        reach = self.cfg.lidar.max_range + task.scene.window_slack
        ch = generate_episodes(
            task.scene, task.network, task.traffic, task.route, self.levels, params, rng, device,
            reach, level, vehicles, settle,
        )  # fmt: skip
        net, tr = ch.network, ch.traffic
        scene = {
            "start": ch.start_options[:, 0],
            "goal": ch.goal,
            "segments": net.segments,
            "mask": net.mask,
            "kind": net.kind,
        }
        state = self.initial_state(params, scene, device)
        for f in TRAFFIC_FIELDS:
            state[f"tr_{f}"] = getattr(tr, f)
        state["route_points"] = ch.route_points
        state["route_cum"] = ch.route_cum
        state["window"] = ch.window
        state["window_valid"] = ch.window_valid
        # the curriculum's inputs (read by on_reset only)
        state["segment_block"] = net.segment_block
        state["block_type"] = net.block_type
        state["junction_turn"] = ch.turn
        state["start_options"] = ch.start_options
        state["level_starts"] = ch.level_starts
        state["level_blocks"] = ch.level_blocks
        state["level_past"] = ch.level_past
        state["keep_draw"] = ch.keep_draw
        state = self.complete_state(state)
        info = route_info(state, torch.zeros(m, dtype=torch.long, device=device))
        info["level"] = torch.full((m,), -1.0, device=device)
        info["feasible"] = ch.feasible.float()
        state[INFO_STATE_KEY] = TensorDict(info, batch_size=[m], device=device)
        return state

    def complete_state(self, state: TensorDict) -> TensorDict:
        """Add missing traffic (none: every slot empty) and route keys (a straight route from
        the current pose to the goal), and the truck's projection on the route."""
        keys = state.keys()
        n, dev = state["pose"].shape[0], state["pose"].device
        if "tr_lanes" not in keys:
            for k, v in empty_traffic(n, self.cfg.task.traffic.max_vehicles, dev).items():
                state[k] = v
        if "window" not in keys:  # one window: every curb
            e = state["segments"].shape[1]
            slots = torch.arange(e, dtype=WINDOW_DTYPE, device=dev)
            state["window"] = slots.expand(n, 1, e).clone()
            state["window_valid"] = state["mask"].unsqueeze(1).clone()
        if "route_points" not in keys:
            f = torch.linspace(0.0, 1.0, self.cfg.task.route.points, device=dev).view(1, -1, 1)
            a, b = state["pose"][:, None, :2], state["goal"][:, None, :2]
            state["route_points"] = a + f * (b - a)
            state["route_cum"] = route_cumulative(state["route_points"])
        if "goal_s" not in keys:
            goal = state["goal"]
            state["goal_s"] = project(state["route_points"], state["route_cum"], goal)[0]
        if "route_s" not in keys:
            for k, v in route_state(state).items():
                state[k] = v
        return state

    def idle_keys(self, difficulty: float) -> tuple[str, ...]:
        """The traffic's keys where the curriculum level of ``difficulty`` keeps no vehicle
        (:meth:`on_reset` then deactivates every one, and a step would leave them as they
        are); else none. The level as :meth:`on_reset` finds it, in float32."""
        return () if self.keeps_vehicles(self.level(difficulty)) else TRAFFIC_KEYS

    def on_reset(self, state: TensorDict, difficulty: Tensor) -> TensorDict:
        """The curriculum level of each episode's difficulty (module doc); a state without the
        curriculum's inputs (built by hand) is returned unchanged."""
        if "start_options" not in state.keys():
            return state
        level = (difficulty.unsqueeze(-1) >= self._thresholds).sum(-1) - 1
        rows = torch.arange(level.shape[0], device=level.device)
        first_block = state["level_blocks"][rows, level]
        start = state["level_starts"][rows, level]
        state["pose"] = torch.cat((start, torch.zeros_like(start[:, :1])), -1)
        state["mask"] = state["mask"] & (state["segment_block"] >= first_block.unsqueeze(-1))
        window = state["window"]
        cut = state["mask"].gather(1, window.flatten(1)).view_as(window)
        state["window_valid"] = state["window_valid"] & cut
        K = state["block_type"].shape[1]
        lanes_per_block = state["tr_lanes"].shape[1] // K
        fb = first_block.unsqueeze(-1)
        home_block = state["tr_home"] // lanes_per_block
        keep = state["keep_draw"] < self._share[level].unsqueeze(-1)
        state["tr_active"] = state["tr_active"] & (home_block >= fb) & keep
        succ = state["tr_successor"]
        cut = (succ >= 0) & (succ // lanes_per_block < fb)
        state["tr_successor"] = torch.where(cut, -1, succ)
        blocks = torch.arange(K, device=level.device)
        state["tr_zone_mask"] = state["tr_zone_mask"] & (blocks >= fb)
        state.update(self.errors(state))
        for k, v in route_state(state).items():
            state[k] = v
        info = route_info(state, first_block, state["level_past"][rows, level])
        info["level"] = level.float()
        del info["feasible"]  # the draw's verdict on the chain, whatever the level
        for k, v in info.items():
            state[INFO_STATE_KEY, k] = v
        return state

    # ------------------------------------------------------------------ step
    def step(self, s: dict[str, Any], action: Tensor) -> dict[str, Tensor]:
        """The shared step, then the traffic (with the truck's new boxes as obstacles) and the
        truck's projection on the route."""
        new = super().step(s, action)
        if TRAFFIC_KEYS[0] not in s:  # no vehicle anywhere: left out (idle_keys)
            new.update(route_state({**s, "pose": new["pose"]}))
            return new
        tractor, trailer, _ = truck_boxes(new["pose"], s["params"])
        traffic = step_traffic(
            traffic_of(s), self.cfg.task.traffic, self.cfg.dt, ego_boxes(tractor, trailer)
        )
        for f in ("lane", "s", "v", "waiting"):
            new[f"tr_{f}"] = getattr(traffic, f)
        new.update(route_state({**s, "pose": new["pose"]}))
        return new

    def sensed(self, s: dict[str, Any]) -> dict[str, Any]:
        """``s`` with ``segments`` and ``mask`` the curbs of the truck's route stretch (its
        window) and the vehicles' outlines (:data:`SENSED` marks it; a marked ``s`` is returned
        as it is, so the step assembles this scene once for the collision test and the
        LiDAR)."""
        if SENSED in s:
            return s
        window, valid = s["window"], s["window_valid"]
        n, _, w = window.shape
        at = s["route_chunk"].view(n, 1, 1).expand(n, 1, w)
        idx = window.gather(1, at).squeeze(1)  # [n, w] curb slots
        curbs = s["segments"].gather(1, idx.unsqueeze(-1).expand(n, w, 4))
        curb_mask = valid.gather(1, at).squeeze(1)  # mask folded in (WINDOW_KEYS)
        if TRAFFIC_KEYS[0] in s:  # else no vehicle anywhere (idle_keys): the curbs alone
            seg, mask = traffic_segments(traffic_of(s))
            curbs, curb_mask = torch.cat((curbs, seg), 1), torch.cat((curb_mask, mask), 1)
        return {**s, "segments": curbs, "mask": curb_mask, SENSED: True}

    def outcome(self, s: dict[str, Any], difficulty: Tensor) -> dict[str, Tensor]:
        """The shared outcome on the scene with the vehicles in it (touching one collides)."""
        return super().outcome(self.sensed(s), difficulty)

    def scan(self, s: dict[str, Any]) -> Tensor:
        """The shared LiDAR on the scene with the vehicles in it."""
        return super().scan(self.sensed(s))

    def reward_terms(
        self, before: dict[str, Any], after: dict[str, Any], flags: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        """The paper's terms on the route's distance to go and heading (module doc)."""
        return pose_reward_terms(
            self.cfg.task.reward, route_errors(before), route_errors(after), flags
        )

    def observation_extras(self, s: dict[str, Any]) -> Tensor:
        """``[N, 2 ahead + 6 tracks]``: the route points ahead (module doc), x and y of each in
        turn, then the nearest vehicles (:func:`observe_tracks`)."""
        pose = s["pose"]
        query = (s["route_s"].unsqueeze(-1) + self._ahead).minimum(s["goal_s"].unsqueeze(-1))
        xy, _ = point_at(s["route_points"], s["route_cum"], query)
        route = (to_local(xy, pose[:, :2], pose[:, 2]) / SENSOR_SCALE).flatten(1)
        k = self.cfg.task.tracks
        if k == 0:
            return route
        if TRAFFIC_KEYS[0] not in s:  # no vehicle anywhere (idle_keys): every track absent
            return torch.cat((route, route.new_zeros(route.shape[0], TRACK_FEATURES * k)), 1)
        tracks = observe_tracks(traffic_of(s), pose, k, self.cfg.lidar.max_range)
        return torch.cat((route, tracks), 1)


# ---------------------------------------------------------------------------------- helpers
def traffic_of(s: Mapping[str, Any]) -> Traffic:
    """The :class:`~truckrl.sim.network.traffic.Traffic` held in a state's ``tr_`` keys."""
    return Traffic(**{f: s[f"tr_{f}"] for f in TRAFFIC_FIELDS})


#: Observed features per track: present (1, else 0 and the rest 0), x and y in the tractor
#: frame over SENSOR_SCALE, cosine and sine of the heading relative to the tractor's, and the
#: speed over TRACK_SPEED_SCALE.
TRACK_FEATURES = 6
#: Speed scale of the tracks [m/s]: the traffic's desired speeds are of this order (5-12 m/s).
TRACK_SPEED_SCALE = 10.0


def observe_tracks(traffic: Traffic, pose: Tensor, k: int, reach: float) -> Tensor:
    """The ``k`` vehicles nearest the tractor's reference point ``pose[:, :2]`` (centre to
    point, those on the road within ``reach`` [m]), nearest first, as ``[N, 6 k]``
    (:data:`TRACK_FEATURES` each, zeros where fewer are in reach)."""
    xy, heading = lane_points(traffic, traffic.lane, traffic.s)  # [N, M, 2], [N, M]
    local = to_local(xy, pose[:, :2], pose[:, 2])
    dist = local.norm(dim=-1)
    seen = traffic.present() & (dist < reach)
    n, m = dist.shape
    j = min(k, m)
    order = dist.masked_fill(~seen, math.inf).topk(j, dim=1, largest=False).indices  # [N, j]
    rel = heading - pose[:, 2:3]
    feats = torch.stack(
        (
            seen.float(),
            local[..., 0] / SENSOR_SCALE,
            local[..., 1] / SENSOR_SCALE,
            torch.cos(rel),
            torch.sin(rel),
            traffic.v / TRACK_SPEED_SCALE,
        ),
        -1,
    ) * seen.unsqueeze(-1)  # [N, M, 6]
    out = feats.gather(1, order.unsqueeze(-1).expand(n, j, TRACK_FEATURES))
    if j < k:
        out = torch.cat((out, out.new_zeros(n, k - j, TRACK_FEATURES)), 1)
    return out.flatten(1)


def empty_traffic(n: int, m: int, device) -> dict[str, Tensor]:
    """``tr_`` state entries of ``n`` scenes without lanes or vehicles (``m`` empty slots)."""
    z = torch.zeros(n, m, device=device)
    zl = torch.zeros(n, m, dtype=torch.long, device=device)
    no = torch.zeros(n, m, dtype=torch.bool, device=device)
    out = {
        "lanes": torch.zeros(n, 1, 2, 2, device=device),
        "cum": torch.zeros(n, 1, 2, device=device),
        "lane_len": torch.zeros(n, 1, device=device),
        "pieces": torch.zeros(n, 1, dtype=torch.long, device=device),
        "successor": torch.full((n, 1), -1, dtype=torch.long, device=device),
        "zone_centre": torch.zeros(n, 1, 2, device=device),
        "zone_radius": torch.zeros(n, 1, device=device),
        "zone_mask": torch.zeros(n, 1, dtype=torch.bool, device=device),
        "lane": zl,
        "home": zl.clone(),
        "s": z,
        "v": z.clone(),
        "v0": z + 1.0,
        "length": z + 1.0,
        "width": z + 1.0,
        "truck": no,
        "active": no.clone(),
        "waiting": no.clone(),
    }
    return {f"tr_{k}": v for k, v in out.items()}


def project(points: Tensor, cum: Tensor, pose: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The nearest point of route polylines ``points [N, R, 2]`` (arc lengths ``cum [N, R]``)
    to ``pose[:, :2]``: its arc length [m], the distance to it [m], the heading of its piece
    [rad] and the piece's index (long), each ``[N]``."""
    a, b = points[:, :-1], points[:, 1:]
    ab = b - a
    length2 = (ab * ab).sum(-1).clamp_min(1e-12)
    rel = pose[:, None, :2] - a
    t = ((rel * ab).sum(-1) / length2).clamp(0.0, 1.0)
    gap = rel - t.unsqueeze(-1) * ab
    d2 = (gap * gap).sum(-1)
    i = d2.argmin(-1, keepdim=True)
    t_i = t.gather(1, i).squeeze(1)
    seg = ab.gather(1, i.unsqueeze(-1).expand(-1, 1, 2)).squeeze(1)
    s = cum.gather(1, i).squeeze(1) + t_i * seg.norm(dim=-1)
    heading = torch.atan2(seg[:, 1], seg[:, 0])
    return s, d2.gather(1, i).squeeze(1).sqrt(), heading, i.squeeze(1)


def route_state(s: Mapping[str, Any]) -> dict[str, Tensor]:
    """``route_s``, ``route_to_go`` (``|goal_s - route_s|`` plus the distance from the route)
    [m], ``route_heading`` [rad] and ``route_chunk`` of the truck's projection
    (``{key: [N]}``)."""
    along, off, heading, piece = project(s["route_points"], s["route_cum"], s["pose"])
    group = chunk_pieces(s["route_points"].shape[1], s["window"].shape[1])
    return {
        "route_s": along,
        "route_to_go": (s["goal_s"] - along).abs() + off,
        "route_heading": heading,
        "route_chunk": (piece // group).clamp_max(s["window"].shape[1] - 1),
    }


def route_errors(s: Mapping[str, Any]) -> dict[str, Tensor]:
    """The errors the reward pays the decrease of: the route's distance to go [m] and the
    tractor and trailer heading to the route's heading [rad] (``{key: [N]}``)."""
    pose, heading = s["pose"], s["route_heading"]
    return {
        "pos_error": s["route_to_go"],
        "tractor_heading_error": wrap_angle(heading - pose[:, 2]).abs(),
        "trailer_heading_error": wrap_angle(heading - pose[:, 2] - pose[:, 3]).abs(),
    }


def route_info(
    state: Mapping[str, Any], first_block: Tensor, past: Tensor | None = None
) -> dict[str, Tensor]:
    """The episodes' metadata (:data:`~truckrl.tasks.network.scene.INFO_KEYS` but ``level`` and
    ``feasible``) for routes from block ``first_block [N]`` (long) to the chain's end; where
    ``past [N]`` (bool) the start lies on the exit arm of the junction after ``first_block``,
    whose manoeuvre is behind it: that junction, its type and its turn are not counted."""
    types = state["block_type"]
    n, K = types.shape
    k = torch.arange(K, device=types.device)
    on = (k >= first_block.unsqueeze(-1)) & (types >= 0)
    if past is not None:
        on = on & ~(past.unsqueeze(-1) & (k == first_block.unsqueeze(-1) + 1))
    joint = on & (k % 2 == 1)
    info = {"blocks": on.sum(-1).float(), "junctions": joint.sum(-1).float()}
    for t, name in enumerate(BLOCK_NAMES):
        info[f"has_{name}"] = ((types == t) & on).any(-1).float()
    turn = state["junction_turn"]
    info["turns_straight"] = (joint & (turn.abs() < STRAIGHT_TURN)).sum(-1).float()
    info["turns_left"] = (joint & (turn >= STRAIGHT_TURN)).sum(-1).float()
    info["turns_right"] = (joint & (turn <= -STRAIGHT_TURN)).sum(-1).float()
    active = state["tr_active"]
    L = state["tr_lanes"].shape[1] // K
    slot = torch.arange(K * L, device=types.device)
    lane_block = (slot // L).expand(n, -1)
    ring = (types.gather(1, lane_block) == ROUNDABOUT) & (slot % L == 0)
    visible = lane_block >= first_block.unsqueeze(-1)
    length = (state["tr_lane_len"] * (visible & ~ring)).sum(-1)
    info["vehicles"] = active.sum(-1).float()
    info["traffic_density"] = 100.0 * info["vehicles"] / length.clamp_min(1.0)
    info["route_length"] = state["goal_s"] - state["route_s"]
    info["level"] = torch.zeros(n, device=types.device)
    info["feasible"] = torch.ones(n, device=types.device)
    return {k: info[k] for k in INFO_KEYS}


TASK = NetworkTask
