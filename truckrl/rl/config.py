"""Config schemas of the agent (``ppo.*`` and ``model.*``), importable without torch.

They live apart from :mod:`truckrl.rl.ppo` and :mod:`truckrl.rl.network` so that a config
can be composed, validated and printed (``--help``, ``--cfg job``, a rejected value) before
the heavy libraries are imported. Both modules re-export them.
"""

from __future__ import annotations

from dataclasses import dataclass

from truckrl.config.fields import ConfigError, check_range, param, validate


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of the two-branch network (``model.*``; the defaults are the paper's)."""

    numeric_hidden: tuple[int, ...] = param(
        (128, 64), lo=1, hi=1e6, unit="-", doc="widths of the numeric MLP layers", source="paper"
    )
    cnn_channels: tuple[int, ...] = param(
        (2, 4),
        lo=1,
        hi=1e4,
        min_len=0,
        unit="-",
        doc="output channels of each LiDAR conv layer (none: raw ranges)",
        source="paper",
    )
    kernel_size: int = param(
        5,
        lo=1,
        hi=101,
        unit="beams",
        doc="conv kernel size; odd, so circular padding is symmetric",
        source="paper",
    )
    stride: int = param(2, lo=1, hi=16, unit="beams", doc="conv stride", source="paper")
    fusion_dim: int = param(
        64, lo=1, hi=1e6, unit="-", doc='width of the fused trunk output "hidden"', source="paper"
    )
    init_std: float = param(
        0.5,
        lo=0.0,
        lo_open=True,
        hi=100.0,
        unit="action units",
        doc="initial std of the Gaussian policy",
        source="paper",
    )
    max_std: float | None = param(
        None,
        lo=0.0,
        lo_open=True,
        hi=100.0,
        unit="action units",
        doc="upper bound on the policy std (null: none, the paper's); the env clamps actions to "
        "[-1, 1], so without a bound the entropy bonus can grow the std without cost",
    )
    # small, so that the first actions are set by the exploration noise, not by random weights
    actor_init_gain: float = param(
        0.01, lo=0.0, lo_open=True, hi=10.0, unit="-", doc="scale of the initial actor-mean weights"
    )

    def __post_init__(self) -> None:
        validate(self, "model")
        if self.kernel_size % 2 != 1:
            raise ConfigError(f"model.kernel_size = {self.kernel_size} must be odd")
        if self.max_std is not None and self.init_std > self.max_std:
            raise ConfigError(
                f"model.init_std = {self.init_std} must be <= model.max_std = {self.max_std}"
            )


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters (``ppo.*``; the defaults are the paper's numbers, ``ppo=fast`` a preset).

    With the adaptive schedule, ``lr`` must lie in ``[lr_min, lr_max]``; ``num_minibatches`` must
    divide the batch size (:meth:`check_batch`).
    """

    lr: float = param(
        1e-4,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        unit="-",
        doc="initial Adam learning rate",
        source="paper",
    )
    lr_schedule: str = param(
        "adaptive",
        choices=("adaptive", "fixed"),
        unit="-",
        doc="adaptive (RSL-RL KL rule) or fixed learning rate",
        source="paper",
    )
    desired_kl: float = param(
        0.01,
        lo=0.0,
        lo_open=True,
        hi=10.0,
        unit="nats",
        doc="KL target of the adaptive schedule",
        source="paper",
    )
    lr_min: float = param(
        1e-5, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="lower clamp of the adaptive lr"
    )
    lr_max: float = param(
        1e-2,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        unit="-",
        doc="upper clamp of the adaptive lr; >= lr_min",
    )
    num_epochs: int = param(
        8, lo=1, hi=1000, unit="-", doc="passes over each batch", source="paper"
    )
    num_minibatches: int = param(
        96,
        lo=1,
        hi=1e7,
        unit="-",
        doc="minibatches per epoch; divides the batch size",
        source="paper",
    )
    gamma: float = param(0.99, lo=0.0, hi=1.0, unit="-", doc="discount", source="paper")
    lmbda: float = param(0.95, lo=0.0, hi=1.0, unit="-", doc="GAE lambda", source="paper")
    clip_epsilon: float = param(
        0.2, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="policy ratio clip", source="paper"
    )
    entropy_coeff: float = param(
        0.005, lo=0.0, hi=10.0, unit="-", doc="entropy bonus weight", source="paper"
    )
    value_coeff: float = param(
        0.5, lo=0.0, hi=100.0, unit="-", doc="critic loss weight", source="paper"
    )
    max_grad_norm: float = param(
        4.0, lo=0.0, lo_open=True, hi=1e6, unit="-", doc="gradient-norm clip", source="paper"
    )
    clip_value: bool = param(
        True,
        unit="-",
        doc="clip the value update to clip_epsilon around the rollout value",
        source="RSL-RL",
    )
    normalize_advantage: bool = param(
        True, unit="-", doc="standardise advantages over the whole batch", source="RSL-RL"
    )
    loss_critic_type: str = param(
        "l2",
        choices=("l2", "l1", "smooth_l1"),
        unit="-",
        doc="critic loss: l2 (squared error), l1 or smooth_l1",
        source="RSL-RL",
    )
    compile: bool = param(
        False,
        unit="-",
        doc="torch.compile the minibatch loss, forward and backward (compiled once per process; "
        "removes per-call overhead, which dominates small minibatches on a CPU)",
    )

    def __post_init__(self) -> None:
        validate(self, "ppo")
        if self.lr_max < self.lr_min:
            raise ConfigError(
                f"ppo.lr_max = {self.lr_max} must be at least ppo.lr_min = {self.lr_min}"
            )
        if self.lr_schedule == "adaptive":
            check_range("ppo.lr", self.lr, self.lr_min, self.lr_max)

    def check_batch(self, batch_size: int) -> int:
        """Check ``num_minibatches`` divides ``batch_size`` frames; return the minibatch size."""
        if batch_size % int(self.num_minibatches) != 0 or batch_size < self.num_minibatches:
            raise ConfigError(
                f"ppo.num_minibatches = {self.num_minibatches} must divide the batch of "
                f"{batch_size} frames (collector.workers x env.num_envs x collector.steps_per_env)"
            )
        return batch_size // int(self.num_minibatches)
