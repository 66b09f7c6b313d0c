"""Sampling-based planner baseline: the cross-entropy method (CEM) over smooth action sequences,
rolled out on the task core with the dynamics, collision, jack-knife and success test of training.

It answers "can this scene be solved within the episode?" independently of any learned policy,
and it is scored like a policy: :func:`plan_episodes` returns the per-episode results of
:func:`truckrl.evaluation.rollout.evaluate_policy` (same keys; the same scenes for the same
``episodes`` and ``seed``), plus each scene's route and vehicle parameters for
:mod:`truckrl.evaluation.categories`.

Modules: :mod:`~truckrl.planning.config` (:class:`PlannerConfig`),
:mod:`~truckrl.planning.controller` (set-points, tracker, pursuit),
:mod:`~truckrl.planning.rollout` (:class:`Planner`: candidates, batched rollout, cost),
:mod:`~truckrl.planning.search` (CEM), :mod:`~truckrl.planning.episodes` (replay, results),
:mod:`~truckrl.planning.scenes` (:func:`held_out_states`), :mod:`~truckrl.planning.experts`.

How a task plugs in its expert: the planner and the demonstrations name no task; they import
``expert.py`` from the task's folder by the task's name (:func:`~truckrl.planning.experts.task_expert`)
and use three optional module attributes. ``steering_prior(pose [N, 3], goal [N, 3], params, f [N])
-> [N, 3]`` (travel [m] where a held steering angle starts and ends, that angle [rad]; ``f`` in
``[0, 1]`` is its one planned parameter) is what ``planner.steer_prior=arc|alternate`` adds to
the knots. ``demonstrations(env_cfg, episodes, seed, difficulty) -> (solved [E] bool, samples [M])``
is the task's own demonstrator for ``demos.source=driver``; ``labelled(env_cfg, episodes, seed,
difficulty, act) -> (solved [E] bool, samples [M])`` lets ``act`` (a policy) drive and labels
every state it visits with the demonstrator's action, for ``demos.dagger_rounds``. A folder
without ``expert.py``, or without the attribute, gets a one-line ConfigError asking for
``steer_prior=none``, ``demos.source=planner`` or ``demos.dagger_rounds=0``; the planner itself
needs no expert.
"""

from truckrl.planning.config import PlannerConfig
from truckrl.planning.controller import knot_matrix
from truckrl.planning.episodes import category_info, plan_episodes, plan_states, replay
from truckrl.planning.experts import (
    scripted_demonstrations,
    scripted_labels,
    steering_prior,
    task_expert,
)
from truckrl.planning.rollout import Planner
from truckrl.planning.scenes import held_out_states

__all__ = [
    "Planner",
    "PlannerConfig",
    "category_info",
    "held_out_states",
    "knot_matrix",
    "plan_episodes",
    "plan_states",
    "replay",
    "scripted_demonstrations",
    "scripted_labels",
    "steering_prior",
    "task_expert",
]
