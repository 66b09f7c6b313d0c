"""Config validation shared by every simulator config dataclass.

Bad input must fail before any work starts, with a message naming the field and the allowed range.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
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


# ---------------------------------------------------------------------------------- field specs
@dataclasses.dataclass(frozen=True)
class Spec:
    """What a config field accepts, and what it means (read by :func:`validate` and the docs).

    Attributes:
        lo, hi: allowed range of a number, of each end of a ``[min, max]`` pair, or of each
            element of a tuple; ``lo_open`` / ``hi_open`` make the bound strict.
        choices: allowed strings.
        min_len: fewest elements a variable-length tuple (``tuple[int, ...]``) may hold.
        unit: unit of the value (``"m"``, ``"rad/s"``, ``"-"``...).
        doc: one line saying what the field is.
        source: where the default comes from (``"paper"``, or a short reason).
    """

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    unit: str = ""
    doc: str = ""
    source: str = ""
    min_len: int = 1

    def range_text(self) -> str:
        if self.choices is not None:
            return " | ".join(self.choices)
        # infinite ends are never reached (values must be finite): shown open
        left = "(" if self.lo_open or math.isinf(self.lo) else "["
        right = ")" if self.hi_open or math.isinf(self.hi) else "]"
        return f"{left}{_num(self.lo)}, {_num(self.hi)}{right}"


def _num(x: float) -> str:
    return ("-inf" if x < 0 else "inf") if math.isinf(x) else f"{x:g}"


def param(
    default: Any = dataclasses.MISSING,
    *,
    lo: float = -math.inf,
    hi: float = math.inf,
    lo_open: bool = False,
    hi_open: bool = False,
    choices: Sequence[str] | None = None,
    unit: str = "",
    doc: str = "",
    source: str = "",
    min_len: int = 1,
) -> Any:
    """A dataclass field carrying its :class:`Spec`: the one place a default and its range live.

    Example::

        num_beams: int = param(16, lo=1, hi=4096, unit="-", doc="LiDAR beams R")
    """
    spec = Spec(
        lo, hi, lo_open, hi_open, tuple(choices) if choices else None, unit, doc, source, min_len
    )
    if isinstance(default, dict):  # a mutable default: each instance gets its own copy
        return dataclasses.field(default_factory=default.copy, metadata={"spec": spec})
    return dataclasses.field(default=default, metadata={"spec": spec})


def spec_of(cls: type, name: str) -> Spec | None:
    """The :class:`Spec` of field ``name`` of dataclass ``cls`` (None when it has none)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            return f.metadata.get("spec")
    raise KeyError(name)


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _check_scalar(name: str, value: Any, typ: Any, spec: Spec) -> Any:
    """Type- and range-check one value; returns it (ints stay ints, numbers become floats)."""
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} = {value!r} must be true or false")
        return value
    if typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"{name} = {value!r} must be a string")
        if spec.choices is not None:
            check_choice(name, value, spec.choices)
        return value
    if typ is int:
        # whole-valued floats (16.0, 1e3 from YAML) are accepted and stored as int
        if not (_is_number(value) and float(value).is_integer()):
            raise ConfigError(f"{name} = {value!r} must be a whole number in {spec.range_text()}")
        check_range(name, value, spec.lo, spec.hi, lo_open=spec.lo_open, hi_open=spec.hi_open)
        return int(value)
    if typ is float:
        if not _is_number(value):
            raise ConfigError(f"{name} = {value!r} must be a number in {spec.range_text()}")
        return check_range(
            name, value, spec.lo, spec.hi, lo_open=spec.lo_open, hi_open=spec.hi_open
        )
    return value


def _check_value(name: str, value: Any, typ: Any, spec: Spec) -> Any:
    origin, args = typing.get_origin(typ), typing.get_args(typ)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _check_value(name, value, inner, spec)
    # free-form overrides (FIELD=VALUE): checked where they are applied
    if origin is dict or typ is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{name} = {value!r} must be FIELD=VALUE overrides")
        return value
    if origin is tuple:
        if isinstance(value, str) or not isinstance(value, Sequence):
            raise ConfigError(f"{name} = {value!r} must be a list")
        if len(args) == 2 and args[1] is Ellipsis:
            if len(value) < spec.min_len:
                least = "one value" if spec.min_len == 1 else f"{spec.min_len} values"
                raise ConfigError(f"{name} = {list(value)!r} must list at least {least}")
            return tuple(
                _check_scalar(f"{name}[{i}]", v, args[0], spec) for i, v in enumerate(value)
            )
        if len(value) != len(args):
            what = "a [min, max] pair" if len(args) == 2 else f"a list of {len(args)} values"
            raise ConfigError(f"{name} = {list(value)!r} must be {what}")
        out = tuple(
            _check_scalar(f"{name}[{i}]", v, t, spec)
            for i, (v, t) in enumerate(zip(value, args, strict=True))
        )
        if len(out) == 2 and out[0] > out[1]:
            raise ConfigError(f"{name} = {list(out)}: min must not exceed max")
        return out
    return _check_scalar(name, value, typ, spec)


def validate(obj: Any, where: str = "") -> None:
    """Check every field of dataclass ``obj`` (recursing into nested ones) against its type and
    :class:`Spec`; normalise lists to tuples in place.

    Errors name the full dotted field (``where`` + field name) and the allowed range or type.

    Raises:
        ConfigError: the first bad value found.
    """
    hints = _hints(type(obj))
    for f in dataclasses.fields(obj):
        name = f"{where}.{f.name}" if where else f.name
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            validate(value, name)
            continue
        hint = hints[f.name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            object.__setattr__(obj, f.name, build(hint, value, name))
            continue
        spec = f.metadata.get("spec")
        if spec is None:
            continue
        checked = _check_value(name, value, hints[f.name], spec)
        if checked is not value:
            object.__setattr__(obj, f.name, checked)


def spec_table(cls: type, where: str = "") -> list[tuple[str, str, str, str, str]]:
    """Rows ``(dotted name, default, unit, allowed, meaning)`` of ``cls`` and nested configs.

    The docs print this table (``truckrl tools configs``) instead of copying the defaults.
    """
    rows = []
    for f in dataclasses.fields(cls):
        name = f"{where}.{f.name}" if where else f.name
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default):
            rows += spec_table(type(default), name)
            continue
        spec = f.metadata.get("spec") or Spec()
        shown = list(default) if isinstance(default, tuple) else default
        doc = spec.doc + (f" ({spec.source})" if spec.source else "")
        rows.append((name, str(shown), spec.unit, _allowed_text(_hints(cls)[f.name], spec), doc))
    return rows


def build(cls: type[T], data: Any = None, where: str = "") -> T:
    """Build config dataclass ``cls`` from a plain mapping, recursing into nested config fields.

    The one way configs are made from data: Hydra's composed config (as a container), a
    checkpoint's saved config and user dicts all come through here. Unknown keys, a non-mapping
    where a nested config belongs, and bad values (via the classes' :func:`validate`) raise
    :class:`ConfigError` naming the dotted field.
    """
    if data is None:
        return cls()
    if isinstance(data, cls):
        return data
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where or cls.__name__} must be a group of fields, got {data!r}")
    hints = _hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data.keys()) - names)
    if unknown:
        raise ConfigError(
            f"unknown field(s) {unknown} for {where or cls.__name__}; known: {sorted(names)}"
        )
    kwargs = {}
    for k, v in data.items():
        t = hints[k]
        name = f"{where}.{k}" if where else k
        kwargs[k] = build(t, v, name) if dataclasses.is_dataclass(t) else v
    try:
        return cls(**kwargs)
    except TypeError as e:  # a required field is missing
        raise ConfigError(f"{where or cls.__name__}: {e}") from None


def _allowed_text(typ: Any, spec: Spec) -> str:
    """The "allowed" column of :func:`spec_table` for a field of type ``typ``."""
    args = typing.get_args(typ)
    if typing.get_origin(typ) in (typing.Union, types.UnionType) and type(None) in args:
        (inner,) = [a for a in args if a is not type(None)]
        return f"{_allowed_text(inner, spec)} or null"
    if typ is bool:
        return "true | false"
    if typ is dict or typing.get_origin(typ) is dict:
        return "FIELD=VALUE, ..."
    return spec.range_text()
