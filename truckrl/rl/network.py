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
from tensordict.nn import ProbabilisticTensorDictSequential, TensorDictModule, TensorDictSequential
from torch import Tensor, nn
from torchrl.modules import ActorValueOperator, IndependentNormal, ProbabilisticActor, ValueOperator

from truckrl.config.fields import ConfigError
from truckrl.env import LIDAR_KEY, OBS_KEY
from truckrl.rl.config import ModelConfig

HIDDEN_KEY = "hidden"
#: What :attr:`ActorCritic.rollout_policy` writes into each collected step.
ROLLOUT_KEYS = ["loc", "scale", "action", "action_log_prob", "state_value"]


def conv_out_len(length: int, kernel_size: int, stride: int) -> int:
    """Length after one circularly padded conv layer (padding ``kernel_size // 2`` each side)."""
    return (length + 2 * (kernel_size // 2) - kernel_size) // stride + 1


def circular_conv_index(
    in_channels: int, out_channels: int, length: int, kernel_size: int, stride: int
) -> tuple[Tensor, int]:
    """Where each weight of a circularly padded ``Conv1d`` lands in its dense matrix.

    A ``Conv1d(in_channels, out_channels, kernel_size, stride, padding=kernel_size // 2,
    padding_mode="circular")`` on a ring of ``length`` positions is the linear map
    ``y.flatten(1) = x.flatten(1) @ M + bias.repeat_interleave(L_out)`` with ``M`` of shape
    ``[in_channels * length, out_channels * L_out]``, channel-major on both sides. Entry
    ``M[c * length + i, o * L_out + j]`` is ``weight[o, c, t]`` when input position ``i`` is
    tap ``t`` of output ``j`` (``i = (j * stride + t - pad) mod length``), else 0.

    Returns:
        ``(index [in_channels * length, out_channels * L_out] long, L_out)``: ``index`` is
        ``1 + (flat position in weight)`` or 0 for a structural zero, so
        ``cat([0], weight.flatten())[index]`` is ``M``.

    Raises:
        ValueError: two taps of one output wrap onto the same input (``length < kernel_size``);
            their weights would have to add, which one index per entry cannot express, so
            :class:`LidarEncoder` then calls the convolution itself.
    """
    pad = kernel_size // 2
    l_out = conv_out_len(length, kernel_size, stride)
    o, c, j, t = torch.meshgrid(
        torch.arange(out_channels), torch.arange(in_channels), torch.arange(l_out),
        torch.arange(kernel_size), indexing="ij",
    )  # fmt: skip
    i = (j * stride + t - pad) % length
    rows = (c * length + i).flatten()
    cols = (o * l_out + j).flatten()
    flat = (o * in_channels * kernel_size + c * kernel_size + t).flatten() + 1
    index = torch.zeros(in_channels * length, out_channels * l_out, dtype=torch.long)
    if (torch.bincount(rows * index.shape[1] + cols, minlength=index.numel()) > 1).any():
        raise ValueError("taps collide: use the convolution itself for rings shorter than k")
    index[rows, cols] = flat
    return index, l_out


class LidarEncoder(nn.Module):
    """1D CNN over the beam ring; circular padding keeps beams at -pi and +pi adjacent.

    Input ``[N, R]`` ranges / 50 m; output ``[N, C_last * L_last]``.

    The layers are ``nn.Conv1d`` modules (their parameters are the checkpoint's), but the forward
    pass multiplies by each layer's dense ring matrix (:func:`circular_conv_index`) instead of
    calling the convolution: with 1-4 channels on tens of beams, one ``addmm`` forward and backward
    costs less on a CPU than the oneDNN convolution, and the results agree to float rounding
    (``tests/rl/test_network.py`` checks it against ``Conv1d``). A ring shorter than the kernel
    (taps wrapping twice) falls back to the convolution.
    """

    def __init__(self, num_beams: int, cfg: ModelConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        in_ch, length = 1, num_beams
        pad = cfg.kernel_size // 2
        self._dense: list[bool] = []
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
            try:
                index, _ = circular_conv_index(in_ch, out_ch, length, cfg.kernel_size, cfg.stride)
                dense = True
            except ValueError:
                index, dense = torch.zeros(0, dtype=torch.long), False
            # derived from the shapes, not state: left out of the state_dict (checkpoints unchanged)
            self.register_buffer(f"_index{i}", index, persistent=False)
            self._dense.append(dense)
            in_ch, length = out_ch, conv_out_len(length, cfg.kernel_size, cfg.stride)
        self.net = nn.Sequential(*layers)
        self.out_features = in_ch * length

    def forward(self, lidar: Tensor) -> Tensor:
        if not all(self._dense):
            return self.net(lidar.unsqueeze(1)).flatten(1)
        x = lidar
        for i in range(len(self._dense)):
            conv: nn.Conv1d = self.net[2 * i]  # type: ignore[assignment]
            index: Tensor = getattr(self, f"_index{i}")
            weight = torch.cat([conv.weight.new_zeros(1), conv.weight.flatten()])[index]
            bias = conv.bias.repeat_interleave(index.shape[1] // conv.out_channels)
            x = self.net[2 * i + 1](torch.addmm(bias, x, weight))
        return x


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

    def __init__(
        self,
        hidden: int,
        action_dim: int,
        init_std: float,
        init_gain: float,
        max_std: float | None = None,
    ) -> None:
        super().__init__()
        self.mean = nn.Linear(hidden, action_dim)
        with torch.no_grad():
            self.mean.weight.mul_(init_gain)
            self.mean.bias.zero_()
        self.log_std = nn.Parameter(torch.full((action_dim,), math.log(init_std)))
        self.max_log_std = None if max_std is None else math.log(max_std)

    def effective_log_std(self) -> Tensor:
        """``log_std`` ``[A]`` bounded above by ``log(max_std)`` (as is without a bound)."""
        if self.max_log_std is None:
            return self.log_std
        return self.log_std.clamp(max=self.max_log_std)

    @torch.no_grad()
    def project_(self) -> None:
        """Clamp the ``log_std`` parameter itself into its bound, so that a parameter above it
        (a loaded checkpoint's) does not sit where the clamp passes no gradient. The optimiser
        calls it after each step."""
        if self.max_log_std is not None:
            self.log_std.clamp_(max=self.max_log_std)

    def forward(self, hidden: Tensor) -> tuple[Tensor, Tensor]:
        loc = self.mean(hidden)
        return loc, self.effective_log_std().exp().expand_as(loc)


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
        rollout_policy: trunk + both heads in one pass, writing the actor's entries and
            "state_value" (not "hidden"); the collectors' policy, so GAE reads the values of the
            collected observations instead of running the critic over the batch again.
    """

    model: ActorValueOperator
    actor: ProbabilisticTensorDictSequential
    critic: nn.Module
    value_head: ValueOperator
    gaussian: GaussianHead
    rollout_policy: TensorDictSequential

    def action_std(self) -> Tensor:
        """Current policy std ``[A]`` in action units."""
        return self.gaussian.effective_log_std().detach().exp()


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
    encoder = TwoBranchTrunk(num_obs, num_beams, cfg)
    trunk = TensorDictModule(encoder, in_keys=[OBS_KEY, LIDAR_KEY], out_keys=[HIDDEN_KEY])
    gaussian = GaussianHead(
        cfg.fusion_dim, action_dim, cfg.init_std, cfg.actor_init_gain, cfg.max_std
    )
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
        rollout_policy=TensorDictSequential(
            trunk, policy_head, value_head, selected_out_keys=ROLLOUT_KEYS
        ),
    )


def parameter_count(module: nn.Module) -> int:
    """Number of trainable scalars in ``module``."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
