"""The field-spec validator: types, ranges, dotted names, and the generated spec table."""

from __future__ import annotations

import dataclasses
import math

import pytest

from truckrl.config.fields import ConfigError, Spec, param, spec_of, spec_table, validate
from truckrl.rl.curriculum import CurriculumConfig
from truckrl.rl.network import ModelConfig
from truckrl.rl.ppo import PPOConfig
from truckrl.sim.control import ControlConfig
from truckrl.sim.lidar import LidarConfig
from truckrl.sim.vehicle import VehicleConfig
from truckrl.tasks.intersection.scene import SceneConfig
from truckrl.viz.keyboard import KeyboardConfig


@dataclasses.dataclass
class Inner:
    count: int = param(3, lo=1, hi=10, unit="-", doc="how many")
    gain: float = param(0.5, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="a gain")

    def __post_init__(self) -> None:
        validate(self, "outer.inner")


@dataclasses.dataclass
class Outer:
    flag: bool = param(True, doc="a switch")
    mode: str = param("a", choices=("a", "b"), doc="a mode")
    span: tuple[float, float] = param(
        (1.0, 2.0), lo=0.0, hi=5.0, hi_open=True, unit="m", doc="a range", source="paper"
    )
    widths: tuple[int, ...] = param((4, 8), lo=1, hi=100, doc="layer widths")
    maybe_empty: tuple[int, ...] = param((), lo=1, hi=100, min_len=0, doc="optional layers")
    cap: float | None = param(None, lo=0.0, hi=30.0, doc="optional cap")
    inner: Inner = dataclasses.field(default_factory=Inner)
    plain: object = None  # no spec: not checked


@dataclasses.dataclass(frozen=True)
class Frozen:
    size: int = param(2, lo=1, hi=4)
    widths: tuple[int, ...] = param((1, 2), lo=1, hi=4)

    def __post_init__(self) -> None:
        validate(self, "frozen")


def check(**kwargs) -> Outer:
    obj = Outer(**kwargs)
    validate(obj, "outer")
    return obj


def test_defaults_pass_and_keep_their_types():
    obj = check()
    assert obj.span == (1.0, 2.0) and obj.widths == (4, 8) and obj.maybe_empty == ()
    assert obj.cap is None and obj.inner.count == 3


# ------------------------------------------------------------------------------------- ints
@pytest.mark.parametrize("bad", [2.5, 1e-3, math.nan, math.inf, "3", True, None])
def test_int_rejects_non_whole_numbers_strings_bools(bad):
    with pytest.raises(ConfigError, match=r"outer\.inner\.count .*whole number in \[1, 10\]"):
        Inner(count=bad)


def test_int_accepts_whole_floats_as_int():
    obj = Inner(count=4.0)
    assert obj.count == 4 and type(obj.count) is int


@pytest.mark.parametrize(("value", "ok"), [(0, False), (1, True), (10, True), (11, False)])
def test_int_closed_bounds(value, ok):
    if ok:
        assert Inner(count=value).count == value
    else:
        with pytest.raises(ConfigError, match=r"outer\.inner\.count = .* \[1, 10\]"):
            Inner(count=value)


# ----------------------------------------------------------------------------------- floats
@pytest.mark.parametrize("bad", ["0.5", True, False, None, [0.5]])
def test_float_rejects_strings_bools_and_none(bad):
    with pytest.raises(ConfigError, match=r"outer\.inner\.gain .*must be a number in \(0, 1\]"):
        Inner(gain=bad)


@pytest.mark.parametrize(
    ("value", "ok"), [(0.0, False), (1e-12, True), (1.0, True), (1.0 + 1e-9, False)]
)
def test_float_open_and_closed_bounds(value, ok):
    if ok:
        assert Inner(gain=value).gain == value
    else:
        with pytest.raises(ConfigError, match=r"outer\.inner\.gain = .*\(0(\.0)?, 1(\.0)?\]"):
            Inner(gain=value)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_float_rejects_non_finite(bad):
    with pytest.raises(ConfigError, match=r"outer\.inner\.gain"):
        Inner(gain=bad)


def test_int_given_to_float_becomes_float():
    obj = Inner(gain=1)
    assert obj.gain == 1.0 and type(obj.gain) is float


# ------------------------------------------------------------------------- bools and strings
@pytest.mark.parametrize("bad", [1, 0, "true", None])
def test_bool_must_be_true_or_false(bad):
    with pytest.raises(ConfigError, match=r"outer\.flag = .* must be true or false"):
        check(flag=bad)


def test_choice_names_the_allowed_values():
    with pytest.raises(ConfigError, match=r"outer\.mode = 'c' is not one of \['a', 'b'\]"):
        check(mode="c")
    with pytest.raises(ConfigError, match=r"outer\.mode = 1 must be a string"):
        check(mode=1)


# ------------------------------------------------------------------------------------ pairs
def test_pair_list_becomes_tuple():
    obj = check(span=[0.0, 1])
    assert obj.span == (0.0, 1.0) and isinstance(obj.span, tuple)


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ((2.0, 1.0), r"outer\.span = \[2\.0, 1\.0\]: min must not exceed max"),
        ((1.0, 5.0), r"outer\.span\[1\] = 5\.0 is outside the allowed range \[0\.0, 5\.0\)"),
        ((-1.0, 1.0), r"outer\.span\[0\] = -1\.0 is outside the allowed range \[0\.0, 5\.0\)"),
        ((1.0,), r"outer\.span = \[1\.0\] must be a \[min, max\] pair"),
        ((1.0, 2.0, 3.0), r"must be a \[min, max\] pair"),
        ("12", r"outer\.span = '12' must be a list"),
        (3.0, r"outer\.span = 3\.0 must be a list"),
        (("1", 2.0), r"outer\.span\[0\] = '1' must be a number"),
        ((True, 2.0), r"outer\.span\[0\] = True must be a number"),
    ],
)
def test_bad_pairs(bad, message):
    with pytest.raises(ConfigError, match=message):
        check(span=bad)


# ---------------------------------------------------------------------- variable-length tuples
def test_tuple_elements_checked_and_named_by_index():
    assert check(widths=[1, 2.0, 100]).widths == (1, 2, 100)
    with pytest.raises(ConfigError, match=r"outer\.widths\[1\] = 2\.5 must be a whole number"):
        check(widths=[1, 2.5])
    with pytest.raises(ConfigError, match=r"outer\.widths\[2\] = 101 is outside .*\[1, 100\]"):
        check(widths=(1, 2, 101))


def test_tuple_length_floor():
    with pytest.raises(ConfigError, match=r"outer\.widths = \[\] must list at least one value"):
        check(widths=[])
    assert check(maybe_empty=[]).maybe_empty == ()
    with pytest.raises(ConfigError, match=r"outer\.maybe_empty\[0\] = 0"):
        check(maybe_empty=[0])


# ---------------------------------------------------------------------------------- optional
def test_optional_accepts_none_and_checks_values():
    assert check(cap=None).cap is None
    assert check(cap=3).cap == 3.0
    with pytest.raises(
        ConfigError, match=r"outer\.cap = 31\.0 is outside the allowed range \[0\.0, 30\.0\]"
    ):
        check(cap=31.0)
    with pytest.raises(ConfigError, match=r"outer\.cap = 'x' must be a number"):
        check(cap="x")


# --------------------------------------------------------------------------- nesting, frozen
def test_nested_dataclass_errors_name_the_dotted_field():
    obj = Outer()
    object.__setattr__(obj.inner, "count", 0)  # bypass Inner's own check
    with pytest.raises(ConfigError, match=r"^top\.inner\.count = 0 "):
        validate(obj, "top")


def test_no_prefix_names_the_bare_field():
    obj = Inner()
    obj.gain = 2.0
    with pytest.raises(ConfigError, match=r"^gain = 2\.0 "):
        validate(obj)


def test_fields_without_spec_are_not_checked():
    assert check(plain="anything").plain == "anything"


def test_frozen_dataclass_is_normalised():
    obj = Frozen(size=3.0, widths=[2, 3])
    assert obj.size == 3 and obj.widths == (2, 3)
    with pytest.raises(ConfigError, match=r"frozen\.size"):
        Frozen(size=5)


# ---------------------------------------------------------------------------------- spec table
def test_spec_table_rows():
    rows = {r[0]: r for r in spec_table(Outer, "outer")}
    assert rows["outer.span"] == ("outer.span", "[1.0, 2.0]", "m", "[0, 5)", "a range (paper)")
    assert rows["outer.mode"][3] == "a | b"
    assert rows["outer.inner.gain"] == ("outer.inner.gain", "0.5", "-", "(0, 1]", "a gain")
    assert rows["outer.cap"][1:4] == ("None", "", "[0, 30] or null")
    assert rows["outer.flag"][1:4] == ("True", "", "true | false")
    assert rows["outer.widths"][1:4] == ("[4, 8]", "", "[1, 100]")
    assert rows["outer.plain"][3] == "(-inf, inf)"  # no spec: an empty one; infinite ends open
    assert list(rows)[-3:] == ["outer.inner.count", "outer.inner.gain", "outer.plain"]


def test_spec_of():
    assert spec_of(Outer, "plain") is None
    assert spec_of(Outer, "span") == Spec(0.0, 5.0, False, True, None, "m", "a range", "paper")
    with pytest.raises(KeyError):
        spec_of(Outer, "nope")


# --------------------------------------------------------------------- the converted configs
CONFIGS = [
    (VehicleConfig, "env.vehicle"),
    (SceneConfig, "env.task.scene"),
    (LidarConfig, "env.lidar"),
    (ControlConfig, "control"),
    (PPOConfig, "ppo"),
    (ModelConfig, "model"),
    (CurriculumConfig, "curriculum"),
    (KeyboardConfig, "keyboard"),
]


@pytest.mark.parametrize(("cls", "prefix"), CONFIGS)
def test_every_config_field_has_a_documented_spec(cls, prefix):
    for f in dataclasses.fields(cls):
        spec = spec_of(cls, f.name)
        assert spec is not None and spec.doc and spec.unit, f"{cls.__name__}.{f.name}"
    rows = spec_table(cls, prefix)
    assert [r[0] for r in rows] == [f"{prefix}.{f.name}" for f in dataclasses.fields(cls)]
    validate(cls(), prefix)  # the defaults satisfy their own specs


@pytest.mark.parametrize(("cls", "prefix"), CONFIGS)
def test_every_config_names_its_prefix_in_errors(cls, prefix):
    for f in dataclasses.fields(cls):
        with pytest.raises(ConfigError) as info:
            cls(**{f.name: "bad" if spec_of(cls, f.name).choices is None else 7})
        assert str(info.value).startswith(f"{prefix}.{f.name}"), str(info.value)


@dataclasses.dataclass
class _Overrides:
    changes: dict = param({}, doc="FIELD=VALUE changes")


def test_dict_field_takes_a_mapping_and_each_instance_gets_its_own():
    a, b = _Overrides(), _Overrides()
    a.changes["x"] = 1
    assert b.changes == {} and _Overrides(changes={"y": {"z": 2}}).changes == {"y": {"z": 2}}
    validate(_Overrides(changes={"k": 1}))
    with pytest.raises(ConfigError, match=r"^changes = 3 must be FIELD=VALUE overrides$"):
        validate(_Overrides(changes=3))
    row = spec_table(_Overrides)[0]
    assert row[0] == "changes" and row[3] == "FIELD=VALUE, ..." and row[4] == "FIELD=VALUE changes"
