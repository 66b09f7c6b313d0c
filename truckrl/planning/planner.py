"""The planner's names under their former module path, for code that still imports them from here
(the package :mod:`truckrl.planning` is where they live now)."""

from truckrl.planning import (
    Planner,
    PlannerConfig,
    category_info,
    held_out_states,
    knot_matrix,
    plan_episodes,
    plan_states,
    replay,
)

__all__ = [
    "Planner",
    "PlannerConfig",
    "category_info",
    "held_out_states",
    "knot_matrix",
    "plan_episodes",
    "plan_states",
    "replay",
]
