"""The paper's two-branch actor-critic (section "Neural network"), as TorchRL modules.

Layout (``R`` LiDAR beams, defaults in :class:`ModelConfig`)::

    "observation" [*B, 26] --MLP 26->128->64 (ELU)-----------------+
                                                                    +-> concat -> Linear 64
    "lidar" [*B, R] --Conv1d 1->2->4 (k 5, s 2, circular) (ELU)----+   -> LayerNorm -> ELU
                      -> flatten [*B, 4 * L2]                              = "hidden" [*B, 64]

    "hidden" -> Linear 64->2 = "loc" ; exp(log_std) [2] = "scale" -> Normal -> "action" [*B, 2]
    "hidden" -> Linear 64->1 = "state_value" [*B, 1]

``L2 = conv_out_len(conv_out_len(R))`` with ``conv_out_len(L) = (L + 2*(k//2) - k) // s + 1``,
so with 16 beams the CNN yields 4 channels x 4 positions = 16 features and the whole model has
17,277 parameters (the paper: "about 17.3k").

Action distribution: a diagonal Gaussian (``IndependentNormal``) with a state-independent
log-std, as in RSL-RL which the paper used. The sampled, unclipped action is what PPO stores and
scores; the environment clamps it to its ``[-1, 1]`` bounds. Against ``TanhNormal`` this keeps
the entropy in closed form (no Monte-Carlo entropy noise), keeps the analytic Gaussian KL that the
adaptive learning-rate schedule needs, gives "initial std 0.5" its plain meaning in action units,
and avoids ``atanh`` of saturated actions when PPO re-scores stored samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict.nn import ProbabilisticTensorDictSequential, TensorDictModule
from torch import Tensor, nn
from torchrl.modules import ActorValueOperator, IndependentNormal, ProbabilisticActor, ValueOperator

from truckrl.agent.config import ModelConfig
from truckrl.sim.validation import ConfigError

OBS_KEY = "observation"
LIDAR_KEY = "lidar"
HIDDEN_KEY = "hidden"


def conv_out_len(length: int, kernel_size: int, stride: int) -> int:
    """Length after one circularly padded conv layer (padding ``kernel_size // 2`` each side)."""
    return (length + 2 * (kernel_size // 2) - kernel_size) // stride + 1


class LidarEncoder(nn.Module):
    """1D CNN over the beam ring; circular padding keeps beams at -pi and +pi adjacent.

    Input ``[N, R]`` ranges / 50 m; output ``[N, C_last * L_last]``.
    """

    def __init__(self, num_beams: int, cfg: ModelConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        in_ch, length = 1, num_beams
        pad = cfg.kernel_size // 2
        for i, out_ch in enumerate(cfg.cnn_channels):
            if length < max(pad, 1):
                raise ConfigError(
                    f"env.lidar.num_beams = {num_beams} is too few for {len(cfg.cnn_channels)} "
                    f"conv layers of kernel {cfg.kernel_size} / stride {cfg.stride}: layer {i} "
                    f"would see {length} beams, circular padding needs at least {max(pad, 1)}"
                )
            layers += [
                nn.Conv1d(in_ch, out_ch, cfg.kernel_size, cfg.stride, pad, padding_mode="circular"),
                nn.ELU(),
            ]
            in_ch, length = out_ch, conv_out_len(length, cfg.kernel_size, cfg.stride)
        self.net = nn.Sequential(*layers)
        self.out_features = in_ch * length

    def forward(self, lidar: Tensor) -> Tensor:
        return self.net(lidar.unsqueeze(1)).flatten(1)


class TwoBranchTrunk(nn.Module):
    """Shared encoder: numeric MLP + LiDAR CNN, fused by Linear -> LayerNorm -> ELU.

    Args:
        num_obs: numeric observation size (26 in the paper).
        num_beams: LiDAR beam count ``R``.
        cfg: layer sizes.

    Forward: ``observation [*B, num_obs]``, ``lidar [*B, R]`` -> ``hidden [*B, fusion_dim]``.
    """

    def __init__(self, num_obs: int, num_beams: int, cfg: ModelConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = num_obs
        for w in cfg.numeric_hidden:
            layers += [nn.Linear(width, w), nn.ELU()]
            width = w
        self.numeric = nn.Sequential(*layers)
        self.lidar = LidarEncoder(num_beams, cfg)
        self.fusion = nn.Sequential(
            nn.Linear(width + self.lidar.out_features, cfg.fusion_dim),
            nn.LayerNorm(cfg.fusion_dim),
            nn.ELU(),
        )

    def forward(self, observation: Tensor, lidar: Tensor) -> Tensor:
        batch = observation.shape[:-1]
        obs = observation.reshape(-1, observation.shape[-1])
        rng = lidar.reshape(-1, lidar.shape[-1])
        hidden = self.fusion(torch.cat([self.numeric(obs), self.lidar(rng)], dim=-1))
        return hidden.reshape(*batch, hidden.shape[-1])


class GaussianHead(nn.Module):
    """Action mean from the trunk and a state-independent std.

    Forward: ``hidden [*B, H]`` -> ``(loc [*B, A], scale [*B, A])``.
    """

    def __init__(self, hidden: int, action_dim: int, init_std: float, init_gain: float) -> None:
        super().__init__()
        self.mean = nn.Linear(hidden, action_dim)
        with torch.no_grad():
            self.mean.weight.mul_(init_gain)
            self.mean.bias.zero_()
        self.log_std = nn.Parameter(torch.full((action_dim,), math.log(init_std)))

    def forward(self, hidden: Tensor) -> tuple[Tensor, Tensor]:
        loc = self.mean(hidden)
        return loc, self.log_std.exp().expand_as(loc)


@dataclass
class ActorCritic:
    """The TorchRL operators built around one shared trunk.

    Attributes:
        model: the whole ``ActorValueOperator`` (trunk + both heads); its ``state_dict`` is the
            checkpointed model.
        actor: trunk + Gaussian head, writing "loc", "scale", "action" and "action_log_prob";
            the collector's policy.
        critic: trunk + value head, writing "state_value" (used by GAE).
        value_head: value head alone, reading "hidden" (used by the PPO loss after the actor pass
            wrote "hidden", so the trunk runs once per minibatch).
        gaussian: the Gaussian head module (holds ``log_std``).
    """

    model: ActorValueOperator
    actor: ProbabilisticTensorDictSequential
    critic: nn.Module
    value_head: ValueOperator
    gaussian: GaussianHead

    def action_std(self) -> Tensor:
        """Current policy std ``[A]`` in action units."""
        return self.gaussian.log_std.detach().exp()


def make_actor_critic(
    cfg: ModelConfig, num_obs: int, num_beams: int, action_dim: int = 2
) -> ActorCritic:
    """Build the paper's two-branch actor-critic.

    Args:
        cfg: layer sizes.
        num_obs: numeric observation size (key "observation").
        num_beams: LiDAR beam count (key "lidar"); the CNN output size follows it.
        action_dim: action size (key "action").
    """
    trunk = TensorDictModule(
        TwoBranchTrunk(num_obs, num_beams, cfg), in_keys=[OBS_KEY, LIDAR_KEY], out_keys=[HIDDEN_KEY]
    )
    gaussian = GaussianHead(cfg.fusion_dim, action_dim, cfg.init_std, cfg.actor_init_gain)
    head = TensorDictModule(
        gaussian,
        in_keys=[HIDDEN_KEY],
        out_keys=["loc", "scale"],
    )
    policy_head = ProbabilisticActor(
        head,
        in_keys=["loc", "scale"],
        out_keys=["action"],
        distribution_class=IndependentNormal,
        distribution_kwargs={"tanh_loc": False},
        return_log_prob=True,
    )
    value_head = ValueOperator(nn.Linear(cfg.fusion_dim, 1), in_keys=[HIDDEN_KEY])
    model = ActorValueOperator(trunk, policy_head, value_head)
    return ActorCritic(
        model=model,
        actor=model.get_policy_operator(),
        critic=model.get_value_operator(),
        value_head=value_head,
        gaussian=gaussian,
    )


def parameter_count(module: nn.Module) -> int:
    """Number of trainable scalars in ``module``."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
