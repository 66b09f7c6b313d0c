"""DAgger after the first clone (``demos.dagger_rounds``, truckrl/rl/imitation.py): each round's
samples are the clone's own drive labelled by the task's demonstrator, the clone is refit to
all samples, and a run that cannot do rounds is refused in one line before any work."""

from __future__ import annotations

import copy

import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.config.fields import ConfigError
from truckrl.config.schemas import DemosConfig, TrainConfig
from truckrl.env import LIDAR_KEY, OBS_KEY, TruckEnv
from truckrl.rl.imitation import action_mse, bootstrap, dagger
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.tasks import EnvConfig
from truckrl.tasks.network.expert import labelled

CFG = EnvConfig(task={"name": "network"}, max_steps=60, episode_pool=16)
DEMOS = dict(source="driver", episodes=6, difficulty=0.0, epochs=2, dagger_episodes=3)


def fresh_actor_critic():
    torch.manual_seed(0)
    env = TruckEnv(num_envs=1, config=CFG, seed=0)
    spec = env.observation_spec
    ac = make_actor_critic(ModelConfig(), spec[OBS_KEY].shape[-1], spec[LIDAR_KEY].shape[-1], 2)
    env.close()
    return ac


def mean_action(ac):
    def act(td):
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            return ac.actor(td.select(OBS_KEY, LIDAR_KEY))["action"]

    return act


def test_a_round_adds_the_clones_own_states_and_refits_to_all():
    ac = fresh_actor_critic()
    dc = DemosConfig(**DEMOS, dagger_rounds=0)
    _, shown = bootstrap(ac, CFG, dc)
    before = copy.deepcopy(ac)
    dc1 = DemosConfig(**DEMOS, dagger_rounds=1, dagger_epochs=3)
    samples, rounds = dagger(ac, CFG, dc1, shown)
    # the round's scenes are those of seed + 1, driven by the clone as it stood
    solved, want = labelled(CFG, 3, dc.seed + 1, 0.0, mean_action(before))
    n = shown.batch_size[0]
    assert samples.batch_size[0] == n + want.batch_size[0]
    assert torch.equal(samples[:n]["action"], shown["action"])
    for k in (OBS_KEY, LIDAR_KEY, "action"):
        assert torch.equal(samples[n:][k], want[k])
    (r,) = rounds
    assert r["seed"] == dc.seed + 1 and r["samples_added"] == want.batch_size[0]
    assert r["clone_success_rate"] == pytest.approx(solved.float().mean().item())
    assert len(r["losses"]) == 3
    # the refit moved the actor towards the labels of all samples
    with torch.no_grad():
        assert action_mse(ac, samples) < action_mse(before, samples)


def test_bootstrap_runs_the_rounds_and_returns_every_sample():
    told = []
    dc = DemosConfig(**DEMOS, dagger_rounds=2)
    summary, samples = bootstrap(fresh_actor_critic(), CFG, dc, on_round=lambda *a: told.append(a))
    rounds = summary["dagger"]
    assert told == list(enumerate(rounds, 1))  # each round reported as it ends
    assert [r["seed"] for r in rounds] == [99992, 99993]
    assert all(r["scenes"] == 3 and r["samples_added"] > 0 for r in rounds)
    added = sum(r["samples_added"] for r in rounds)
    assert samples.batch_size[0] == summary["samples"] + added


@pytest.mark.parametrize(
    ("demos", "task", "message"),
    [
        ({"episodes": 8}, "network", r"needs demos.episodes > 0 and demos.source = driver"),
        ({"source": "driver"}, "network", r"needs demos.episodes > 0 and demos.source = driver"),
        ({"source": "driver", "episodes": 8}, "intersection", r"labelled\(\) in the expert.py"),
    ],
)
def test_rounds_that_cannot_run_are_one_line(demos, task, message):
    with pytest.raises(ConfigError, match=f"^demos.dagger_rounds.*{message}"):
        TrainConfig(env={"task": {"name": task}}, demos={**demos, "dagger_rounds": 2})
    TrainConfig(env={"task": {"name": task}}, demos={**demos, "dagger_rounds": 0})
