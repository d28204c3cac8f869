"""What each section of each algorithm's spec accepts, recorded from the table of algorithms,
so that `qdrl run` refuses a bad key, type, range or name before jax is imported.

The checks of a spec (`qdrl.experiment.check_spec`) are pure Python, but the recipes and
config classes they read live beside the code that builds networks and environments, so
reaching them imports jax, brax and haiku (a second or more on 2 cores). `qdrl.spec_recording` runs
every recipe's `parse` over the packaged specs, with each task name and each emitter kind
in turn, and keeps what `qdrl.config.check_keys` and `check_params` were asked to check:
for every algorithm, the sections it reads, each section's keys and their declared types
(`Range`s, registries of names, literals), and for `[task]` and `[emitter]` the table of
each name or kind. `qdrl/_spec_schema.json` holds the result (`python -m qdrl.spec_recording`
rewrites it; a test keeps it current), and `precheck(spec)` checks a spec against it with
the same functions and messages as the full check, importing nothing heavy.

The precheck only refuses what the full check refuses: keys of a section whose table it
does not know (an algorithm registered at run time, a name or kind no packaged spec
reaches) are left to the full check, as are checks across keys (`check()` methods).
"""

from __future__ import annotations

import difflib
import functools
import json
import operator
import sys
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

from qdrl.config import (
    ConfigError,
    OneOf,
    Range,
    _annotation,
    check_table,
    coerce,
    did_you_mean,
)

__all__ = ["COMMON", "SCHEMA_FILE", "decode_type", "encode_type", "precheck"]

SCHEMA_FILE = Path(__file__).with_name("_spec_schema.json")
COMMON = ("experiment", "log")  # the sections every spec has, the same for every algorithm


# -- declared types as JSON --


def encode_type(tp: Any) -> dict[str, Any]:
    """A config field's declared type as JSON ({"t": "int", "range": [...]}, ...)."""
    base, rng, one_of = _annotation(tp)
    origin = typing.get_origin(base)
    out: dict[str, Any]
    if origin is Literal:
        out = {"t": "literal", "values": list(typing.get_args(base))}
    elif origin in (types.UnionType, typing.Union):
        out = {"t": "union", "options": [encode_type(a) for a in typing.get_args(base)]}
    elif origin in (tuple, list, Sequence):
        out = {"t": "list", "item": encode_type(typing.get_args(base)[0])}
    elif base is type(None):
        out = {"t": "none"}
    elif base in (bool, int, float, str):
        out = {"t": base.__name__}
    else:
        return {"t": "any"}
    if rng is not None:
        out["range"] = [rng.low, rng.high, rng.low_open, rng.high_open, rng.finite]
    if one_of is not None:
        out["names"] = sorted(one_of.names())
    return out


def decode_type(obj: Mapping[str, Any]) -> Any:
    """The type `encode_type` wrote (registries of names as the names it saw); None for "any"."""
    t = obj["t"]
    tp: Any
    if t == "any":
        return None
    if t == "literal":
        tp = Literal[tuple(obj["values"])]
    elif t == "union":
        options = [decode_type(o) for o in obj["options"]]
        if any(o is None for o in options):
            return None
        tp = functools.reduce(operator.or_, options) if len(options) > 1 else options[0]
    elif t == "list":
        item = decode_type(obj["item"])
        if item is None:
            return None
        tp = tuple[item, ...]  # type: ignore[valid-type]
    elif t == "none":
        tp = type(None)
    else:
        tp = {"bool": bool, "int": int, "float": float, "str": str}[t]
    meta: list[Any] = []
    if "range" in obj:
        low, high, low_open, high_open, finite = obj["range"]
        meta.append(Range(low, high, low_open, high_open, finite))
    if "names" in obj:
        names = tuple(obj["names"])
        meta.append(OneOf(lambda: names))
    return Annotated[(tp, *meta)] if meta else tp


# -- checking (jax-free) --


@functools.cache
def _schema() -> dict[str, Any]:
    schema: dict[str, Any] = json.loads(SCHEMA_FILE.read_text())
    return schema


_DECODED: dict[int, dict[str, Any]] = {}  # by the id of a table of the (cached, never freed) schema


def _decoded(table: Mapping[str, Any]) -> dict[str, Any]:
    """The declared types of a table of the schema, decoded once."""
    if id(table) not in _DECODED:
        _DECODED[id(table)] = {k: decode_type(v) for k, v in table.items()}
    return _DECODED[id(table)]


def _check_table(data: Mapping[str, Any], entry: Mapping[str, Any], section: str, extra: tuple[str, ...] = ()) -> None:
    """The keys of `data` against one recorded table, with the full check's messages."""
    table = entry["table"]
    types = _decoded(table)
    owner = entry["owner"]
    if owner:  # check_params: keys in the order given, "unknown key for <owner>"
        accepted = sorted(table)
        for key in data:
            if key in extra:
                continue
            if key not in table:
                raise ConfigError(
                    f"{section}.{key}: unknown key for {owner}{did_you_mean(key, accepted)}; expected one of {accepted}"
                )
    else:
        unknown = sorted(set(data) - set(table) - set(extra))
        if unknown:
            raise ConfigError(
                f"{section}.{unknown[0]}: unknown key{did_you_mean(unknown[0], table)}; expected one of {sorted(table)}"
            )
    for key, value in data.items():
        tp = types.get(key)
        if tp is not None:
            coerce(value, tp, f"{section}.{key}")


def _table_entry(entry: Mapping[str, Any]) -> Mapping[str, Any]:
    entry = _schema()["tables"][entry["ref"]] if "ref" in entry else entry
    return entry


def _check_section(data: Any, entry: Mapping[str, Any], section: str) -> None:
    data = check_table(data, section)
    entry = _table_entry(entry)
    if "table" in entry:
        _check_table(data, entry, section)
        return
    if entry.get("open"):
        return
    by = entry["by"]
    value = data.get(by, entry["default"])
    if value is None:
        return
    names = sorted(entry["variants"])
    coerce(value, Annotated[str, OneOf(lambda: names)], f"{section}.{by}")
    _check_table(data, _table_entry(entry["variants"][value]), section, extra=(by,))


def precheck(spec: Mapping[str, Any]) -> None:
    """Refuses (ConfigError, the full check's message) a spec with an unknown algorithm,
    section or key, or a value its key's declared type, range or registry refuses; jax-free."""
    schema = _schema()
    if "experiment" not in spec:
        raise ConfigError("experiment: missing section; expected [experiment] with algorithm = ...")
    experiment = check_table(spec["experiment"], "experiment")
    name = experiment.get("algorithm")
    algorithms = schema["algorithms"]
    if name is None:
        raise ConfigError(f"experiment.algorithm: missing; expected one of {sorted(algorithms)}")
    if not isinstance(name, str) or name not in algorithms:
        # an algorithm registered in Python (qdrl.algorithms.register) is the full check's to judge
        if isinstance(name, str) and _registered_elsewhere(name):
            return
        close = difflib.get_close_matches(name, algorithms, n=3, cutoff=0.6) if isinstance(name, str) else []
        hint = f" (close names: {', '.join(close)})" if close else ""
        raise ConfigError(f"experiment.algorithm: expected one of {sorted(algorithms)}, got {name!r}{hint}")
    entry = algorithms[name]
    arrays = set(entry["arrays"])
    for section, table in spec.items():
        if not isinstance(table, list) and section not in arrays:
            check_table(table, section)
    sections = {**schema["common"], **entry["sections"]}
    for section in COMMON:
        _check_section(spec.get(section, {}), sections[section], section)
    every = set().union(*entry["known"])
    unknown = sorted(set(spec) - every)
    if unknown:  # named against the form of the spec its other sections take (as the full check)
        given = set(spec) & every
        known = min((k for k in entry["known"] if given <= set(k)), key=len, default=sorted(every))
        raise ConfigError(
            f"{unknown[0]}: unknown section for algorithm {name!r}"
            f"{did_you_mean(unknown[0], known)}; expected sections {known}"
        )
    for section, data in spec.items():
        if section in COMMON:
            continue
        if isinstance(data, list):
            pattern = sections.get(f"{section}[]")
            if pattern is not None:
                for i, item in enumerate(data):
                    _check_section(item, pattern, f"{section}[{i}]")
        elif section in sections:
            _check_section(data, sections[section], section)


def _registered_elsewhere(name: str) -> bool:
    """Whether the table of algorithms, already imported by this process, has `name`."""
    module = sys.modules.get("qdrl.algorithms")
    return module is not None and name in getattr(module, "ALGORITHMS", {})

