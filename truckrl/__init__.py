"""truckrl: batched articulated-truck simulator and PPO training on TorchRL."""

__version__ = "0.1.0"
