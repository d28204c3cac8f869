"""What `qdrl list` prints: the packaged specs, the algorithms, the emitter kinds and the tasks."""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from qdrl import specs, suites
from qdrl.algorithms import ALGORITHMS
from qdrl.envs import PURE_JAX_ENVS
from qdrl.envs.brax import BACKENDS, brax_env_names
from qdrl.qd.emitters.registry import EMITTER_KINDS
from qdrl.tasks import TASKS

__all__ = ["listing", "shorten", "spec_lines"]


def shorten(text: str, width: int = 90) -> str:
    """`text` cut at a word boundary to at most `width` characters ("..." marks a cut)."""
    if len(text) <= width:
        return text
    return text[: width - 3].rsplit(" ", 1)[0].rstrip(",;:(") + "..."


def _leaves(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, Mapping):
            out.update(_leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _count(value: Any) -> str:
    return f"{value:,}" if isinstance(value, int) else str(value)


def _summary(leaves: Mapping[str, Any]) -> str:
    """What a spec runs, from its own keys: algorithm, task, length, batch, episode length."""
    algorithm = str(leaves.get("experiment.algorithm", "?"))
    task = leaves.get("env.task", leaves.get("env.name", leaves.get("task.name", "?")))
    backend = leaves.get("env.backend", leaves.get("task.backend"))
    where = f"{task} ({backend})" if backend else str(task)
    parts = []
    if algorithm in ALGORITHMS:
        length_key = ALGORITHMS[algorithm].length_key
        unit = {"total_env_steps": "env steps", "num_iterations": "iterations"}.get(
            length_key.split(".")[-1], length_key.split(".")[-1].replace("_", " ").removeprefix("num ")
        )
        if length_key in leaves:
            parts.append(f"{_count(leaves[length_key])} {unit}")
    for key, what in (("train.num_envs", "envs"), ("emitter.batch_size", "per batch"),
                      ("qd.batch_size", "per batch"), ("pbt.population_size", "agents")):
        if key in leaves:
            parts.append(f"{_count(leaves[key])} {what}")
    for key in ("env.episode_length", "task.episode_length"):
        if key in leaves:
            parts.append(f"{leaves[key]}-step episodes")
    return f"{algorithm} on {where}" + (f": {', '.join(parts)}" if parts else "")


def spec_lines(paths: list[Path]) -> dict[str, str]:
    """Spec name -> its line of `qdrl list`: what it runs (algorithm, task, length, batch,
    episodes), what sets it apart from specs that would otherwise read the same (the keys it
    sets differently, at most three), and, for a `_cpu` spec, the full-size spec it is the
    2-core variant of. Every spec thus reads differently from every other."""
    leaves = {p.stem: _leaves(tomllib.loads(p.read_text(encoding="utf-8"))) for p in paths}
    summaries = {name: _summary(table) for name, table in leaves.items()}
    same: dict[str, list[str]] = {}
    for name, text in summaries.items():
        same.setdefault(text, []).append(name)
    lines = {}
    for name, text in summaries.items():
        twins = [n for n in same[text] if n != name]
        if twins:
            mine = leaves[name]
            differs = sorted(
                k for k in mine if k != "experiment.name" and any(leaves[t].get(k) != mine[k] for t in twins)
            )
            if differs:
                text += "; " + ", ".join(f"{k}={mine[k]}" for k in differs[:3])
        if name.endswith("_cpu"):
            full = name.removesuffix("_cpu")
            text += f" [2-core variant of {full}]" if full in leaves else " [sized for 2 CPU cores]"
        elif "_cpu_" in name:
            text += f" [2-core, a variant of {name.split('_cpu_')[0]}_cpu]"
        lines[name] = text
    return lines


def listing() -> str:
    """The lines of `qdrl list`."""
    lines = []
    directory = specs.spec_dir()
    names = specs.spec_names()
    where = f" ({directory}; run one by name: qdrl run NAME)" if directory is not None else ""
    lines.append(f"specs{where}:")
    width = max((len(n) for n in names), default=0)
    described = spec_lines([directory / f"{name}.toml" for name in names]) if directory is not None else {}
    lines.extend(f"  {name:<{width}}  {described[name]}" for name in names)
    for folder in specs.SPEC_FOLDERS:
        inside = specs.spec_names(folder)
        if inside:
            lines.append(
                f"  {folder}/  {len(inside)} specs of the skill-discovery benchmark (Chalumeau, Boige et al. "
                f"2023): <algorithm>_<task>[_cpu], e.g. {inside[0]}"
            )
    names_of_suites = suites.suite_names()
    if names_of_suites:
        lines.append(f"suites (qdrl suite run NAME): {', '.join(names_of_suites)}")
    lines.append("algorithms:")
    width = max(len(n) for n in ALGORITHMS)
    lines.extend(f"  {n:<{width}}  {ALGORITHMS[n].description}".rstrip() for n in sorted(ALGORITHMS))
    lines.append("emitter kinds (the [emitter] kind of QD specs, or each [[emitters]] of a pool):")
    lines.extend(f"  {name}: {kind.description}" for name, kind in sorted(EMITTER_KINDS.items()))
    lines.append("tasks:")
    lines.append(f"  QD tasks (the [task] section of QD specs): {', '.join(sorted(TASKS))}")
    lines.append(f"  pure-JAX environments: {', '.join(PURE_JAX_ENVS)}")
    lines.append(f"  brax environments ({', '.join(BACKENDS)} backends): {', '.join(brax_env_names())}")
    return "\n".join(lines)
