"""truckrl: batched articulated-truck simulator and PPO training on TorchRL.

The public API, importable from the package itself::

    from truckrl import TruckEnv, evaluate_policy, load_policy, make_env

Each name is imported on first use (PEP 562 module ``__getattr__``), so ``import truckrl`` and
``truckrl --help`` load no torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"  # the one copy: pyproject.toml reads it (tool.setuptools.dynamic)

#: public name -> the module that defines it.
_EXPORTS = {
    "TruckEnv": "truckrl.env.truck_env",
    "make_env": "truckrl.env.make",
    "load_policy": "truckrl.rl.policy",
    "evaluate_policy": "truckrl.evaluation.rollout",
}

__all__ = ["TruckEnv", "__version__", "evaluate_policy", "load_policy", "make_env"]

if TYPE_CHECKING:  # the same names for type checkers, which do not run __getattr__
    from truckrl.env.make import make_env
    from truckrl.env.truck_env import TruckEnv
    from truckrl.evaluation.rollout import evaluate_policy
    from truckrl.rl.policy import load_policy


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    """The public names and the module's own dunders (not its imports)."""
    return sorted({n for n in globals() if n.startswith("__")} | set(__all__))
