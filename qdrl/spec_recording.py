"""Records `qdrl/_spec_schema.json` from the table of algorithms (imports it, hence jax):
`python -m qdrl.spec_recording`. What the schema is and how `qdrl run` reads it:
`qdrl.spec_schema`."""

from __future__ import annotations

import contextlib
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from qdrl import specs
from qdrl._version import __version__
from qdrl.algorithms import ALGORITHMS
from qdrl.config import OBSERVERS, ConfigError, load_toml
from qdrl.experiment import check_spec
from qdrl.qd.emitters.registry import EMITTER_KINDS
from qdrl.spec_schema import COMMON, SCHEMA_FILE, encode_type
from qdrl.tasks import TASKS

__all__ = ["record", "write"]


def _section_pattern(section: str) -> str:
    """"emitters[2]" -> "emitters[]" (the tables of an array share one entry)."""
    return section.split("[", 1)[0] + "[]" if section.endswith("]") else section


class _Recorder:
    """Collects, per section, the tables `check_keys` / `check_params` were asked about."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, dict[str, Any], tuple[str, str] | None, str, Mapping[str, Any]]] = []

    def __call__(
        self, section: str, table: Mapping[str, Any], given: Mapping[str, Any], selector: tuple[str, str] | None, owner: str
    ) -> None:
        encoded = {k: encode_type(tp) for k, tp in table.items()}
        inferred = selector is None and isinstance(given.get("kind"), str)
        if inferred:  # an emitter's kind chooses its config class
            selector = ("kind", given["kind"])
        self.calls.append((section, encoded, selector, owner, {**given, "__inferred__": inferred}))


def _raw_section(spec: Mapping[str, Any], section: str) -> Any:
    if section.endswith("]"):
        name, index = section[:-1].split("[", 1)
        tables = spec.get(name)
        return tables[int(index)] if isinstance(tables, list) and int(index) < len(tables) else None
    return spec.get(section)


def _variants_of(spec: Mapping[str, Any], tasks: list[str], kinds: list[str]) -> list[dict[str, Any]]:
    """The spec with each task name, and each emitter kind, in turn."""
    out = [{**spec, "task": {"name": t}} for t in tasks]
    if "emitter" in spec or "emitters" not in spec:
        out += [{**spec, "emitter": {}}] + [{**spec, "emitter": {"kind": k}} for k in kinds]
    if isinstance(spec.get("emitters"), list) and spec["emitters"]:
        out += [{**spec, "emitters": [{"kind": k}, *spec["emitters"][1:]]} for k in kinds]
    return out


def record() -> dict[str, Any]:
    """The schema of every algorithm of the table, from the packaged specs and their variants."""
    by_algorithm: dict[str, list[Mapping[str, Any]]] = {name: [] for name in ALGORITHMS}
    # the top-level specs, then those of the folders (an algorithm whose only specs are there)
    names = [*specs.spec_names(), *(n for folder in specs.SPEC_FOLDERS for n in specs.spec_names(folder))]
    for name in names:
        spec = load_toml(specs.resolve(name))
        algorithm = spec.get("experiment", {}).get("algorithm")
        if algorithm in by_algorithm:
            by_algorithm[algorithm].append(spec)
    algorithms: dict[str, Any] = {}
    common: dict[str, Any] = {}
    for algorithm, packaged in sorted(by_algorithm.items()):
        bases = packaged or [{"experiment": {"algorithm": algorithm}}]
        recorder = _Recorder()
        known: set[tuple[str, ...]] = set()
        OBSERVERS.append(recorder)
        try:
            # every packaged spec as it is; each task name and emitter kind on the first one, and on
            # the first with a pool of [[emitters]] (a table is its config class's: the other specs
            # of the algorithm give the same)
            with_pool = next((b for b in bases if "emitters" in b), None)
            variants = [*bases, *_variants_of(bases[0], sorted(TASKS), sorted(EMITTER_KINDS))]
            if with_pool is not None and with_pool is not bases[0]:
                variants += _variants_of(with_pool, [], sorted(EMITTER_KINDS))
            for variant in variants:
                start = len(recorder.calls)
                with contextlib.suppress(ConfigError):
                    known.add(tuple(sorted({*COMMON, *check_spec(variant).sections})))
                # the default of a selector: the value its section took when the spec gave none
                recorder.calls[start:] = [
                    (s, t, sel, o, {**g, "__raw__": _raw_section(variant, s)})
                    for s, t, sel, o, g in recorder.calls[start:]
                ]
        finally:
            OBSERVERS.remove(recorder)
        sections = _sections(recorder.calls)
        for name in COMMON:
            common[name] = sections.pop(name)
        algorithms[algorithm] = {
            "sections": sections,
            "known": sorted(list(k) for k in known),  # the sections of each form of the spec
            "arrays": list(ALGORITHMS[algorithm].array_sections),
        }
    pool: dict[str, Any] = {}

    def pooled(entry: Any) -> Any:  # each table once, referred to by a digest of it
        if isinstance(entry, dict) and "table" in entry:
            text = json.dumps(entry, sort_keys=True)
            ref = hashlib.sha256(text.encode()).hexdigest()[:12]
            pool[ref] = entry
            return {"ref": ref}
        if isinstance(entry, dict):
            return {k: pooled(v) for k, v in entry.items()}
        return entry

    return {"qdrl": __version__, "common": pooled(common), "algorithms": pooled(algorithms), "tables": pool}


def _sections(calls: list[tuple[str, dict[str, Any], tuple[str, str] | None, str, Mapping[str, Any]]]) -> dict[str, Any]:
    """Per section: one table ({"table", "owner"}), a table per selector value ({"by",
    "variants", "default", "names"}), or {"open": true} when neither explains the calls."""
    grouped: dict[str, list[Any]] = {}
    for section, table, selector, owner, given in calls:
        grouped.setdefault(_section_pattern(section), []).append((table, selector, owner, given))
    out: dict[str, Any] = {}
    for section, entries in sorted(grouped.items()):
        tables = {json.dumps(t, sort_keys=True) for t, _, _, _ in entries}
        owners = {o for _, _, o, _ in entries}
        explicit = any(sel is not None and not given["__inferred__"] for _, sel, _, given in entries)
        if len(tables) == 1 and len(owners) == 1 and not explicit:
            out[section] = {"table": entries[0][0], "owner": entries[0][2]}
            continue
        keys = {sel[0] for _, sel, _, _ in entries if sel is not None}
        if len(keys) != 1 or any(sel is None for _, sel, _, _ in entries):
            out[section] = {"open": True}
            continue
        (by,) = keys
        variants: dict[str, Any] = {}
        defaults: set[str] = set()
        consistent = True
        for table, (_, value), owner, given in entries:
            entry = {"table": table, "owner": owner}
            if variants.setdefault(value, entry) != entry:
                consistent = False
            raw = given.get("__raw__")
            if isinstance(raw, Mapping) and by not in raw:
                defaults.add(value)
        if not consistent or len(defaults) > 1:
            out[section] = {"open": True}
            continue
        out[section] = {
            "by": by,
            "variants": dict(sorted(variants.items())),
            "default": next(iter(defaults)) if defaults else None,
        }
    return out


def write(path: Path = SCHEMA_FILE) -> None:
    """Rewrites the packaged schema from the table of algorithms."""
    path.write_text(json.dumps(record(), indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    write()
    print(f"wrote {SCHEMA_FILE}")
