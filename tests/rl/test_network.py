"""Two-branch network: parameter count by hand, circular CNN, Gaussian head, batch shapes."""

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.config.fields import ConfigError
from truckrl.rl.network import (
    LidarEncoder,
    ModelConfig,
    circular_conv_index,
    make_actor_critic,
    parameter_count,
)


def linear(i, o):
    return i * o + o


def conv(i, o, k):
    return i * o * k + o


def expected_params(beams: int) -> int:
    # Hand layout: 26->128->64 MLP; conv 1->2->4 (k=5, s=2, pad 2): length beams -> ceil/2 -> /2.
    l1 = (beams + 4 - 5) // 2 + 1
    l2 = (l1 + 4 - 5) // 2 + 1
    mlp = linear(26, 128) + linear(128, 64)
    cnn = conv(1, 2, 5) + conv(2, 4, 5)
    fusion = linear(64 + 4 * l2, 64) + 2 * 64  # Linear + LayerNorm (weight, bias)
    actor = linear(64, 2) + 2  # mean head + state-independent log-std
    critic = linear(64, 1)
    return mlp + cnn + fusion + actor + critic


def test_parameter_count_matches_hand_count_and_paper():
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    assert expected_params(16) == 17277
    assert parameter_count(ac.model) == 17277
    assert abs(parameter_count(ac.model) - 17_300) < 100  # paper: "about 17.3k"


@pytest.mark.parametrize("beams", [8, 33, 64])
def test_cnn_output_follows_beam_count(beams):
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=beams)
    assert parameter_count(ac.model) == expected_params(beams)


def test_circular_padding_makes_cnn_rotation_equivariant():
    torch.manual_seed(0)
    enc = LidarEncoder(16, ModelConfig())
    x = torch.rand(3, 16)
    # Two stride-2 layers: rolling the ring by 4 beams rolls the output by exactly 1 position.
    y = enc(x).reshape(3, 4, 4)
    y_rolled = enc(torch.roll(x, 4, dims=-1)).reshape(3, 4, 4)
    torch.testing.assert_close(y_rolled, torch.roll(y, 1, dims=-1))


def test_too_few_beams_is_a_config_error():
    with pytest.raises(ConfigError, match="num_beams"):
        make_actor_critic(ModelConfig(), num_obs=26, num_beams=1)


def test_bad_model_config_names_field():
    with pytest.raises(ConfigError, match="model.kernel_size"):
        ModelConfig(kernel_size=4)
    with pytest.raises(ConfigError, match="model.init_std"):
        ModelConfig(init_std=0.0)
    with pytest.raises(ConfigError, match=r"model.numeric_hidden\[1\] = 2.5"):
        ModelConfig(numeric_hidden=(64, 2.5))
    with pytest.raises(ConfigError, match="model.numeric_hidden"):
        ModelConfig(numeric_hidden=())


def test_model_config_normalises_lists_and_allows_no_cnn():
    cfg = ModelConfig(numeric_hidden=[32], cnn_channels=[], kernel_size=3.0)
    assert cfg.numeric_hidden == (32,) and cfg.cnn_channels == () and cfg.kernel_size == 3
    enc = LidarEncoder(16, cfg)  # no conv layer: the raw ranges feed the fusion layer
    assert enc.out_features == 16 and enc(torch.rand(3, 16)).shape == (3, 16)


def test_policy_and_value_on_worker_by_env_by_time_batch():
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    td = TensorDict(
        {"observation": torch.randn(2, 3, 5, 26), "lidar": torch.rand(2, 3, 5, 16)}, [2, 3, 5]
    )
    with torch.no_grad():
        ac.actor(td)
        ac.critic(td)
    assert td["action"].shape == (2, 3, 5, 2)
    assert td["action_log_prob"].shape == (2, 3, 5)
    assert td["state_value"].shape == (2, 3, 5, 1)
    torch.testing.assert_close(td["scale"], torch.full((2, 3, 5, 2), 0.5))  # paper: std 0.5
    # log-prob of a diagonal Gaussian, written out by hand
    z = (td["action"] - td["loc"]) / 0.5
    logp = (-0.5 * z.square() - math.log(0.5) - 0.5 * math.log(2 * math.pi)).sum(-1)
    torch.testing.assert_close(td["action_log_prob"], logp)


def test_deterministic_mode_returns_the_mean():
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    td = TensorDict({"observation": torch.randn(7, 26), "lidar": torch.rand(7, 16)}, [7])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        ac.actor(td)
    torch.testing.assert_close(td["action"], td["loc"])


@pytest.mark.parametrize("beams", [3, 4, 5, 8, 16, 33, 64])
def test_dense_ring_forward_equals_the_convolution(beams):
    """The encoder's dense-matrix forward against the nn.Conv1d layers it holds, run directly."""
    torch.manual_seed(beams)
    cfg = ModelConfig()
    enc = LidarEncoder(beams, cfg)
    x = torch.rand(6, beams, requires_grad=True)
    y = enc(x)
    ref = enc.net(x.unsqueeze(1)).flatten(1)  # the torch convolutions, circular padding
    torch.testing.assert_close(y, ref, rtol=1e-5, atol=1e-6)
    g = torch.randn_like(y)
    grads = torch.autograd.grad(y, [x, *enc.parameters()], g)
    ref_grads = torch.autograd.grad(ref, [x, *enc.parameters()], g)
    for a, b in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_circular_conv_index_by_hand():
    # 1 -> 1 channel, k = 3, stride 1, ring of 4: output j reads inputs j-1, j, j+1 (mod 4)
    index, l_out = circular_conv_index(1, 1, 4, 3, 1)
    assert l_out == 4
    w = torch.tensor([10.0, 20.0, 30.0])  # taps t = 0, 1, 2
    m = torch.cat([torch.zeros(1), w])[index]
    expected = torch.tensor(
        [[20.0, 10.0, 0.0, 30.0],  # input 0 feeds output 0 (centre), 1 (left tap), 3 (right tap)
         [30.0, 20.0, 10.0, 0.0],
         [0.0, 30.0, 20.0, 10.0],
         [10.0, 0.0, 30.0, 20.0]]
    )  # fmt: skip
    torch.testing.assert_close(m, expected)
