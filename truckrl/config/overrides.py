"""``KEY=VALUE`` arguments into a config dataclass: the argument style of every command whose
config is one dataclass rather than a composed Hydra config (``bench``, ``tools ...``).

Keys are dotted field paths; values are read as YAML (``3``, ``1e-4``, ``[1,2]``, ``null``,
``true``), except where the field is a string: there the text is kept as written, so ``on`` and
``off`` stay words instead of becoming YAML 1.1 booleans.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, TypeVar

import yaml

from truckrl.config.fields import ConfigError, build

T = TypeVar("T")


def _field_type(schema: type, parts: list[str]) -> Any:
    """The annotated type of the dotted field ``parts`` of ``schema``, or None where the path
    leaves the dataclasses (a free-form dict field, an unknown key: ``build`` reports those)."""
    typ: Any = schema
    for part in parts:
        if not dataclasses.is_dataclass(typ):
            return None
        typ = typing.get_type_hints(typ).get(part)
        args = typing.get_args(typ)
        if typing.get_origin(typ) in (typing.Union, types.UnionType) and type(None) in args:
            (typ,) = [a for a in args if a is not type(None)] or [None]
    return typ


def _value(schema: type, parts: list[str], text: str) -> Any:
    if _field_type(schema, parts) is str and text not in ("null", "~"):
        return text
    try:
        return yaml.safe_load(text) if text else ""
    except yaml.YAMLError:
        return text


def parse_key_values(schema: type[T], argv: list[str]) -> T:
    """A validated ``schema`` instance from ``KEY=VALUE`` arguments.

    Raises:
        ConfigError: a malformed argument, an unknown key or a bad value, in one line.
    """
    data: dict[str, Any] = {}
    for arg in argv:
        key, sep, text = arg.partition("=")
        if not sep or not key or not all(p.isidentifier() for p in key.split(".")):
            raise ConfigError(f"{arg!r}: arguments are KEY=VALUE")
        node = data
        *parents, leaf = parts = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{key}: {part} is a value, not a group of fields")
        node[leaf] = _value(schema, parts, text)
    return build(schema, data)
