"""The config framework: typed fields with ranges, units and sources, one loader, one error type.

:mod:`truckrl.config.fields` is pure Python (every layer may use it, ``sim`` included);
:mod:`truckrl.config.schemas` holds the entry points' schemas and registers them with Hydra.
"""

from truckrl.config.fields import ConfigError, build, check_range, param, validate

__all__ = ["ConfigError", "build", "check_range", "param", "validate"]
