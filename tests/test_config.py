"""Spec parsing: types, unknown keys, impossible values, overrides, TOML round trip."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from typing import Annotated, Any, Literal

import pytest

from qdrl.config import (
    ConfigError,
    NonNegativeFloat,
    OneOf,
    PositiveInt,
    PositiveUnitFloat,
    Range,
    apply_overrides,
    as_table,
    build,
    check_fields,
    check_keys,
    check_params,
    coerce,
    describe,
    dump_toml,
    parse_override,
)


@dataclasses.dataclass(frozen=True)
class Demo:
    n: int = 3
    lr: float = 1e-3
    flag: bool = False
    name: str = "a"
    hidden: tuple[PositiveInt, ...] = (4, 4)
    mode: Literal["x", "y"] = "x"
    opt: float | None = None
    rate: PositiveUnitFloat = 0.5
    noise: NonNegativeFloat = 0.1
    bound: Annotated[float, Range(finite=False)] = math.inf  # inf means "no bound"
    color: Annotated[str, OneOf(lambda: ("red", "green"))] = "red"

    def check(self) -> None:
        if self.n <= 0:
            raise ValueError(f"demo.n: expected a positive integer, got {self.n}")


def test_build_coerces_and_defaults() -> None:
    d = build(Demo, {"n": 5, "lr": 1, "hidden": [8, 16], "opt": 0.5}, "demo")
    assert d == Demo(n=5, lr=1.0, hidden=(8, 16), opt=0.5)
    assert isinstance(d.lr, float)
    assert build(Demo, {"bound": float("-inf"), "color": "green"}, "demo").bound == -math.inf


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"batch": 1}, r"demo\.batch: unknown key; expected one of"),
        ({"n": 1.5}, r"demo\.n: expected an integer, got 1\.5"),
        ({"n": True}, r"demo\.n: expected an integer, got True"),
        ({"lr": "fast"}, r"demo\.lr: expected a finite number, got 'fast'"),
        ({"lr": float("nan")}, r"demo\.lr: expected a finite number, got nan"),
        ({"lr": float("-inf")}, r"demo\.lr: expected a finite number, got -inf"),
        ({"flag": 1}, r"demo\.flag: expected true or false"),
        ({"hidden": [8, "x"]}, r"demo\.hidden: expected a list of positive integers, got \[8, 'x'\]"),
        ({"hidden": 8}, r"demo\.hidden: expected a list of positive integers, got 8"),
        ({"hidden": [8, 0]}, r"demo\.hidden: expected a list of positive integers, got \[8, 0\]"),
        ({"rate": 0.0}, r"demo\.rate: expected a number in \(0, 1\], got 0\.0"),
        ({"rate": float("inf")}, r"demo\.rate: expected a number in \(0, 1\], got inf"),
        ({"noise": -0.5}, r"demo\.noise: expected a number >= 0, got -0\.5"),
        ({"bound": float("nan")}, r"demo\.bound: expected a number \(inf allowed\), got nan"),
        ({"color": "blue"}, r"demo\.color: expected one of \['green', 'red'\], got 'blue'"),
        ({"opt": "x"}, r"demo\.opt: expected a finite number or nothing \(omit the key\), got 'x'"),
        ({"mode": "z"}, r"demo\.mode: expected one of 'x', 'y'"),
        ({"n": -2}, r"demo\.n: expected a positive integer, got -2"),
    ],
)
def test_build_names_key_and_expectation(data: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        build(Demo, data, "demo")


def test_overrides_parse_toml_values() -> None:
    assert parse_override("train.batch_size=64") == (["train", "batch_size"], 64)
    assert parse_override("agent.hidden=[32, 32]") == (["agent", "hidden"], [32, 32])
    assert parse_override("env.name=hopper") == (["env", "name"], "hopper")
    assert parse_override('env.name="ant"') == (["env", "name"], "ant")
    with pytest.raises(ConfigError, match=r"expected section\.key=value"):
        parse_override("batch_size")
    with pytest.raises(ConfigError, match=r"expected section\.key=value"):
        parse_override("batch_size=3")
    spec = {"train": {"batch_size": 256}}
    out = apply_overrides(spec, ["train.batch_size=8", "agent.tau=0.01"])
    assert out == {"train": {"batch_size": 8}, "agent": {"tau": 0.01}}
    assert spec == {"train": {"batch_size": 256}}  # the input is not modified


def test_dump_round_trips_through_toml() -> None:
    d = Demo(n=7, hidden=(1, 2), name='quote " and \\ slash')
    text = dump_toml({"demo": as_table(d)})
    back = tomllib.loads(text)["demo"]
    assert build(Demo, back, "demo") == d


@dataclasses.dataclass(frozen=True)
class Needs:
    name: str  # required: no default
    size: PositiveInt = 1


def test_sections_of_the_wrong_toml_type_and_missing_keys_name_the_section() -> None:
    for value in (5, "x", [1, 2], 1.5, True):
        with pytest.raises(ConfigError, match=r"^demo: expected a table \(\[demo\] followed by key = value lines\), got "):
            build(Demo, value, "demo")
    with pytest.raises(ConfigError, match=r"^needs\.name: missing; expected a string$"):
        build(Needs, {"size": 2}, "needs")
    with pytest.raises(ConfigError, match=r"^needs\.size: expected a positive integer, got \{'a': 1\}$"):
        build(Needs, {"name": "a", "size": {"a": 1}}, "needs")


def test_check_keys_checks_given_keys_only() -> None:
    assert check_keys(Demo, {"n": 2, "hidden": [1]}, "demo") == {"n": 2, "hidden": (1,)}
    with pytest.raises(ConfigError, match=r"^demo\.noise: expected a number >= 0, got -1$"):
        check_keys(Demo, {"noise": -1}, "demo")


def test_check_fields_refuses_a_config_built_in_python() -> None:
    check_fields(Demo(), "demo")
    with pytest.raises(ConfigError, match=r"^demo\.rate: expected a number in \(0, 1\], got 2\.0$"):
        check_fields(Demo(rate=2.0), "demo")


@pytest.mark.parametrize(
    ("tp", "ok", "bad"),
    [
        (PositiveInt, [1, 10**12], [0, -1, 1.0, True, "1"]),
        (Annotated[int, Range(2, 4)], [2, 4], [1, 5]),
        (Annotated[float, Range(0.0, 1.0, low_open=True, high_open=True)], [0.5, 1e-9], [0.0, 1.0, math.nan]),
        (Annotated[float, Range(high=-1.0)], [-1.0, -5], [0.0, -math.inf]),
        (float, [0, -3.5, 1e300], [math.inf, -math.inf, math.nan, "0", None, [1.0]]),
        (tuple[float, ...], [[], [1, 2.5]], [[math.inf], "1", 1.0, [[1.0]]]),
    ],
)
def test_declared_ranges_accept_and_refuse(tp: Any, ok: list[Any], bad: list[Any]) -> None:
    for value in ok:
        coerce(value, tp, "s.k")
    for value in bad:
        with pytest.raises(ConfigError, match=rf"^s\.k: expected {re.escape(describe(tp))}, got "):
            coerce(value, tp, "s.k")


def test_descriptions_read_as_english() -> None:
    assert describe(PositiveInt) == "a positive integer"
    assert describe(tuple[PositiveInt, ...]) == "a list of positive integers"
    assert describe(Annotated[int, Range(low=0)]) == "an integer >= 0"
    assert describe(Annotated[float, Range(0.0, 1.0)]) == "a number in [0, 1]"
    assert describe(tuple[Annotated[float, Range(low=0.0, low_open=True)], ...]) == "a list of numbers > 0"
    assert describe(Annotated[int, Range(low=2)] | None) == "an integer >= 2 or nothing (omit the key)"


def _builder(size: PositiveInt = 3, scale: float = 1.0, tag: str = "a") -> None:
    raise AssertionError("check_params must not call the builder")


def test_check_params_checks_a_builders_keywords_without_calling_it() -> None:
    assert check_params(_builder, {"size": 4, "scale": 2}, "task") == {"size": 4, "scale": 2.0}
    with pytest.raises(ConfigError, match=r"^task\.size: expected a positive integer, got 0$"):
        check_params(_builder, {"size": 0}, "task")
    with pytest.raises(ConfigError, match=r"^task\.scale: expected a finite number, got inf$"):
        check_params(_builder, {"scale": math.inf}, "task")
    with pytest.raises(ConfigError, match=r"^task\.sise: unknown key for task 'x'; did you mean 'size'\?; expected one of \['scale', 'size', 'tag'\]$"):
        check_params(_builder, {"sise": 1}, "task", owner="task 'x'")
