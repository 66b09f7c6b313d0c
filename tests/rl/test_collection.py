"""The collector's policy: the compiled rollout policy against the eager one, and make_collector."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.rl.collection import CompiledRollout, make_collector, make_env
from truckrl.rl.network import ROLLOUT_KEYS, ModelConfig, make_actor_critic
from truckrl.tasks import EnvConfig


def _carrier(n: int, seed: int) -> TensorDict:
    """A collector's carrier: the two observation entries plus one the policy must not touch."""
    g = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "observation": torch.randn(n, 26, generator=g),
            "lidar": torch.rand(n, 16, generator=g),
            "done": torch.zeros(n, 1, dtype=torch.bool),
        },
        [n],
    )


@pytest.mark.parametrize("exploration", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_compiled_rollout_policy_writes_what_the_eager_one_writes(exploration):
    """Same seed, same carrier: equal outputs, including the sampled actions (the action noise
    comes from torch's generator in both; the collector samples, RANDOM); after a weight change
    the compiled calls follow it (the parameters are shared, not copied) and nothing else of the
    carrier changes."""
    ac = make_actor_critic(ModelConfig(max_std=0.5), num_obs=26, num_beams=16)
    compiled = CompiledRollout(ac.rollout_policy)
    # the eager policy's parameters, registered once (not again under the compiled wrapper)
    assert [id(p) for p in compiled.parameters()] == [id(p) for p in ac.model.parameters()]
    for step in range(3):
        if step == 2:  # an optimiser step between two collections
            with torch.no_grad():
                for p in ac.model.parameters():
                    p.add_(0.05)
        td_eager, td_compiled = _carrier(64, step), _carrier(64, step)
        with torch.no_grad(), set_exploration_type(exploration):
            torch.manual_seed(7 + step)
            out_eager = ac.rollout_policy(td_eager)
            torch.manual_seed(7 + step)
            out_compiled = compiled(td_compiled)
        assert out_compiled is td_compiled  # written into the carrier, as the eager policy does
        for key in ROLLOUT_KEYS:
            torch.testing.assert_close(out_compiled[key], out_eager[key], rtol=1e-5, atol=1e-5)
        assert not out_compiled["done"].any()
        assert set(out_compiled.keys()) == set(out_eager.keys())
    with torch.no_grad(), set_exploration_type(exploration):
        torch.manual_seed(123)
        other = compiled(_carrier(64, 2))["action"]
    if exploration == ExplorationType.RANDOM:  # another seed's noise: other actions
        assert not torch.allclose(other, out_compiled["action"])
    else:  # the mean: no noise
        torch.testing.assert_close(other, out_compiled["loc"])


@pytest.mark.parametrize("compile_policy", [False, True])
def test_make_collector_batches_carry_the_rollout_entries(compile_policy):
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    env = make_env(EnvConfig(compile=False, max_steps=20), 1, 4, seed=0)
    collector = make_collector(env, ac, frames_per_batch=32, compile_policy=compile_policy)
    try:
        batch = next(iter(collector))
    finally:
        collector.shutdown()
    assert batch.batch_size == torch.Size([4, 8])
    for key in ROLLOUT_KEYS:
        assert key in batch.keys()
    # the values GAE reuses are the critic's of the collected observations
    with torch.no_grad():
        values = ac.critic(batch.select("observation", "lidar").clone())["state_value"]
    torch.testing.assert_close(batch["state_value"], values)
