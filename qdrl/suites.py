"""Suites: many specs x tasks x seeds run under one shared budget, resumable as one command.

A suite file (TOML) names its runs and their budget:

    [suite]
    name = "seed_benchmark_cpu"
    seeds = [0, 1]
    time_limit_s = 600          # every run's wall-clock budget (and/or env_steps = N)

    [[runs]]                    # a group: every algorithm on every task
    specs = "seed_benchmark/{algorithm}_{task}_cpu"
    algorithms = ["map_elites", "pga_me", "smerl_diayn"]
    tasks = ["ant_omni", "halfcheetah_uni"]

Each (task, algorithm, seed) runs the spec `specs` names (a packaged spec or a path; the
placeholders filled in) with `experiment.seed`, and the budget as `experiment.time_limit_s`
/ `experiment.env_steps_limit`, into `OUT/<task>/<algorithm>/seed_<seed>/` (OUT defaults to
`runs/<suite name>`). `qdrl suite run FILE` runs, one after the other, what is not done:
a run that finished or stopped at the budget is skipped, one with checkpoints (a killed
suite) resumes, the others start; `qdrl suite status FILE` says which is which. Every spec
is checked before the first run starts, so a bad suite fails in milliseconds.
`qdrl report OUT` compares the algorithms per task (curves against environment steps and
wall time with bands over seeds, final archives side by side, environment steps per hour).
Packaged suites (`agents/suites/`): `seed_benchmark` (the study of Chalumeau, Boige et al.
2023 at its settings) and `seed_benchmark_cpu` (sized for 2 cores).
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from qdrl import checkpoint, specs
from qdrl.config import ConfigError, PositiveFloat, PositiveInt, build, check_table, load_toml
from qdrl.experiment import check_spec, run
from qdrl.sweeps import finished_as_given

__all__ = ["Entry", "Suite", "entry_status", "load_suite", "resolve_suite", "run_suite", "suite_names", "suite_status"]

SUITE_FOLDER = "suites"


@dataclasses.dataclass(frozen=True)
class SuiteConfig:
    """The `[suite]` table: its name, seeds and the budget every run shares."""

    name: str = ""  # default: the file's stem; the default output directory is runs/<name>
    seeds: tuple[int, ...] = (0,)  # every run once per seed
    time_limit_s: PositiveFloat | None = None  # every run's wall-clock budget (seconds)
    env_steps: PositiveInt | None = None  # every run's environment-steps budget

    def check(self) -> None:
        if not self.seeds:
            raise ValueError("suite.seeds: expected at least one seed, got []")
        if any(s < 0 or s > 2**32 - 1 for s in self.seeds):
            raise ValueError(f"suite.seeds: expected seeds in [0, 2**32), got {list(self.seeds)}")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"suite.seeds: expected distinct seeds, got {list(self.seeds)}")


@dataclasses.dataclass(frozen=True)
class GroupConfig:
    """A `[[runs]]` table: every algorithm of `algorithms` on every task of `tasks`."""

    specs: str = ""  # the spec of each run: a packaged name or a path, with {algorithm} and {task}
    algorithms: tuple[str, ...] = ()
    tasks: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Entry:
    """One run of a suite: its task, algorithm label, seed, spec and directory."""

    task: str
    algorithm: str
    seed: int
    spec: Path
    out: Path
    overrides: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class Suite:
    """A parsed suite file: its settings, output directory and runs in order."""

    path: Path
    config: SuiteConfig
    out: Path
    entries: tuple[Entry, ...]


def suite_names() -> list[str]:
    """The packaged suites' names."""
    d = specs.spec_dir()
    return sorted(p.stem for p in (d / SUITE_FOLDER).glob("*.toml")) if d is not None else []


def resolve_suite(suite: str | Path) -> Path:
    """The suite file of `suite`: an existing path or a packaged suite's name."""
    path = Path(suite)
    if path.is_file():
        return path
    d = specs.spec_dir()
    name = str(suite).removesuffix(".toml")
    if d is not None and "/" not in name and (d / SUITE_FOLDER / f"{name}.toml").is_file():
        return d / SUITE_FOLDER / f"{name}.toml"
    close = difflib.get_close_matches(name, suite_names(), n=3)
    hint = f"; close names: {', '.join(close)}" if close else f"; packaged suites: {', '.join(suite_names())}"
    raise ConfigError(f"suite {str(suite)!r}: expected a suite file or the name of a packaged suite{hint}")


def _task_of(spec: Mapping[str, Any]) -> str | None:
    """The task a spec runs on: `[task] name` (QD), `[env] task` (skills) or `[env] name` (RL)."""
    task, env = spec.get("task", {}), spec.get("env", {})
    if isinstance(task, Mapping) and "name" in task:
        return str(task["name"])
    if isinstance(env, Mapping):
        return str(env.get("task", env.get("name"))) if ("task" in env or "name" in env) else None
    return None


def load_suite(suite: str | Path, out_dir: str | Path | None = None, check: bool = True) -> Suite:
    """The suite of a file (or packaged name), every spec it names resolved and, with `check`,
    checked with its overrides (`qdrl.experiment.check_spec`: nothing built); ConfigError naming
    the key and what it accepts otherwise."""
    path = resolve_suite(suite)
    data = load_toml(path)
    unknown = sorted(set(data) - {"suite", "runs"})
    if unknown:
        raise ConfigError(f"{unknown[0]}: expected the sections [suite] and [[runs]], got [{unknown[0]}]")
    config = build(SuiteConfig, data.get("suite", {}), "suite")
    groups = data.get("runs")
    if not isinstance(groups, list) or not groups:
        raise ConfigError("runs: expected one [[runs]] table or more (specs, algorithms, tasks), got none")
    name = config.name or path.stem
    out = Path(out_dir) if out_dir is not None else Path("runs") / name
    budget = []
    if config.time_limit_s is not None:
        budget.append(f"experiment.time_limit_s={config.time_limit_s!r}")
    if config.env_steps is not None:
        budget.append(f"experiment.env_steps_limit={config.env_steps}")
    entries: list[Entry] = []
    seen: set[tuple[str, str]] = set()
    for i, table in enumerate(groups):
        where = f"runs[{i}]"
        group = build(GroupConfig, check_table(table, where), where)
        for key in ("specs", "algorithms", "tasks"):
            if not getattr(group, key):
                raise ConfigError(f"{where}.{key}: expected a non-empty value, got none")
        for task in group.tasks:
            for algorithm in group.algorithms:
                if (task, algorithm) in seen:
                    raise ConfigError(f"{where}: {algorithm} on {task} is listed twice; expected each pair once")
                seen.add((task, algorithm))
                try:
                    text = group.specs.format(algorithm=algorithm, task=task)
                except (KeyError, IndexError, ValueError) as e:
                    raise ConfigError(
                        f"{where}.specs: expected a name with the placeholders {{algorithm}} and {{task}} only, "
                        f"got {group.specs!r}"
                    ) from e
                try:
                    spec_path = specs.resolve(text)
                except ConfigError as e:
                    raise ConfigError(f"{where}.specs: {algorithm} on {task}: {e}") from None
                for seed in config.seeds:
                    overrides = (f"experiment.seed={seed}", *budget)
                    entries.append(Entry(task, algorithm, seed, spec_path, out / task / algorithm / f"seed_{seed}", overrides))
    if check:
        for entry in entries[:: len(config.seeds)]:  # one check per spec: the seeds differ in the seed only
            spec = specs.load_spec(entry.spec, list(entry.overrides))
            task = _task_of(spec)
            if task is not None and task != entry.task:
                raise ConfigError(
                    f"runs: the spec {entry.spec.name} of {entry.algorithm} on {entry.task} runs on {task!r}; "
                    f"expected a spec of the task {entry.task!r}"
                )
            try:
                check_spec(spec)
            except ConfigError as e:
                raise ConfigError(f"{entry.spec.name} ({entry.algorithm} on {entry.task}): {e}") from None
    return Suite(path, config, out, tuple(entries))


def entry_status(entry: Entry) -> dict[str, Any]:
    """Where one run stands: "done" (finished, or stopped at the suite's budget, with these
    settings), "partial" (checkpoints, not done: `run` resumes it) or "not started"; with its
    environment steps and wall time so far."""
    spec = specs.load_spec(entry.spec, list(entry.overrides))
    out: dict[str, Any] = {"task": entry.task, "algorithm": entry.algorithm, "seed": entry.seed, "dir": str(entry.out)}
    summary = finished_as_given(entry.out, spec)
    if summary is not None:
        out.update({"status": "done", "env_steps": summary.get("env_steps"), "wall_s": summary.get("wall_s")})
        out["stopped_by"] = summary.get("stopped_by", "length")
        return out
    found = checkpoint.checkpoints(entry.out / "checkpoints")
    if found:
        meta = checkpoint.read_metadata(found[-1])
        out.update({"status": "partial", "env_steps": meta.get("env_steps"), "wall_s": meta.get("wall_s")})
        return out
    out["status"] = "not started"
    return out


def suite_status(suite: Suite) -> dict[str, Any]:
    """Every run's `entry_status`, and the counts by status."""
    runs = [entry_status(e) for e in suite.entries]
    counts = {s: sum(r["status"] == s for r in runs) for s in ("done", "partial", "not started")}
    return {"suite": str(suite.path), "out": str(suite.out), "runs": runs, "counts": counts}


def _write_index(suite: Suite) -> None:
    """OUT/suite.json: the suite file, its budget and every run's status (rewritten after each run)."""
    suite.out.mkdir(parents=True, exist_ok=True)
    status = suite_status(suite)
    status["budget"] = {"time_limit_s": suite.config.time_limit_s, "env_steps": suite.config.env_steps}
    tmp = suite.out / "suite.json.tmp"
    tmp.write_text(json.dumps(status, indent=2) + "\n")
    tmp.replace(suite.out / "suite.json")


def run_suite(suite: Suite, on_start: Callable[[Path], None] | None = None) -> dict[str, Any]:
    """Runs every run of `suite` that is not done, one after the other (see the module
    docstring); returns `suite_status` after the last. RunInterrupted propagates (Ctrl-C):
    the next call resumes from the run's checkpoint."""
    todo = [(e, entry_status(e)) for e in suite.entries]
    left = [(e, s) for e, s in todo if s["status"] != "done"]
    print(
        f"qdrl: suite {suite.config.name or suite.path.stem}: {len(todo) - len(left)} of {len(todo)} runs done, "
        f"{len(left)} to run, into {suite.out}", file=sys.stderr,
    )
    _write_index(suite)
    for i, (entry, status) in enumerate(left):
        spec = specs.load_spec(entry.spec, list(entry.overrides))
        resume = bool(checkpoint.checkpoints(entry.out / "checkpoints"))
        label = f"{entry.algorithm} on {entry.task}, seed {entry.seed} ({i + 1} of {len(left)} left)"
        if status["status"] == "partial":
            label += ", resumed"
        run(spec, entry.out, resume=resume, overwrite=not resume, label=label, on_start=on_start)
        _write_index(suite)
    return suite_status(suite)
