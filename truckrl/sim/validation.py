"""Config validation shared by every simulator config dataclass.

Bad input must fail before any work starts, with a message naming the field and the allowed range.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value is missing, unknown or outside its allowed range."""


def check_range(
    name: str,
    value: float,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """Check ``lo <= value <= hi`` (or strict where ``*_open``); return ``value`` as float.

    Raises:
        ConfigError: naming ``name``, the value and the allowed range.
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a number, got {value!r}") from None
    too_low = v <= lo if lo_open else v < lo
    too_high = v >= hi if hi_open else v > hi
    if not math.isfinite(v) or too_low or too_high:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        raise ConfigError(
            f"{name} = {value!r} is outside the allowed range {left}{lo}, {hi}{right}"
        )
    return v


def check_interval(
    name: str, interval: Any, lo: float = -math.inf, hi: float = math.inf
) -> tuple[float, float]:
    """Check a ``[min, max]`` pair lies in ``[lo, hi]`` with ``min <= max``; return it as a tuple.

    Raises:
        ConfigError: naming ``name`` when the pair is malformed, reversed or out of range.
    """
    try:
        a, b = (float(x) for x in interval)
    except (TypeError, ValueError):
        raise ConfigError(
            f"{name} must be a [min, max] pair of numbers, got {interval!r}"
        ) from None
    check_range(f"{name}[0] (min)", a, lo, hi)
    check_range(f"{name}[1] (max)", b, lo, hi)
    if a > b:
        raise ConfigError(f"{name} = [{a}, {b}]: min must not exceed max")
    return a, b


def check_choice(name: str, value: Any, allowed: tuple[str, ...]) -> str:
    """Check ``value`` is one of ``allowed``; return it."""
    if value not in allowed:
        raise ConfigError(f"{name} = {value!r} is not one of {list(allowed)}")
    return value


def from_mapping(cls: type[T], data: Mapping[str, Any] | T | None, where: str = "") -> T:
    """Build dataclass ``cls`` from a mapping (e.g. a Hydra/OmegaConf node), rejecting unknown keys.

    Already-built instances pass through. ``where`` prefixes field names in error messages.
    """
    if data is None:
        return cls()
    if isinstance(data, cls):
        return data
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data.keys()) - names)
    if unknown:
        raise ConfigError(
            f"unknown field(s) {unknown} for {where or cls.__name__}; known: {sorted(names)}"
        )
    kwargs = {
        k: tuple(v) if isinstance(v, Sequence) and not isinstance(v, str) else v
        for k, v in data.items()
    }
    return cls(**kwargs)
