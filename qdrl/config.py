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
import difflib
import functools
import inspect
import math
import tomllib
import types
import typing
from collections.abc import Callable, Collection, Hashable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any


class ConfigError(ValueError):
    """A spec that cannot run: unknown key, wrong type or impossible value."""


def did_you_mean(name: str, options: Iterable[str]) -> str:
    """`"; did you mean 'x'?"` naming the options closest to a misspelt `name` (at most two), or
    "" when none is close."""
    close = difflib.get_close_matches(name, sorted(options), n=2, cutoff=0.6)
    return f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""


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


@dataclasses.dataclass(frozen=True)
class Nested:
    """A field holding a sub-config whose keys sit flat in the parent's spec table.

    `Annotated[TD3Config, Nested(("critic_learning_rate", "critic_lr"), ...)]`: each
    pair is (spec key, spec key of the sub-config), in table order; `Nested()` with
    no pairs takes every key of the sub-config under its own name. The keys are
    checked against the sub-config's declarations and errors name them as the spec
    writes them (`pg.critic_learning_rate: ...`); keys not listed keep the value of
    the field's default. A typed config thus nests by role (Acme's habit) while
    the spec stays one flat section.
    """

    keys: tuple[tuple[str, str], ...]

    def __init__(self, *keys: tuple[str, str]) -> None:
        object.__setattr__(self, "keys", tuple(keys))


@dataclasses.dataclass(frozen=True)
class OtherSection:
    """A field of a config that another spec section gives: `Annotated[GAConfig, OtherSection("emitter")]`.

    It is not a key of the config's own section (`build` leaves its default, `as_table`
    leaves it out); the recipe that reads both sections sets it.
    """

    section: str


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
    hint = did_you_mean(value, _names_of(tp)) if isinstance(value, str) else ""
    raise ConfigError(f"{where}: expected {describe(tp)}, got {_show(value)}{hint}")


def _names_of(tp: Any) -> set[str]:
    """The names a string field of type `tp` accepts (its `OneOf` registry, its Literal values)."""
    base, _, one_of = _annotation(tp)
    names = set(one_of.names()) if one_of is not None else set()
    origin = typing.get_origin(base)
    if origin in (types.UnionType, typing.Union):
        for arg in typing.get_args(base):
            names |= _names_of(arg)
    elif origin is typing.Literal:
        names |= {a for a in typing.get_args(base) if isinstance(a, str)}
    return names


def _hints(owner: Any) -> dict[str, Any]:
    """The resolved annotations of a dataclass or function (cached: resolving them is slow)."""
    return _resolved_hints(owner)


@functools.cache
def _resolved_hints(owner: Hashable) -> dict[str, Any]:
    return typing.get_type_hints(owner, include_extras=True)


def _nested(cls: type[Any]) -> dict[str, Nested]:
    """field name -> its `Nested` marker, for the nested sub-config fields of dataclass `cls`."""
    out = {}
    for name, tp in _hints(cls).items():
        if typing.get_origin(tp) is Annotated:
            marker = next((m for m in typing.get_args(tp)[1:] if isinstance(m, Nested)), None)
            if marker is not None:
                out[name] = marker
    return out


def _other_section(tp: Any) -> str | None:
    if typing.get_origin(tp) is Annotated:
        marker = next((m for m in typing.get_args(tp)[1:] if isinstance(m, OtherSection)), None)
        return None if marker is None else marker.section
    return None


def table_keys(cls: Any) -> dict[str, tuple[tuple[str, ...], Any]]:
    """The spec keys of a section parsed into dataclass `cls`, in table order:
    key -> (the path of fields to its value, its declared type)."""
    return _table_keys(cls)


@functools.cache
def _table_keys(cls: Hashable) -> dict[str, tuple[tuple[str, ...], Any]]:
    assert isinstance(cls, type)
    hints, nested = _hints(cls), _nested(cls)
    keys: dict[str, tuple[tuple[str, ...], Any]] = {}
    for f in dataclasses.fields(cls):
        if not f.init or _other_section(hints[f.name]) is not None:
            continue
        if f.name not in nested:
            keys[f.name] = ((f.name,), hints[f.name])
            continue
        sub = table_keys(typing.get_args(hints[f.name])[0])
        pairs = nested[f.name].keys or tuple((k, k) for k in sub)
        for key, sub_key in pairs:
            path, tp = sub[sub_key]
            keys[key] = ((f.name, *path), tp)
    return keys


def field_default(f: dataclasses.Field[Any]) -> Any:
    """The default value of dataclass field `f` (dataclasses.MISSING when it has none)."""
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return f.default


def _get(obj: Any, path: tuple[str, ...]) -> Any:
    for name in path:
        obj = getattr(obj, name)
    return obj


def _assemble(cls: type[Any], values: Mapping[tuple[str, ...], Any]) -> dict[str, Any]:
    """Constructor arguments of `cls` from values by field path; nested sub-configs are their
    field's default with the given values replaced."""
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        own = {path[1:]: v for path, v in values.items() if path[0] == f.name}
        if not own:
            continue
        if () in own:
            kwargs[f.name] = own[()]
        else:
            sub = field_default(f)
            kwargs[f.name] = dataclasses.replace(sub, **_assemble(type(sub), own))
    return kwargs


# Called with (section, {key: declared type}, the keys given, selector, owner) by every
# `check_keys` and `check_params`: how `qdrl.spec_recording` records what each section of each
# algorithm takes. `selector` is ("name", value) for a table whose keys the value of another
# key decides (a task's builder); `owner` is check_params' ("task 'arm'"), else "".
OBSERVERS: list[Callable[[str, Mapping[str, Any], Mapping[str, Any], tuple[str, str] | None, str], None]] = []


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
    task); `build` does this and then the rest. Keys of nested sub-configs
    (`Nested`) are checked against the sub-config's declarations.
    """
    data = check_table(data, section)
    keys = table_keys(cls)
    for observe in OBSERVERS:
        observe(section, {k: tp for k, (_, tp) in keys.items()}, data, None, "")
    unknown = sorted(set(data) - set(keys))
    if unknown:
        raise ConfigError(
            f"{section}.{unknown[0]}: unknown key{did_you_mean(unknown[0], keys)}; expected one of {sorted(keys)}"
        )
    return {k: coerce(v, keys[k][1], f"{section}.{k}") for k, v in data.items()}


def build(cls: type[Any], data: Any, section: str) -> Any:
    """An instance of dataclass `cls` from `data`, checked; errors name `section.key`."""
    given = check_keys(cls, data, section)
    keys = table_keys(cls)
    kwargs = _assemble(cls, {keys[k][0]: v for k, v in given.items()})
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
    """Raises ConfigError naming `section.<key>` for the first key of dataclass `obj` whose
    value its declared type refuses (for configs built in Python, not parsed); the keys of
    nested sub-configs (`Nested`) are checked under their spec names."""
    for key, (path, tp) in table_keys(type(obj)).items():
        coerce(_get(obj, path), tp, f"{section}.{key}")


def check_params(
    fn: Callable[..., Any],
    params: Mapping[str, Any],
    section: str,
    owner: str = "",
    selector: tuple[str, str] | None = None,
) -> dict[str, Any]:
    """`params` for the keyword parameters of `fn`, each checked against its annotation.

    Unknown names and values the annotations refuse raise ConfigError naming
    `section.<name>` (unknown ones "for <owner>"); `fn` is not called. `selector`: the
    (key, value) of the section that chose `fn` (a task's name), for `OBSERVERS`.
    """

    sig = inspect.signature(fn)
    hints = _hints(fn)
    accepted = sorted(
        k for k, p in sig.parameters.items() if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)
    )
    for observe in OBSERVERS:
        observe(section, {k: hints.get(k, Any) for k in accepted}, params, selector, owner)
    out = {}
    for key, value in params.items():
        if key not in accepted:
            label = f" for {owner}" if owner else ""
            hint = did_you_mean(key, accepted)
            raise ConfigError(f"{section}.{key}: unknown key{label}{hint}; expected one of {accepted}")
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
    """A config dataclass (or a plain mapping) as a flat dict of its spec keys (nested
    sub-configs flattened, `Nested`), tuples as lists, for TOML."""
    if isinstance(obj, Mapping):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in obj.items()}
    out = {}
    for key, (path, _) in table_keys(type(obj)).items():
        value = _get(obj, path)
        out[key] = list(value) if isinstance(value, tuple) else value
    return out
