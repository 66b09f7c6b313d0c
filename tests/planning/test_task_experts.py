"""The planner asks a task's folder for its expert by the task's name (truckrl/planning/experts.py):
the intersection's steering prior is found and used, a folder without ``expert.py`` plans without
one and refuses ``steer_prior``, and an expert that fails to import is not mistaken for none."""

from __future__ import annotations

import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.planning import Planner, plan_episodes, steering_prior, task_expert
from truckrl.tasks import EnvConfig

REACH = "tests.tasks.reach"
#: Eager, tiny budget.
FAST = {"samples": 8, "iterations": 1, "attempts": 1, "scenes_per_batch": 2, "compile": False}


def test_the_expert_module_is_looked_up_in_the_task_folder():
    import truckrl.tasks.intersection.expert as intersection
    import truckrl.tasks.uturn.expert as uturn

    assert task_expert("intersection") is intersection
    assert task_expert("uturn") is uturn
    assert steering_prior("intersection") is intersection.steering_prior
    assert task_expert(REACH) is None  # a folder without expert.py
    assert task_expert("tests.tasks.reverse_reach_task") is None  # a task that is one module


def test_the_planner_uses_the_prior_of_the_task_folder(monkeypatch):
    """``steer_prior=arc`` steers by what the folder's ``steering_prior`` returns (a spy that
    records its inputs and holds a fixed angle over the first 5 m)."""
    import truckrl.tasks.intersection.expert as intersection

    calls = []

    def spy(pose, goal, params, f):
        calls.append((pose.shape, goal.shape, f.clone()))
        n = pose.shape[0]
        return torch.tensor([0.0, 5.0, 0.1]).expand(n, 3)

    monkeypatch.setattr(intersection, "steering_prior", spy)
    env = EnvConfig(max_steps=4)
    res, _, _ = plan_episodes(env, 2.0, 2, 0, {**FAST, "steer_prior": "arc"})
    assert calls and calls[0][0] == (16, 3) and calls[0][1] == (16, 3)
    assert ((calls[0][2] >= 0) & (calls[0][2] <= 1)).all()  # the last parameter, in [0, 1]
    assert res["actions"].shape == (2, 4, 2)


def test_a_folder_without_an_expert_plans_without_a_prior():
    env = EnvConfig(max_steps=30, task={"name": REACH})
    assert Planner(env, FAST).prior is None
    res, (tol_m, _), _ = plan_episodes(env, 2.0, 2, 0, FAST)
    assert res["success"].shape == (2,) and tol_m > 0
    for prior in ("arc", "alternate"):
        with pytest.raises(ConfigError, match="steering_prior") as e:
            Planner(env, {**FAST, "steer_prior": prior})
        assert REACH in str(e.value) and "steer_prior=none" in str(e.value)
        assert len(str(e.value).splitlines()) == 1


def test_an_expert_that_fails_to_import_is_an_error_not_a_missing_expert(tmp_path, monkeypatch):
    folder = tmp_path / "broken_tasks" / "one"  # a task outside the package: a dotted name
    folder.mkdir(parents=True)
    (folder.parent / "__init__.py").write_text("")
    (folder / "__init__.py").write_text("")
    (folder / "expert.py").write_text("import no_such_module_of_this_test\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError, match="no_such_module_of_this_test"):
        task_expert("broken_tasks.one")
    (folder / "expert.py").unlink()
    assert task_expert("broken_tasks.one") is None
