"""``KEY=VALUE`` arguments (truckrl.config.overrides): typed by the schema's fields."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from truckrl.config.fields import ConfigError, param, validate
from truckrl.config.overrides import parse_key_values


@dataclass
class Inner:
    mode: str = param("on", choices=("on", "off", "both"), doc="a word that YAML would misread")
    rate: float = param(0.5, lo=0.0, hi=1.0, doc="a number")

    def __post_init__(self) -> None:
        validate(self, "inner")


@dataclass
class Outer:
    compile: str = param("both", choices=("on", "off", "both"), doc="a word")
    out: str | None = param(None, doc="a path or null")
    quick: bool = param(False, doc="a flag")
    sizes: tuple[int, ...] = param((1, 2), doc="a list")
    inner: Inner = field(default_factory=Inner)

    def __post_init__(self) -> None:
        validate(self)


def test_words_stay_words_in_string_fields_and_yaml_elsewhere():
    cfg = parse_key_values(
        Outer, ["compile=off", "out=2026", "quick=true", "sizes=[4,8]", "inner.mode=off"]
    )
    assert cfg.compile == "off" and cfg.inner.mode == "off"  # YAML 1.1 would give False
    assert cfg.out == "2026"  # a path that looks like a number stays a string
    assert cfg.quick is True and tuple(cfg.sizes) == (4, 8)
    assert parse_key_values(Outer, ["out=null"]).out is None
    assert parse_key_values(Outer, ["inner.rate=0.25"]).inner.rate == 0.25


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--quick"], r"'--quick': arguments are KEY=VALUE"),
        (["compile"], r"arguments are KEY=VALUE"),
        (["speed=3"], r"unknown field\(s\) \['speed'\]"),
        (["inner.rate=2"], r"inner.rate = 2 is outside the allowed range \[0.0, 1.0\]"),
        (["compile=fast"], r"compile = 'fast' is not one of"),
        (["quick=true", "quick.x=1"], r"quick.x: quick is a value, not a group of fields"),
    ],
)
def test_bad_arguments_are_one_line(argv, match):
    with pytest.raises(ConfigError, match=match):
        parse_key_values(Outer, argv)
