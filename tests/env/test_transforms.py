"""TruckEnv inside TorchRL's ``TransformedEnv`` with its standard transforms: ``StepCounter``,
``RewardSum``, ``ObservationNorm`` and ``VecNormV2`` pass TorchRL's ``check_env_specs``, and
their episode counts and sums match hand-checked values and a plain loop over the rollout's own
rewards and done flags, across autoresets and partial resets."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import (
    Compose,
    ObservationNorm,
    RewardSum,
    StepCounter,
    TransformedEnv,
    VecNormV2,
)
from torchrl.envs.utils import check_env_specs, step_mdp

from truckrl.env import TruckEnv

#: Five-step episodes: every truck times out at step 5 unless it finishes earlier.
CONFIG = {"max_steps": 5, "compile": False}


def counted(num_envs: int = 3) -> TransformedEnv:
    """TruckEnv with TorchRL's episode length (as ``episode_steps``, beside the env's own
    ``step_count``) and episode return."""
    env = TruckEnv(num_envs=num_envs, seed=0, config=CONFIG)
    return TransformedEnv(env, Compose(StepCounter(step_count_key="episode_steps"), RewardSum()))


@pytest.mark.filterwarnings("ignore:Support of VecNormV2 for containers with non-empty batch")
def test_transformed_env_passes_torchrls_spec_check():
    torch.manual_seed(0)
    check_env_specs(counted())
    norm = ObservationNorm(loc=0.5, scale=2.0, in_keys=["observation"], standard_normal=True)
    check_env_specs(TransformedEnv(TruckEnv(num_envs=2, seed=1, config=CONFIG), norm))
    vec = VecNormV2(in_keys=["observation"], decay=0.99)
    check_env_specs(TransformedEnv(TruckEnv(num_envs=2, seed=1, config=CONFIG), vec))


def test_counts_and_sums_restart_with_each_episode_in_a_rollout():
    """12 steps of 5-step episodes: lengths 1..5, 1..5, 1, 2 where every episode times out; the
    return is the running sum of the rewards since the last done (a plain loop)."""
    torch.manual_seed(0)
    env = counted()
    td = env.rollout(12, break_when_any_done=False)
    nxt = td["next"]
    done = nxt["done"].squeeze(-1)
    assert done.sum(-1).tolist() == [2, 2, 2] and done[:, [4, 9]].all()  # all time out
    expected_steps = [1, 2, 3, 4, 5, 1, 2, 3, 4, 5, 1, 2]
    assert nxt["episode_steps"].squeeze(-1).tolist() == [expected_steps] * 3
    assert torch.equal(nxt["episode_steps"], nxt["step_count"])  # TorchRL's count is the env's
    reward = nxt["reward"].squeeze(-1)
    for e in range(3):
        total = torch.zeros((), dtype=reward.dtype)
        for t in range(12):
            total = total + reward[e, t]
            assert nxt["episode_reward"][e, t, 0] == pytest.approx(float(total), abs=1e-6)
            if done[e, t]:
                total = torch.zeros((), dtype=reward.dtype)
    assert (reward[:, 4] < -1.0).all()  # the timeout penalty lands in the first episode's sum


def test_a_partial_reset_restarts_only_the_flagged_trucks():
    torch.manual_seed(0)
    env = counted()
    td, rewards = env.reset(), torch.zeros(3)
    for _ in range(3):
        td = env.rand_step(td)
        rewards += td["next", "reward"].squeeze(-1)
        td = step_mdp(td)
    assert td["episode_steps"].squeeze(-1).tolist() == [3, 3, 3]
    assert torch.allclose(td["episode_reward"].squeeze(-1), rewards, atol=1e-6)
    assert rewards[2] != 0.0  # so keeping truck 2's sum differs from restarting it
    td["_reset"] = torch.tensor([[True], [True], [False]])
    out = env.reset(td)
    assert out["episode_steps"].squeeze(-1).tolist() == [0, 0, 3]
    assert out["step_count"].squeeze(-1).tolist() == [0, 0, 3]
    kept = out["episode_reward"].squeeze(-1)
    assert kept[:2].tolist() == [0.0, 0.0] and kept[2] == pytest.approx(float(rewards[2]))
    out = env.rand_step(out)
    assert out["next", "episode_steps"].squeeze(-1).tolist() == [1, 1, 4]
    assert torch.equal(out["next", "step_count"], out["next", "episode_steps"])  # the env agrees


def test_observation_norm_is_the_affine_map_it_names():
    """``standard_normal=True``: ``(x - loc) / scale``, kept beside the raw observation."""
    torch.manual_seed(0)
    norm = ObservationNorm(loc=0.5, scale=2.0, in_keys=["observation"],
                           out_keys=["observation_norm"], standard_normal=True)  # fmt: skip
    env = TransformedEnv(TruckEnv(num_envs=2, seed=1, config=CONFIG), norm)
    td = env.rollout(3)
    for x in (td, td["next"]):
        assert torch.allclose(x["observation_norm"], (x["observation"] - 0.5) / 2.0)
