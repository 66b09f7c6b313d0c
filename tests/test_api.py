"""The public API of the package: ``from truckrl import TruckEnv, make_env, load_policy,
evaluate_policy``, loaded on first use; ``make_env`` over every task folder; the version written
once and quoted alike by the citation file and the changelog."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
import torch

import truckrl
from tests.conftest import ROOT
from truckrl.config.fields import ConfigError
from truckrl.tasks import task_names

PUBLIC = ("TruckEnv", "make_env", "load_policy", "evaluate_policy")


def test_the_public_names_import_from_the_package():
    from truckrl import TruckEnv, evaluate_policy, load_policy, make_env
    from truckrl.env.make import make_env as defined_make_env
    from truckrl.env.truck_env import TruckEnv as defined_env
    from truckrl.evaluation.rollout import evaluate_policy as defined_evaluate
    from truckrl.rl.policy import load_policy as defined_load

    assert TruckEnv is defined_env and make_env is defined_make_env
    assert load_policy is defined_load and evaluate_policy is defined_evaluate
    assert set(truckrl.__all__) == {*PUBLIC, "__version__"}
    assert set(truckrl.__all__) <= set(dir(truckrl))
    assert re.fullmatch(r"\d+\.\d+\.\d+", truckrl.__version__)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        truckrl.nope  # noqa: B018
    assert not hasattr(truckrl, "nope")


def test_import_truckrl_loads_no_torch():
    """The names load on first use: ``import truckrl`` alone stays cheap (``truckrl --help``)."""
    code = (
        "import sys, truckrl; print(sorted(m for m in sys.modules if m.startswith('torch')), "
        "sorted(set(truckrl.__all__) - set(dir(truckrl))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout == "[] []\n", out.stdout + out.stderr


@pytest.mark.parametrize("task", task_names())
def test_make_env_builds_every_task_and_rolls_out(task):
    n, steps, beams = 3, 5, 8
    env = truckrl.make_env(task, num_envs=n, **{"lidar.num_beams": beams})
    assert isinstance(env, truckrl.TruckEnv) and env.config.task.name == task
    assert env.batch_size == (n,)
    td = env.rollout(steps, break_when_any_done=False)
    assert td.batch_size == (n, steps)
    assert td["observation"].shape == (n, steps, env.task.num_features)
    assert td["lidar"].shape == (n, steps, beams)
    assert td["action"].shape == (n, steps, 2)
    for key in ("reward", "done", "terminated", "truncated"):
        assert td["next", key].shape == (n, steps, 1), key
    assert torch.isfinite(td["next", "reward"]).all()


def test_make_env_overrides_dotted_nested_and_the_difficulty():
    dotted = truckrl.make_env(**{"lidar.num_beams": 12, "control.lateral": "rate"})
    nested = truckrl.make_env(lidar={"num_beams": 12}, control={"lateral": "rate"})
    assert dotted.config == nested.config
    assert dotted.config.lidar.num_beams == 12 and dotted.config.control.lateral == "rate"
    assert truckrl.make_env().config.lidar.num_beams != 12  # the default differs
    hard = truckrl.make_env(difficulty=6)
    assert hard.config.tolerance.difficulty == 6.0
    assert hard.get_difficulty() == 6.0
    scene = truckrl.make_env("intersection", **{"task.scene.crossing_prob": 1.0})
    assert scene.config.task.scene.crossing_prob == 1.0


def test_make_env_is_seeded():
    a = truckrl.make_env(num_envs=4, seed=3).reset()
    b = truckrl.make_env(num_envs=4, seed=3).reset()
    c = truckrl.make_env(num_envs=4, seed=4).reset()
    assert torch.equal(a["observation"], b["observation"])
    assert not torch.equal(a["observation"], c["observation"])


@pytest.mark.parametrize(
    "overrides, named",
    [
        ({"nope": 1}, r"\['nope'\] for env;"),
        ({"lidar.nope": 1}, r"\['nope'\] for env\.lidar;"),
        ({"lidar": {"nope": 1}}, r"\['nope'\] for env\.lidar;"),
        ({"task.scene.nope": 1}, r"\['nope'\] for env\.task\.scene;"),
        ({"lidar.num_beams": 0}, r"env\.lidar\.num_beams = 0"),
        ({"lidar": 3, "lidar.num_beams": 2}, r"lidar is given a value"),
        ({"task.name": "dock"}, r"task\.name is make_env's first argument"),
        ({"difficulty": 2, "tolerance.difficulty": 2}, r"one field"),
        ({"lidar..num_beams": 2}, r"'lidar\.\.num_beams': an override key"),
    ],
)
def test_make_env_refuses_a_bad_override_naming_it(overrides, named):
    with pytest.raises(ConfigError, match=named):
        truckrl.make_env(**overrides)


def test_make_env_refuses_an_unknown_task():
    with pytest.raises(ConfigError, match=r"env\.task\.name = 'nope' is not one of"):
        truckrl.make_env("nope")


def test_the_version_is_written_once_and_quoted_alike():
    """pyproject.toml reads ``truckrl.__version__``; the citation and the changelog quote it."""
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in pyproject["project"] and "version" in pyproject["project"]["dynamic"]
    dynamic = pyproject["tool"]["setuptools"]["dynamic"]
    assert dynamic["version"] == {"attr": "truckrl.__version__"}
    cited = re.search(r"^version: (\S+)$", (ROOT / "CITATION.cff").read_text(), re.M)
    assert cited is not None and cited.group(1) == truckrl.__version__
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in changelog
    assert re.search(
        rf"^## \[{re.escape(truckrl.__version__)}\] - \d{{4}}-\d\d-\d\d$", changelog, re.M
    )
