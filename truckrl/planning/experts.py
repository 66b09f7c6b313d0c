"""A task folder's expert, found by the task's name: ``<task package>.expert`` (optional).

The planner and the demonstrations never name a task; they import the module ``expert`` of the
task's folder (``truckrl.tasks.<name>.expert``, or ``<name>.expert`` for a task outside the
package, named by its dotted path) and read three optional attributes of it (the contract is in
:mod:`truckrl.planning`). A folder without ``expert.py`` has neither.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from types import ModuleType

from truckrl.config.fields import ConfigError
from truckrl.tasks.registry import task_package

#: Expert attribute: ``steering_prior(pose [N, 3], goal [N, 3], params, f [N]) -> [N, 3]``.
STEERING_PRIOR = "steering_prior"
#: Expert attribute: ``demonstrations(env_cfg, episodes, seed, difficulty) -> (solved, samples)``.
DEMONSTRATIONS = "demonstrations"
#: Expert attribute: ``labelled(env_cfg, episodes, seed, difficulty, act) -> (solved, samples)``.
LABELLED = "labelled"


def task_expert(name: str) -> ModuleType | None:
    """The ``expert`` module of task ``name``'s folder, or None where the folder has none (an
    expert that exists but fails to import raises)."""
    module = f"{task_package(name)}.expert"
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        if e.name != module:
            raise
        return None


def _attribute(name: str, attr: str, setting: str, instead: str) -> Callable:
    """Attribute ``attr`` of task ``name``'s expert, which ``setting`` needs (else a ConfigError
    that suggests ``instead``)."""
    found = getattr(task_expert(name), attr, None)
    if found is None:
        raise ConfigError(
            f"{setting} needs a {attr}() in the expert.py of task {name!r}, which has none: "
            f"use {instead}"
        )
    return found


def steering_prior(name: str, mode: str = "arc") -> Callable:
    """Task ``name``'s steering prior for ``planner.steer_prior = mode``.

    Raises:
        ConfigError: the task's folder has no expert, or its expert no ``steering_prior``.
    """
    return _attribute(name, STEERING_PRIOR, f"planner.steer_prior = {mode!r}", "steer_prior=none")


def scripted_demonstrations(name: str) -> Callable:
    """Task ``name``'s own demonstrator (``demos.source = driver``).

    Raises:
        ConfigError: the task's folder has no expert, or its expert no ``demonstrations``.
    """
    return _attribute(name, DEMONSTRATIONS, "demos.source = driver", "demos.source=planner")


def scripted_labels(name: str) -> Callable:
    """Task ``name``'s demonstrator as a labeller of a policy's own states
    (``demos.dagger_rounds > 0``).

    Raises:
        ConfigError: the task's folder has no expert, or its expert no ``labelled``.
    """
    return _attribute(name, LABELLED, "demos.dagger_rounds > 0", "demos.dagger_rounds=0")
