"""Experiment specs: TOML files turned into checked, typed config dataclasses.

A spec has one table per section (`[experiment]`, `[env]`, `[agent]`, ...); each
section maps to a frozen dataclass. Every field declares what it accepts in its
type: `int`, `float` (finite: NaN and +-inf are refused unless the field's `Range`
says `finite=False`), `bool`, `str`, a `Literal`, a list (`tuple[T, ...]`), and
with `typing.Annotated` a `Range` (`PositiveInt`, `UnitFloat`, ...) or a registry
of names (`OneOf`). Parsing checks every key against these declarations and then
calls the dataclass's `check()` (checks across keys), so a bad spec fails in
milliseconds, before anything is built or compiled, with one line naming
`section.key` and what was expected. The same declarations check a task
builder's keyword parameters (`[task]` keys) and a config built in Python
(`check_fields`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import types
import typing
from collections.abc import Callable, Collection, Hashable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any


class ConfigError(ValueError):
    """A spec that cannot run: unknown key, wrong type or impossible value."""


@dataclasses.dataclass(frozen=True)
class Range:
    """The values a numeric field accepts, declared with `Annotated[int | float, Range(...)]`.

    `low` / `high` bound the value (excluded when `low_open` / `high_open`). Floats
    are finite unless `finite=False`: a key where infinity means something says so.
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    finite: bool = True

    def contains(self, x: float) -> bool:
        """Whether `x` is in the range (NaN never is)."""
        if math.isnan(x) or (self.finite and math.isinf(x)):
            return False
        if self.low is not None and (x <= self.low if self.low_open else x < self.low):
            return False
        return self.high is None or (x < self.high if self.high_open else x <= self.high)

    def describe(self, base: Any, plural: bool = False) -> str:
        """E.g. "a positive integer", "numbers in (0, 1]"."""
        integer = base is int
        noun = ("integers" if plural else "an integer") if integer else ("numbers" if plural else "a number")
        if integer and self.high is None and self.low == 1 and not self.low_open:
            return "positive integers" if plural else "a positive integer"
        if self.low is not None and self.high is not None:
            lb, rb = "(" if self.low_open else "[", ")" if self.high_open else "]"
            return f"{noun} in {lb}{_num(self.low)}, {_num(self.high)}{rb}"
        if self.low is not None:
            return f"{noun} {'>' if self.low_open else '>='} {_num(self.low)}"
        if self.high is not None:
            return f"{noun} {'<' if self.high_open else '<='} {_num(self.high)}"
        if integer:
            return noun
        if self.finite:
            return "finite numbers" if plural else "a finite number"
        return f"{noun} (inf allowed)"


@dataclasses.dataclass(frozen=True)
class OneOf:
    """A string field whose value is a name from a registry: `Annotated[str, OneOf(names_fn)]`.

    `names` is called when a value is checked, so registries filled at import time
    (algorithms, tasks, environments) are complete by then.
    """

    names: Callable[[], Collection[str]]

    def describe(self, plural: bool = False) -> str:
        return f"{'names' if plural else 'one'} of {sorted(self.names())}"


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(x)


PositiveInt = Annotated[int, Range(low=1)]
NonNegativeInt = Annotated[int, Range(low=0)]
PositiveFloat = Annotated[float, Range(low=0.0, low_open=True)]
NonNegativeFloat = Annotated[float, Range(low=0.0)]
UnitFloat = Annotated[float, Range(0.0, 1.0)]  # probabilities, shares, discounts: [0, 1]
PositiveUnitFloat = Annotated[float, Range(0.0, 1.0, low_open=True)]  # (0, 1], e.g. Polyak rates


def _annotation(tp: Any) -> tuple[Any, Range | None, OneOf | None]:
    """(base type, its Range, its OneOf) of a possibly `Annotated` type."""
    if typing.get_origin(tp) is Annotated:
        base, *meta = typing.get_args(tp)
        rng = next((m for m in meta if isinstance(m, Range)), None)
        one_of = next((m for m in meta if isinstance(m, OneOf)), None)
        return base, rng, one_of
    return tp, None, None


def describe(tp: Any, plural: bool = False) -> str:
    """What a field of type `tp` accepts, in words ("a positive integer", "a list of numbers")."""
    base, rng, one_of = _annotation(tp)
    origin = typing.get_origin(base)
    if origin is typing.Literal:
        return ("values among " if plural else "one of ") + ", ".join(repr(a) for a in typing.get_args(base))
    if origin in (types.UnionType, typing.Union):
        return " or ".join(describe(a, plural) for a in typing.get_args(base))
    if origin in (tuple, list, Sequence):
        return f"{'lists' if plural else 'a list'} of {describe(typing.get_args(base)[0], plural=True)}"
    if base is type(None):
        return "nothing (omit the key)"
    if one_of is not None:
        return one_of.describe(plural)
    if base in (int, float):
        return (rng or Range()).describe(base, plural)
    names = {bool: ("true or false", "booleans"), str: ("a string", "strings")}
    if base in names:
        return names[base][plural]
    return getattr(base, "__name__", str(base))


def _show(value: Any) -> str:
    """A value as the user wrote it, on one line."""
    if isinstance(value, tuple):
        value = list(value)
    return repr(value)


def coerce(value: Any, tp: Any, where: str) -> Any:
    """`value` as type `tp` (lists as tuples, integers as floats where floats are expected).

    Raises ConfigError `"<where>: expected <what tp accepts>, got <value>"` when the
    type, the finiteness, the declared `Range` or the `OneOf` registry refuses it.
    """
    base, rng, one_of = _annotation(tp)
    origin = typing.get_origin(base)
    if origin in (types.UnionType, typing.Union):
        for arg in typing.get_args(base):
            try:
                return coerce(value, arg, where)
            except ConfigError:
                continue
    elif origin is typing.Literal:
        if isinstance(value, str | int | float) and value in typing.get_args(base):
            return value
    elif origin in (tuple, list, Sequence):
        item_tp = typing.get_args(base)[0]
        if isinstance(value, list | tuple):
            try:
                return tuple(coerce(v, item_tp, f"{where}[{i}]") for i, v in enumerate(value))
            except ConfigError:
                pass
    elif base is type(None):
        if value is None:
            return None
    elif base is bool:
        if isinstance(value, bool):
            return value
    elif base is int:
        if isinstance(value, int) and not isinstance(value, bool) and (rng is None or rng.contains(value)):
            return value
    elif base is float:
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if number and (rng or Range()).contains(float(value)):
            return float(value)
    elif base is str:
        if isinstance(value, str) and (one_of is None or value in one_of.names()):
            return value
    else:
        raise TypeError(f"unsupported config type {tp!r} at {where}")
    raise ConfigError(f"{where}: expected {describe(tp)}, got {_show(value)}")


def _hints(owner: Any) -> dict[str, Any]:
    """The resolved annotations of a dataclass or function (cached: resolving them is slow)."""
    return _resolved_hints(owner)


@functools.cache
def _resolved_hints(owner: Hashable) -> dict[str, Any]:
    return typing.get_type_hints(owner, include_extras=True)


def check_table(data: Any, section: str) -> Mapping[str, Any]:
    """`data` if it is a TOML table; otherwise ConfigError naming the section."""
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{section}: expected a table ([{section}] followed by key = value lines), got {_show(data)}"
        )
    return data


def check_keys(cls: type[Any], data: Any, section: str) -> dict[str, Any]:
    """The keys given in `data` for dataclass `cls`, each checked and coerced; no check across keys.

    For sections whose other keys default to values known only later (e.g. from a
    task); `build` does this and then the rest.
    """
    data = check_table(data, section)
    hints = _hints(cls)
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ConfigError(
            f"{section}.{unknown[0]}: unknown key; expected one of {sorted(fields)}"
        )
    return {k: coerce(v, hints[k], f"{section}.{k}") for k, v in data.items()}


def build(cls: type[Any], data: Any, section: str) -> Any:
    """An instance of dataclass `cls` from `data`, checked; errors name `section.key`."""
    kwargs = check_keys(cls, data, section)
    hints = _hints(cls)
    for f in dataclasses.fields(cls):
        missing = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if f.init and missing and f.name not in kwargs:
            raise ConfigError(f"{section}.{f.name}: missing; expected {describe(hints[f.name])}")
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


def check_fields(obj: Any, section: str) -> None:
    """Raises ConfigError naming `section.<field>` for the first field of dataclass `obj`
    whose value its declared type refuses (for configs built in Python, not parsed)."""
    hints = _hints(type(obj))
    for f in dataclasses.fields(obj):
        if f.init:
            coerce(getattr(obj, f.name), hints[f.name], f"{section}.{f.name}")


def check_params(
    fn: Callable[..., Any], params: Mapping[str, Any], section: str, owner: str = ""
) -> dict[str, Any]:
    """`params` for the keyword parameters of `fn`, each checked against its annotation.

    Unknown names and values the annotations refuse raise ConfigError naming
    `section.<name>` (unknown ones "for <owner>"); `fn` is not called.
    """
    import inspect

    sig = inspect.signature(fn)
    hints = _hints(fn)
    accepted = sorted(
        k for k, p in sig.parameters.items() if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)
    )
    out = {}
    for key, value in params.items():
        if key not in accepted:
            label = f" for {owner}" if owner else ""
            raise ConfigError(f"{section}.{key}: unknown key{label}; expected one of {accepted}")
        out[key] = coerce(value, hints[key], f"{section}.{key}") if key in hints else value
    return out


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


def dump_toml(sections: Mapping[str, Mapping[str, Any] | Sequence[Mapping[str, Any]]]) -> str:
    """TOML text for a mapping of section -> flat table, or -> list of flat tables (an array
    of tables, `[[section]]`); None values are left out."""
    lines: list[str] = []
    for name, value in sections.items():
        if isinstance(value, Mapping):
            tables = [(f"[{name}]", value)]
        else:
            tables = [(f"[[{name}]]", t) for t in value]
        for header, table in tables:
            lines.append(header)
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
