"""Experiment specs: TOML files turned into checked, typed config dataclasses.

A spec has one table per section (`[experiment]`, `[env]`, `[agent]`, ...); each
section maps to a frozen dataclass. Parsing checks every key and type against
the dataclass and then calls its `check()`, so a bad spec fails in well under a
second, before anything is compiled, with a message naming `section.key` and
what was expected.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A spec that cannot run: unknown key, wrong type or impossible value."""


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"a list of {_type_name(typing.get_args(tp)[0])}"
    if tp is type(None):
        return "nothing (omit the key)"
    names = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
    return names.get(tp, getattr(tp, "__name__", str(tp)))


def coerce(value: Any, tp: Any, where: str) -> Any:
    """`value` as type `tp`, or ConfigError naming `where` and the expected type."""
    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        for arg in typing.get_args(tp):
            try:
                return coerce(value, arg, where)
            except ConfigError:
                continue
    elif origin is typing.Literal:
        if value in typing.get_args(tp):
            return value
    elif origin in (tuple, list, Sequence):
        item_tp = typing.get_args(tp)[0]
        if isinstance(value, list | tuple):
            return tuple(coerce(v, item_tp, f"{where}[{i}]") for i, v in enumerate(value))
    elif tp is type(None):
        if value is None:
            return None
    elif tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            if math.isnan(float(value)):
                raise ConfigError(f"{where}: expected a number, got nan")
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    else:
        raise TypeError(f"unsupported config type {tp!r} at {where}")
    raise ConfigError(f"{where}: expected {_type_name(tp)}, got {value!r}")


def build(cls: type[Any], data: Mapping[str, Any], section: str) -> Any:
    """An instance of dataclass `cls` from `data`, checked; errors name `section.key`."""
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ConfigError(
            f"{section}.{unknown[0]}: unknown key; expected one of {sorted(fields)}"
        )
    kwargs = {k: coerce(v, hints[k], f"{section}.{k}") for k, v in data.items()}
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if check is not None:
        try:
            check()
        except ConfigError:
            raise
        except ValueError as e:
            msg = str(e)
            if not msg.startswith(f"{section}."):
                msg = f"{section}: {msg}"
            raise ConfigError(msg) from e
    return obj


def parse_override(text: str) -> tuple[list[str], Any]:
    """`section.key=value` -> (["section", "key"], value); value read as TOML, else a string."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    path, raw = text.split("=", 1)
    keys = path.strip().split(".")
    if len(keys) < 2 or not all(keys):
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return keys, value


def apply_overrides(spec: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """A copy of `spec` with each `section.key=value` override set."""
    out: dict[str, Any] = {k: dict(v) if isinstance(v, dict) else v for k, v in spec.items()}
    for text in overrides:
        keys, value = parse_override(text)
        table = out
        for k in keys[:-1]:
            table = table.setdefault(k, {})
            if not isinstance(table, dict):
                raise ConfigError(f"--set {text!r}: {k} is not a section")
        table[keys[-1]] = value
    return out


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a spec file; errors say which file and why."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"spec file {str(path)!r} not found")
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from e


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} to TOML")


def dump_toml(sections: Mapping[str, Mapping[str, Any]]) -> str:
    """TOML text for a mapping of section -> flat table (None values are left out)."""
    lines: list[str] = []
    for name, table in sections.items():
        lines.append(f"[{name}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in table.items() if v is not None)
        lines.append("")
    return "\n".join(lines)


def as_table(obj: Any) -> dict[str, Any]:
    """A config dataclass (or a plain mapping) as a flat dict, tuples as lists, for TOML."""
    if isinstance(obj, Mapping):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in obj.items()}
    return {
        f.name: list(v) if isinstance(v := getattr(obj, f.name), tuple) else v
        for f in dataclasses.fields(obj)
    }
