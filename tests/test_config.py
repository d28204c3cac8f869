"""Spec parsing: types, unknown keys, impossible values, overrides, TOML round trip."""

from __future__ import annotations

import dataclasses
import tomllib
from typing import Literal

import pytest

from qdrl.config import ConfigError, apply_overrides, as_table, build, dump_toml, parse_override


@dataclasses.dataclass(frozen=True)
class Demo:
    n: int = 3
    lr: float = 1e-3
    flag: bool = False
    name: str = "a"
    hidden: tuple[int, ...] = (4, 4)
    mode: Literal["x", "y"] = "x"
    opt: float | None = None

    def check(self) -> None:
        if self.n <= 0:
            raise ValueError(f"demo.n: expected a positive integer, got {self.n}")


def test_build_coerces_and_defaults() -> None:
    d = build(Demo, {"n": 5, "lr": 1, "hidden": [8, 16], "opt": 0.5}, "demo")
    assert d == Demo(n=5, lr=1.0, hidden=(8, 16), opt=0.5)
    assert isinstance(d.lr, float)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"batch": 1}, r"demo\.batch: unknown key; expected one of"),
        ({"n": 1.5}, r"demo\.n: expected an integer, got 1\.5"),
        ({"n": True}, r"demo\.n: expected an integer, got True"),
        ({"lr": "fast"}, r"demo\.lr: expected a number, got 'fast'"),
        ({"lr": float("nan")}, r"demo\.lr: expected a number, got nan"),
        ({"flag": 1}, r"demo\.flag: expected true or false"),
        ({"hidden": [8, "x"]}, r"demo\.hidden\[1\]: expected an integer"),
        ({"hidden": 8}, r"demo\.hidden: expected a list of an integer"),
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
