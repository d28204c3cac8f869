"""Shorter, predictable compile waits: jax's persistent compilation cache and measured startup times.

`enabled(True)` points jax's persistent compilation cache at `cache_dir() / "jax"`
for the duration of a run, unless `JAX_COMPILATION_CACHE_DIR` (or jax's config)
already names a directory: a second run of a spec then loads its executables
instead of compiling them. `enabled(False)`, `log.compile_cache = false` in a
spec or `QDRL_COMPILE_CACHE=0` turn the cache off.

`estimate` and `record` keep the measured startup time (initial state and
compilation) of each spec per machine in `cache_dir() / "compile_times.json"`,
so that a run can say how long its compilation took last time, or, for a new
spec, how long a cold compilation (no executable from the persistent cache, as
`cache_hits` counts) of the same algorithm and task took. Nothing here ever
fails a run: an unwritable cache directory only loses the record.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import time
import tomllib
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.monitoring
from jax.experimental.compilation_cache import compilation_cache as cc

__all__ = ["cache_dir", "cache_hits", "enabled", "estimate", "record", "spec_key"]

_TIMES_FILE = "compile_times.json"
# Keys that do not change what is compiled (logging, seed, label; and the run's length key).
_NOT_COMPILED = (
    "log", "experiment.seed", "experiment.name", "experiment.time_limit_s", "experiment.env_steps_limit",
)


def cache_dir() -> Path:
    """qdrl's cache directory: `$QDRL_CACHE_DIR`, else `$XDG_CACHE_HOME/qdrl`, else `~/.cache/qdrl`."""
    if os.environ.get("QDRL_CACHE_DIR"):
        return Path(os.environ["QDRL_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "qdrl"


def _env_allows() -> bool:
    return os.environ.get("QDRL_COMPILE_CACHE", "1").strip().lower() not in ("0", "false", "no", "off")


@contextlib.contextmanager
def enabled(on: bool = True) -> Iterator[str | None]:
    """Within the block, jax's persistent compilation cache is on (or off); yields its directory.

    On: jax's own setting (`JAX_COMPILATION_CACHE_DIR`) is kept when there is one;
    otherwise `cache_dir() / "jax"` is used. Off when `on` is False or the
    environment says `QDRL_COMPILE_CACHE=0`. The previous settings come back on exit.
    """

    config: Any = jax.config  # its flags are attributes that the stubs do not list
    before = (config.jax_compilation_cache_dir, config.jax_enable_compilation_cache)
    on = on and _env_allows()
    directory = before[0] if on else None
    if on and directory is None:
        path = cache_dir() / "jax"
        try:
            path.mkdir(parents=True, exist_ok=True)
            directory = str(path)
        except OSError:
            on = False
    changed = (directory, on) != before
    if changed:
        jax.config.update("jax_enable_compilation_cache", on)
        if directory is not None:
            cc.set_cache_dir(directory)
        cc.reset_cache()  # jax decides whether to use its cache once; make it look again
    try:
        yield directory
    finally:
        if changed:
            jax.config.update("jax_enable_compilation_cache", before[1])
            jax.config.update("jax_compilation_cache_dir", before[0])
            cc.reset_cache()


@contextlib.contextmanager
def cache_hits() -> Iterator[dict[str, int]]:
    """Counts, within the block, compilations looked up in the persistent cache and found there."""

    counts = {"lookups": 0, "hits": 0}

    def listen(event: str, **kwargs: str | int) -> None:
        if event == "/jax/compilation_cache/compile_requests_use_cache":
            counts["lookups"] += 1
        elif event == "/jax/compilation_cache/cache_hits":
            counts["hits"] += 1

    jax.monitoring.register_event_listener(listen)
    try:
        yield counts
    finally:
        jax.monitoring.unregister_event_listener(listen)


def spec_key(config_toml: str, length_key: str = "") -> str:
    """A digest of a resolved spec, leaving out the keys that do not change what is compiled
    (logging, seed, name, and `length_key`: the algorithm's run length, `Recipe.length_key`)."""
    spec = tomllib.loads(config_toml)
    skip = (*_NOT_COMPILED, length_key)
    flat = {
        f"{section}{'' if isinstance(tables, dict) else f'[{i}]'}.{key}": value
        for section, tables in spec.items()
        for i, table in enumerate([tables] if isinstance(tables, dict) else tables)  # [[section]]: a list
        for key, value in table.items()
        if section not in skip and f"{section}.{key}" not in skip
    }
    return hashlib.sha256(json.dumps(flat, sort_keys=True).encode()).hexdigest()[:16]


def _machine() -> str:
    device = jax.devices()[0]
    return f"{platform.node()} {device.platform} {device.device_kind} jax {jax.__version__}"


def _load() -> dict[str, Any]:
    try:
        data = json.loads((cache_dir() / _TIMES_FILE).read_text())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def estimate(key: str, algorithm: str, task: str) -> tuple[float, bool] | None:
    """`(seconds, same_spec)`: the last startup time of this spec on this machine, else that of
    the newest cold start of the same algorithm and task (`same_spec` False); else None."""
    runs: Mapping[str, Any] = _load().get(_machine(), {})
    if key in runs:
        return float(runs[key]["seconds"]), True
    similar = [
        r for r in runs.values()
        if r.get("algorithm") == algorithm and r.get("task") == task and r.get("cold")
    ]
    if similar:
        return float(max(similar, key=lambda r: r.get("when", 0))["seconds"]), False
    return None


def record(key: str, algorithm: str, task: str, seconds: float, cold: bool) -> None:
    """Stores this spec's startup time on this machine (best effort); `cold`: compiled from scratch."""
    data = _load()
    machine = data.setdefault(_machine(), {})
    machine[key] = {
        "algorithm": algorithm, "task": task, "seconds": round(seconds, 2), "cold": cold, "when": time.time(),
    }
    path = cache_dir() / _TIMES_FILE
    tmp = path.with_name(f".{_TIMES_FILE}.{uuid.uuid4().hex}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
