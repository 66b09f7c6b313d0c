"""The ``network`` task seen as a chain of intersection cells: the intersection task's
observation, computed against the route's successive junction exits as sub-goals.

The source paper claims that larger networks "factorize into repeated instances of the same
skill; even at deployment time, a policy can be rolled forward across consecutive intersection
cells" (issue 42, item 4). This task is how that claim is measured without retraining: a policy
trained on the ``intersection`` task drives a ``network`` episode with its own observation
layout, and the goal it sees is moved from junction exit to junction exit.

What is the network task's (:class:`~truckrl.tasks.network.task.NetworkTask`, unchanged): the
chains, the route, start and goal, traffic and the curriculum; the step, the collision and the
LiDAR (curbs in reach and the vehicles); the errors, the success test (the **final** goal within
the tolerances: reaching a sub-goal ends nothing) and the reward.

What differs: the observation. It is the shared 26 features plus the LiDAR, no route extras,
exactly the ``intersection`` task's layout, with the goal position and the goal heading terms
(indices 0-5) those of the current sub-goal instead of the final goal.

Sub-goals (``env.task.subgoal``)
--------------------------------
For each junction ``J_i`` of the chain (``i = 1 .. J``, :mod:`truckrl.tasks.network.scene`),
the pose on the route ``past_exit`` metres of arc length past the junction's exit (the entry of
the link ``L_i`` behind it: on that link's lane, heading along the route there), never past the
final goal; then the final goal itself. The junction's exit is read from the network task's
start option on ``L_i``, which stands ``rear + start_margin`` along the lane from the link's
entry (the scene's feasibility rule; ``rear``: the truck's extent behind its rear axle).

The default ``past_exit = 20 m`` puts the whole truck beyond the junction: its rear extent is
6.6-14.6 m at the default vehicle ranges, and the intersection task trained on goals whose
footprint stands beyond the crossing (its ``pose_intersection_margin``).

Switching. The current sub-goal ``k`` is the first whose arc length ``s_k`` the truck's
projection on the route (``route_s``, :func:`~truckrl.tasks.network.task.route_state`) has not
come within ``switch`` of: after every step ``k <- max(k, #{k' < S - 1 : route_s >= s_k' -
switch})``, the final goal (index ``S - 1``) never passed. The arc length, not the distance to
the pose, so that a truck that drives past a sub-goal off to one side still moves on; the max,
so that the goal never moves back. At a reset the sub-goals of the junctions behind the start
(those the curriculum cut off) count as passed. The default ``switch = 5 m`` hands over when the
rear axle is 15 m past the exit (the truck mostly out of the junction) without making the policy
align to a pose it does not need to reach. ``subgoal.junctions = false`` shows the final goal
from the start (the control: the intersection policy without sub-goals).

Horizon (a diagnostic, off by default). The intersection task's goals lie 25-70 m from its
starts; a junction exit can lie 150 m ahead. With ``subgoal.horizon = h > 0`` a current
sub-goal more than ``h`` metres of arc length ahead of the truck's projection is shown as the
route pose ``h`` ahead of it (on the route, heading along it), the sub-goal itself once it is
within ``h``: the same cells, with goals at the distances the policy was trained on.

State keys (:data:`SUBGOAL_KEYS`): ``subgoals [N, S, 3]`` (x, y [m], heading [rad]; ``S = J +
1``), ``subgoal_s [N, S]`` (their arc lengths along the route [m], non-decreasing) and
``subgoal_index [N]`` (long, the current one). A state built by hand without the network's
start options gets every sub-goal at the final goal.

The task is not a folder of ``truckrl/tasks``: it runs by its dotted package path,
``env.task.name=truckrl.tasks.network.cells`` (:mod:`truckrl.tasks.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from truckrl.config.fields import param, validate
from truckrl.sim.vehicle import truck_extents
from truckrl.tasks.base import Task
from truckrl.tasks.network.scene import point_at
from truckrl.tasks.network.task import NetworkTask, NetworkTaskConfig, project

if TYPE_CHECKING:
    from tensordict import TensorDict

    from truckrl.tasks.config import EnvConfig

#: The task's name: its dotted package path (it is no folder of ``truckrl/tasks``).
CELLS_TASK = "truckrl.tasks.network.cells"
#: State keys of the sub-goals (module doc).
SUBGOAL_KEYS: tuple[str, ...] = ("subgoals", "subgoal_s", "subgoal_index")


@dataclass
class SubgoalConfig:
    """Where the sub-goals stand and when the next takes over (``env.task.subgoal.*``)."""

    past_exit: float = param(
        20.0, lo=0.0, hi=1000.0, unit="m",
        doc="a junction's sub-goal stands this far along the route past its exit",
    )  # fmt: skip
    switch: float = param(
        5.0, lo=0.0, hi=1000.0, unit="m",
        doc="the next sub-goal takes over when the truck's route projection is this close",
    )  # fmt: skip
    junctions: bool = param(
        True, doc="sub-goals at the junction exits (false: the final goal from the start)"
    )
    horizon: float = param(
        0.0, lo=0.0, hi=1000.0, unit="m",
        doc="0: off; else a sub-goal farther along the route is shown as the route pose this "
        "far ahead of the truck's projection",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate(self, "env.task.subgoal")


@dataclass
class CellsTaskConfig(NetworkTaskConfig):
    """The network task's config and the sub-goals (``env.task.subgoal``)."""

    name: str = param(
        CELLS_TASK, choices=(CELLS_TASK,), doc="task package (the network task's sub-goal view)"
    )
    subgoal: SubgoalConfig = field(default_factory=SubgoalConfig)


# ---------------------------------------------------------------------------------- helpers
def junction_exits(points: Tensor, cum: Tensor, start_options: Tensor, back: Tensor) -> Tensor:
    """Arc lengths ``[N, J]`` [m] of the junction exits along the route ``points [N, R, 2]``
    (arc lengths ``cum [N, R]``): each start option on a link ``L_1 .. L_J``
    (``start_options [N, J + 1, 3]``) projected on the route, less ``back [N]`` [m] (the
    option's distance from its link's entry, ``rear + start_margin``)."""
    n, options = start_options.shape[:2]
    # each option as one batch row (the route repeated): one projection for all of them
    rep = lambda t: t.repeat_interleave(options - 1, 0)  # noqa: E731
    s = project(rep(points), rep(cum), start_options[:, 1:].reshape(-1, 3))[0]
    return s.view(n, options - 1) - back.unsqueeze(-1)


def subgoal_poses(
    points: Tensor, cum: Tensor, exits: Tensor, goal: Tensor, goal_s: Tensor, past: float
) -> tuple[Tensor, Tensor]:
    """The sub-goals (module doc): ``(poses [N, J + 1, 3], s [N, J + 1])``.

    Args:
        points, cum: the route ``[N, R, 2]`` and its arc length ``[N, R]`` [m].
        exits: ``[N, J]`` the junction exits' arc lengths [m] (:func:`junction_exits`).
        goal: ``[N, 3]`` the final goal; ``goal_s [N]`` its arc length [m].
        past: [m] how far past an exit its sub-goal stands (clamped at ``goal_s``, where it is
            the goal).
    """
    s = (exits + past).minimum(goal_s.unsqueeze(-1))
    xy, heading = point_at(points, cum, s)
    poses = torch.cat((xy, heading.unsqueeze(-1)), -1)
    # one clamped at the goal is the goal itself, not the resampled route's point there
    poses = torch.where(
        (exits + past >= goal_s.unsqueeze(-1)).unsqueeze(-1), goal.unsqueeze(1), poses
    )
    return (
        torch.cat((poses, goal.unsqueeze(1)), 1),
        torch.cat((s, goal_s.unsqueeze(-1)), 1),
    )


def advance(index: Tensor, route_s: Tensor, subgoal_s: Tensor, switch: float) -> Tensor:
    """The current sub-goal ``[N]`` (long) after the truck's projection reached ``route_s [N]``
    [m]: ``max(index, #{k < S - 1 : route_s >= subgoal_s[k] - switch})`` (module doc)."""
    reached = (subgoal_s[:, :-1] - switch <= route_s.unsqueeze(-1)).sum(-1)
    return torch.maximum(index, reached)


def current_subgoal(s: Mapping[str, Any]) -> Tensor:
    """The current sub-goal pose ``[N, 3]`` of a state."""
    n = s["subgoal_index"].shape[0]
    at = s["subgoal_index"].view(n, 1, 1).expand(n, 1, 3)
    return s["subgoals"].gather(1, at).squeeze(1)


# ---------------------------------------------------------------------------------- the task
class CellsTask(NetworkTask):
    """The network task with the intersection task's observation against sub-goals; see the
    module docstring."""

    name = CELLS_TASK
    config_class = CellsTaskConfig
    extra_state_keys = (*NetworkTask.extra_state_keys, *SUBGOAL_KEYS)
    #: the common refill size, not the network task's: a refill's size decides which episodes a
    #: seed draws, and the cells measurement (docs/chaining.md) keeps drawing the same ones
    episode_pool = Task.episode_pool

    def __init__(self, cfg: EnvConfig) -> None:
        super().__init__(cfg)
        self.num_extras = 0  # the intersection task's layout: no route points

    def observation_extras(self, s: dict[str, Any]) -> Tensor | None:
        """None: the shared 26 features only."""
        return None

    def subgoal_state(self, state: Mapping[str, Any]) -> dict[str, Tensor]:
        """``subgoals`` and ``subgoal_s`` of a state (module doc), from its start options, or
        every one at the final goal where it has none."""
        goal, goal_s = state["goal"], state["goal_s"]
        n, J = goal.shape[0], self.max_junctions
        if "start_options" in state.keys():
            _, rear, _ = truck_extents(state["params"])
            back = rear + self.cfg.task.scene.start_margin
            exits = junction_exits(
                state["route_points"], state["route_cum"], state["start_options"], back
            )
            poses, s = subgoal_poses(
                state["route_points"], state["route_cum"], exits, goal, goal_s,
                self.cfg.task.subgoal.past_exit,
            )  # fmt: skip
            return {"subgoals": poses, "subgoal_s": s}
        return {
            "subgoals": goal.unsqueeze(1).expand(n, J + 1, 3).clone(),
            "subgoal_s": goal_s.unsqueeze(1).expand(n, J + 1).clone(),
        }

    def first_index(self, state: Mapping[str, Any], passed: Tensor) -> Tensor:
        """The current sub-goal ``[N]`` at an episode's start: the switching rule from
        ``passed [N]`` (long, the sub-goals behind the start), or the final goal's index where
        ``subgoal.junctions`` is false."""
        cfg = self.cfg.task.subgoal
        last = state["subgoal_s"].shape[1] - 1
        if not cfg.junctions:
            return torch.full_like(passed, last)
        return advance(passed, state["route_s"], state["subgoal_s"], cfg.switch)

    def complete_state(self, state: TensorDict) -> TensorDict:
        """The network task's keys, then the sub-goals where they are missing (module doc)."""
        state = super().complete_state(state)
        keys = state.keys()
        if "subgoals" not in keys:
            for k, v in self.subgoal_state(state).items():
                state[k] = v
        if "subgoal_index" not in keys:
            zero = torch.zeros(state["goal"].shape[0], dtype=torch.long, device=state.device)
            state["subgoal_index"] = self.first_index(state, zero)
        return state

    def on_reset(self, state: TensorDict, difficulty: Tensor) -> TensorDict:
        """The network task's curriculum, then the first sub-goal: those of the junctions
        behind the start (``J - junctions`` of the level) count as passed."""
        state = super().on_reset(state, difficulty)
        if "start_options" not in state.keys():
            return state
        level = state["route", "level"].long()
        behind = self.max_junctions - self._junctions[level]
        state["subgoal_index"] = self.first_index(state, behind)
        return state

    def step(self, s: dict[str, Any], action: Tensor) -> dict[str, Tensor]:
        """The network task's step, then the switching rule on the truck's new projection."""
        new = super().step(s, action)
        new["subgoal_index"] = advance(
            s["subgoal_index"], new["route_s"], s["subgoal_s"], self.cfg.task.subgoal.switch
        )
        return new

    def observed_goal(self, s: Mapping[str, Any]) -> Tensor:
        """The goal pose ``[N, 3]`` the observation shows: the current sub-goal, or with
        ``subgoal.horizon`` ``h > 0`` the route pose ``h`` ahead of the truck's projection
        where the sub-goal lies farther along the route (module doc)."""
        goal = current_subgoal(s)
        h = self.cfg.task.subgoal.horizon
        if h <= 0.0:  # a config value: no tensor is read
            return goal
        n = goal.shape[0]
        sub_s = s["subgoal_s"].gather(1, s["subgoal_index"].view(n, 1)).squeeze(1)
        ahead = s["route_s"] + h
        xy, heading = point_at(s["route_points"], s["route_cum"], ahead.unsqueeze(-1))
        carrot = torch.cat((xy[:, 0], heading), -1)
        return torch.where((sub_s > ahead).unsqueeze(-1), carrot, goal)

    def observe(self, s: dict[str, Any], difficulty: Tensor) -> dict[str, Tensor]:
        """The shared observation with :meth:`observed_goal` as the goal (errors, flags and
        the rest of the state stay the final goal's)."""
        return super().observe({**s, "goal": self.observed_goal(s)}, difficulty)


TASK = CellsTask
