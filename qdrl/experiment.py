"""Run an experiment spec: the driver every algorithm, RL or QD, shares.

An algorithm is a row of the table (`qdrl.algorithms`): a recipe whose `build` gives
pure functions (`qdrl.algorithms.base.Algorithm`). The driver is the only place
that compiles them: it jits `init`, compiles `chunk` once ahead of time with its
state donated (timed), places the state on the devices, and runs the chunks. It
owns everything around them: the output directory, the progress line (a compile
timer, then a bar over iterations or env steps), `metrics.csv`, checkpoints named
by log point, `--resume` (falling back past unusable checkpoints, and extending a
run when only its length changed), Ctrl-C, `summary.json` and plots. Python runs
only between chunks.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import shlex
import shutil
import sys
import time
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np

from qdrl import (
    checkpoint,
    compile_cache,
    compiling,
    interrupt,
    loggers,
    placement,
    plotting,
)
from qdrl._version import __version__
from qdrl.algorithms import ALGORITHMS, algorithm_names, recipe
from qdrl.algorithms.base import (
    Algorithm,
    BuildContext,
    ExperimentConfig,
    LogConfig,
    Row,
    Sections,
    scalar,
)
from qdrl.config import (
    ConfigError,
    as_table,
    build,
    check_table,
    did_you_mean,
    dump_toml,
)
from qdrl.progress import RunProgress
from qdrl.specs import load_spec

__all__ = [
    "CheckedSpec",
    "ExperimentConfig",
    "LogConfig",
    "RunInterrupted",
    "build_run",
    "check_spec",
    "check_spec_file",
    "compile_chunk",
    "default_out_dir",
    "initial_state",
    "load_spec",
    "resolved_toml",
    "resume_command",
    "run",
    "run_chunk",
    "run_spec",
    "scalar",
    "spec_changes",
]


@dataclasses.dataclass(frozen=True)
class CheckedSpec:
    """A spec whose every section is parsed into a checked config; nothing built yet."""

    experiment: ExperimentConfig
    log: LogConfig
    sections: Sections  # the algorithm's own sections


def check_spec(spec: Mapping[str, Any]) -> CheckedSpec:
    """Parse and check every section of a spec (pure Python, milliseconds); raises ConfigError.

    Every value is checked for type, finiteness and range, every name against its
    registry, before any task, environment or network is built.
    """
    if "experiment" not in spec:
        raise ConfigError("experiment: missing section; expected [experiment] with algorithm = ...")
    experiment = check_table(spec["experiment"], "experiment")
    name = experiment.get("algorithm")
    if name is None:
        raise ConfigError(f"experiment.algorithm: missing; expected one of {algorithm_names()}")
    if not isinstance(name, str):
        raise ConfigError(f"experiment.algorithm: expected one of {algorithm_names()}, got {name!r}")
    arrays = recipe(name).array_sections
    for name, table in spec.items():
        if not isinstance(table, list) and name not in arrays:
            check_table(table, name)
    exp = build(ExperimentConfig, experiment, "experiment")
    log = build(LogConfig, spec.get("log", {}), "log")
    sections = recipe(exp.algorithm).parse(spec, exp)
    known = {"experiment", "log", *sections}
    unknown = sorted(set(spec) - known)
    if unknown:
        raise ConfigError(
            f"{unknown[0]}: unknown section for algorithm {exp.algorithm!r}"
            f"{did_you_mean(unknown[0], known)}; expected sections {sorted(known)}"
        )
    return CheckedSpec(exp, log, sections)


def build_run(spec: Mapping[str, Any], centroids: Any = None) -> tuple[Algorithm, ExperimentConfig, LogConfig]:
    """Check a whole spec (`check_spec`), then build its algorithm (no compilation); raises
    ConfigError. `centroids`: a CVT repertoire's known cells (no k-means)."""
    checked = check_spec(spec)
    exp = checked.experiment
    context = BuildContext(exp.algorithm, exp.seed, exp.devices, centroids)
    return ALGORITHMS[exp.algorithm].build(checked.sections, context), exp, checked.log


def resolved_toml(alg: Algorithm, exp: ExperimentConfig, log: LogConfig) -> str:
    """The spec with every default filled in, as TOML."""
    sections: dict[str, Any] = {"experiment": as_table(exp)}
    for k, v in alg.sections.items():  # a tuple of configs is an array of tables ([[k]])
        sections[k] = [as_table(x) for x in v] if isinstance(v, tuple) else as_table(v)
    sections["log"] = as_table(log)
    return dump_toml(sections)


def check_spec_file(spec_path: str | Path, overrides: list[str] | None = None) -> str:
    """Check the spec at `spec_path` as `run_spec` would, building its algorithm but compiling
    and running nothing; returns the resolved spec (every default filled in) as TOML."""
    return resolved_toml(*build_run(load_spec(spec_path, overrides)))


def default_out_dir(spec_path: str | Path) -> Path:
    """Where `qdrl run SPEC` writes without --out: runs/<spec file stem> (SPEC: a path or a name)."""
    return Path("runs") / Path(spec_path).name.removesuffix(".toml")


def run_spec(
    spec_path: str | Path,
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_start: Callable[[Path], None] | None = None,
) -> dict[str, Any]:
    """Run the spec at `spec_path` (a path, or a packaged spec's name; with `--set`
    overrides) and return its summary; `on_start` as in `run`."""
    spec = load_spec(spec_path, overrides)
    out = Path(out_dir) if out_dir else default_out_dir(spec_path)
    return run(spec, out, resume, overwrite, on_start=on_start)


# -- the run directory --


def _parse_cell(text: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        return float(text)


def read_rows(path: Path) -> list[Row]:
    """The rows of a metrics.csv (none when it does not exist)."""
    if not path.exists():
        return []
    with path.open() as f:
        return [{k: _parse_cell(v) for k, v in row.items()} for row in csv.DictReader(f)]


def _write_rows(path: Path, rows: list[Row]) -> None:
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        if rows:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    tmp.replace(path)


def _append_row(path: Path, row: Row) -> None:
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)


def flat_spec(toml_text: str) -> dict[str, Any]:
    """A resolved spec's values by `section.key` (`section[i].key` in arrays of tables)."""
    flat: dict[str, Any] = {}
    for s, table in tomllib.loads(toml_text).items():
        tables = {f"{s}[{i}]": t for i, t in enumerate(table)} if isinstance(table, list) else {s: table}
        flat.update({f"{name}.{k}": v for name, t in tables.items() for k, v in t.items()})
    return flat


_ABSENT = object()


def _show(value: Any) -> str:
    return "(absent)" if value is _ABSENT else json.dumps(value)


def spec_changes(old_toml: str, new_toml: str) -> list[tuple[str, Any, Any]]:
    """`(section.key, old, new)` for each key whose value differs (`_ABSENT` where missing)."""
    old, new = flat_spec(old_toml), flat_spec(new_toml)
    keys = [*old, *(k for k in new if k not in old)]
    return [(k, old.get(k, _ABSENT), new.get(k, _ABSENT)) for k in keys if old.get(k, _ABSENT) != new.get(k, _ABSENT)]


def _check_resume_spec(
    config_path: Path, config_text: str, length_key: str, given: frozenset[str] = frozenset()
) -> None:
    """Raises ConfigError naming each differing key unless only the length key and [log] differ.

    A key the run's resolved spec lacks (one qdrl added since the run was made) and the spec
    does not set (`given`: its flat keys) resolves to its default: not a change."""
    if not config_path.is_file():
        raise ConfigError(f"--resume: {config_path} is missing; expected the resolved spec of the run")
    changes = [
        c for c in spec_changes(config_path.read_text(), config_text)
        if not (c[1] is _ABSENT and c[0] not in given)
    ]
    free = (length_key, TIME_LIMIT_KEY, ENV_STEPS_LIMIT_KEY)
    fixed = [c for c in changes if c[0] not in free and not c[0].startswith("log.")]
    if fixed:
        listed = ", ".join(f"{k} {_show(a)} -> {_show(b)}" for k, a, b in changes)
        raise ConfigError(
            f"--resume: the spec differs from {config_path}: {listed}; only "
            f"{length_key} (to extend the run), {TIME_LIMIT_KEY}, {ENV_STEPS_LIMIT_KEY} and [log] may change on resume"
        )


def _check_time_limit(out_dir: Path, time_limit_s: float | None, env_steps_limit: int | None = None) -> None:
    """Refuses (before compiling) to resume a run stopped at its time limit (or its
    environment-steps limit) with a limit that it has already reached: it would stop again at once."""
    try:
        summary = json.loads((out_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return
    if not isinstance(summary, dict):
        return
    budgets = {  # the reason a run stopped -> (its new limit, what it has done, the key, the flag)
        "time_limit": (time_limit_s, float(summary.get("wall_s", 0.0)), TIME_LIMIT_KEY, " (--time-limit)"),
        "env_steps_limit": (env_steps_limit, int(summary.get("env_steps", 0)), ENV_STEPS_LIMIT_KEY, ""),
    }
    if summary.get("stopped_by") not in budgets:
        return
    limit, done, key, flag = budgets[summary["stopped_by"]]
    if limit is not None and limit <= done:
        what = f"its time limit after {done:.0f} s" if key == TIME_LIMIT_KEY else (
            f"its environment-steps limit after {done:,} steps"
        )
        raise ConfigError(
            f"--resume: {out_dir} stopped at {what}; expected a larger {key}{flag} than that, or none, got {limit:g}"
        )


TIME_LIMIT_KEY = "experiment.time_limit_s"
ENV_STEPS_LIMIT_KEY = "experiment.env_steps_limit"


def _newest_log_point(ckpt_dir: Path) -> tuple[Path | None, int]:
    """The newest checkpoint that verifies and the log points it holds; (None, 0) without one."""
    for path in checkpoint.checkpoints(ckpt_dir):
        try:
            checkpoint.verify(path)
            return path, int(checkpoint.read_metadata(path)["chunk"]) + 1
        except (checkpoint.CheckpointError, KeyError, TypeError, ValueError):
            continue
    return None, 0


def _check_resume_checkpoints(found: list[Path], num_chunks: int, length_key: str) -> None:
    """Fails fast (before compiling) when no checkpoint verifies or the new length is too short."""
    reasons = []
    for path in found:
        try:
            checkpoint.verify(path)
            done = int(checkpoint.read_metadata(path)["chunk"]) + 1
        except (checkpoint.CheckpointError, KeyError, TypeError, ValueError) as e:
            reasons.append(f"{path.name}: {e}")
            continue
        if done > num_chunks:
            raise ConfigError(
                f"--resume: expected a length of at least the {done} log points already run "
                f"({path.name}), got {num_chunks}; only a longer or equal {length_key} may be given"
            )
        return
    raise ConfigError(f"--resume: no usable checkpoint in {found[0].parent} ({'; '.join(reasons)})")


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a run cleanly; `checkpoint` holds its newest complete log point (or None)."""

    def __init__(self, out_dir: Path, checkpoint: Path | None, log_points: int, num_chunks: int) -> None:
        self.out_dir, self.checkpoint = out_dir, checkpoint
        self.log_points, self.num_chunks = log_points, num_chunks
        if checkpoint is None:
            text = f"interrupted before the first log point of {num_chunks}; nothing saved"
        else:
            text = (f"interrupted at log point {log_points} of {num_chunks}; "
                    f"{checkpoint} holds the run up to there")
        super().__init__(text)


def resume_command(
    spec_path: str | Path, overrides: list[str], out_dir: str | Path, seeds: str | None = None
) -> str:
    """The shell command that resumes a run (or, with `seeds`, a sweep) started by `qdrl run`
    with these arguments."""
    args = ["qdrl", "run", str(spec_path)]
    if seeds is not None:
        args += ["--seeds", seeds]
    for text in overrides:
        args += ["--set", text]
    return shlex.join([*args, "--out", str(out_dir), "--resume"])


# -- running --


def _context(alg: Algorithm) -> contextlib.AbstractContextManager[Any]:
    return contextlib.nullcontext() if alg.run_context is None else alg.run_context()


def initial_state(alg: Algorithm, seed: int) -> Any:
    """`alg.init` of the seed's key, jitted (every leaf its own buffer, as donation needs)."""
    with _context(alg):
        return jax.jit(alg.init)(jax.random.PRNGKey(seed))


def compile_chunk(alg: Algorithm, state: Any) -> compiling.Compiled:
    """`alg.chunk` compiled ahead of time for `state` on the algorithm's devices, its state donated."""
    with _context(alg):
        return compiling.compile_timed(alg.chunk, alg.placement.place(state, alg.state_axes), donate_argnums=0)


def run_chunk(alg: Algorithm, chunk_fn: Callable[[Any], Any], state: Any) -> tuple[Any, Any]:
    """One compiled chunk (`compile_chunk(...).fn`) on `state` placed on the algorithm's devices;
    inside the algorithm's context, waiting there for the result (CMA-ES: one LAPACK thread)."""
    placed = alg.placement.place(state, alg.state_axes)
    if alg.run_context is None:
        out: tuple[Any, Any] = chunk_fn(placed)
        return out
    with alg.run_context():
        return jax.block_until_ready(chunk_fn(placed))  # type: ignore[no-any-return]


@dataclasses.dataclass
class _Session:
    """What one `run` call carries between its phases."""

    alg: Algorithm
    exp: ExperimentConfig
    log: LogConfig
    out_dir: Path
    primary: bool
    config_text: str
    started: float
    rows: list[Row] = dataclasses.field(default_factory=list)
    start_chunk: int = 0
    wall_offset: float = 0.0
    run_s: float = 0.0
    compile_s: float = 0.0  # the chunk's compilation
    stopped_at: int = 0  # log points done when a budget (time, env steps) stopped the run (0: not stopped)
    stopped_by: str = ""  # why: "time_limit" or "env_steps_limit"
    startup_s: float = 0.0  # this session's start: initial state, checkpoint, compilations

    @property
    def ckpt_dir(self) -> Path:
        return self.out_dir / "checkpoints"

    def progress_value(self, row: Mapping[str, Any], chunk: int) -> int:
        unit = self.alg.progress.unit
        return chunk + 1 if unit == "log_point" else int(row[unit])


def _open(spec: Mapping[str, Any], out_dir: Path, resume: bool, overwrite: bool, started: float) -> _Session:
    """Build the run and prepare its directory; every refusal comes here, before compiling."""
    alg, exp, log = build_run(spec)
    # Under jax.distributed every process runs the same spec; process 0 alone writes
    # the run directory (read by all on --resume: it must be on a shared filesystem).
    s = _Session(alg, exp, log, out_dir, placement.is_primary(), resolved_toml(alg, exp, log), started)
    length_key = ALGORITHMS[exp.algorithm].length_key
    found = checkpoint.checkpoints(s.ckpt_dir)
    if found and not resume and not overwrite:
        raise ConfigError(
            f"{out_dir} already holds a run with checkpoints; pass --resume to continue it, "
            "--overwrite to discard it, or --out for a new directory"
        )
    if resume:
        if not found:
            raise ConfigError(f"--resume: no checkpoint found in {s.ckpt_dir}")
        given = frozenset(
            f"{section}.{key}" for section, table in spec.items() if isinstance(table, Mapping) for key in table
        )
        _check_resume_spec(out_dir / "config.toml", s.config_text, length_key, given)
        _check_resume_checkpoints(found, alg.num_chunks, length_key)
        _check_time_limit(out_dir, exp.time_limit_s, exp.env_steps_limit)
    if s.primary and overwrite and not resume and out_dir.exists():
        shutil.rmtree(out_dir)
    if s.primary:
        out_dir.mkdir(parents=True, exist_ok=True)
    if s.primary and not resume:
        (out_dir / "config.toml").write_text(s.config_text)
    return s


def _prepare(s: _Session, resume: bool) -> tuple[Any, Any, dict[str, Any], Path | None, list[tuple[Path, str]]]:
    """The initial state (or the newest usable checkpoint's) and the compiled chunk; the chunk
    is None when a resumed run has nothing left to run."""
    state = initial_state(s.alg, s.exp.seed)
    meta: dict[str, Any] = {}
    path: Path | None = None
    skipped: list[tuple[Path, str]] = []
    if resume:
        state, meta, path, skipped = checkpoint.restore_newest(s.ckpt_dir, state)
        if int(meta["chunk"]) + 1 >= s.alg.num_chunks:  # finished: nothing to compile
            return state, None, meta, path, skipped
    compiled = compile_chunk(s.alg, state)
    s.compile_s = compiled.seconds
    return state, compiled.fn, meta, path, skipped


def _resume_rows(s: _Session, meta: Mapping[str, Any], restored: Path, skipped: list[tuple[Path, str]]) -> None:
    """The rows and timings of the earlier sessions of a resumed run, as its checkpoint holds them."""
    for path, why in skipped if s.primary else ():
        checkpoint.remove(path)
        print(f"qdrl: --resume: {path.name} is unusable ({why}); removed it", file=sys.stderr)
    s.start_chunk = int(meta["chunk"]) + 1
    if skipped:
        print(
            f"qdrl: --resume: resuming from {restored.name} (log point {s.start_chunk} of "
            f"{s.alg.num_chunks})", file=sys.stderr,
        )
    s.wall_offset, s.run_s = float(meta["wall_s"]), float(meta["run_s"])
    s.rows = read_rows(s.out_dir / "metrics.csv")[: s.start_chunk]
    if s.primary:
        _write_rows(s.out_dir / "metrics.csv", s.rows)
        (s.out_dir / "config.toml").write_text(s.config_text)


def _loop(
    s: _Session, state: Any, chunk_fn: Any, last_saved: Path | None, progress: RunProgress,
    dashboards: loggers.Loggers, stop: interrupt.Interrupts, worker: interrupt.Worker,
) -> Any:
    """Runs the chunks left, logging and checkpointing each; returns the final state."""
    alg, metrics_path = s.alg, s.out_dir / "metrics.csv"

    def save(chunk: int, row: Mapping[str, Any], wall_s: float) -> Path:
        meta = {
            "chunk": chunk, "env_steps": int(row["env_steps"]), "wall_s": wall_s, "run_s": s.run_s,
            "qdrl_version": __version__,
        }
        host = placement.fetch(state)  # every process takes part: parts may live in others
        if not s.primary:
            return s.ckpt_dir / checkpoint.step_name(chunk + 1)
        return checkpoint.save(s.ckpt_dir, chunk + 1, host, meta, keep=s.log.keep_checkpoints)

    for chunk in range(s.start_chunk, alg.num_chunks):
        t0 = time.perf_counter()
        state, metrics = run_chunk(alg, chunk_fn, state)
        worker.wait_ready((state, metrics))
        s.run_s += time.perf_counter() - t0
        # Wall time since the run's start, compilation included; a resumed run adds the
        # time of its earlier sessions.
        wall_s = s.wall_offset + time.perf_counter() - s.started
        row = {"log_point": chunk, **alg.log_row(state, metrics), "wall_s": wall_s}
        # Throughput excludes compilation; QD runs also count evaluations. Tasks that step
        # no environment (functions, the arm) have no env steps per second.
        if row["env_steps"] > 0:
            row["env_steps_per_s"] = row["env_steps"] / s.run_s if s.run_s > 0 else math.nan
        if "evaluations" in row:
            row["evaluations_per_s"] = row["evaluations"] / s.run_s if s.run_s > 0 else math.nan
        s.rows.append(row)
        if s.primary:
            _append_row(metrics_path, row)
            if alg.on_log_point is not None:
                alg.on_log_point(s.out_dir)
        dashboards.log(row, s.progress_value(row, chunk))
        last = chunk == alg.num_chunks - 1
        saved = (chunk + 1) % s.log.checkpoint_every == 0 or last
        if saved:
            last_saved = save(chunk, row, wall_s)
        progress.update(
            s.progress_value(row, chunk), {k: _fmt(v) for k, v in row.items() if k in alg.progress.keys}
        )
        if stop.requested and not last:
            if not saved:
                last_saved = save(chunk, row, wall_s)
            raise RunInterrupted(s.out_dir, last_saved, chunk + 1, alg.num_chunks)
        limit, steps_limit = s.exp.time_limit_s, s.exp.env_steps_limit
        if limit is not None and wall_s >= limit:
            reason = "time_limit"
        elif steps_limit is not None and row["env_steps"] >= steps_limit:
            reason = "env_steps_limit"
        else:
            reason = None
        if reason is not None and not last:  # the budget is spent: stop here
            if not saved:
                last_saved = save(chunk, row, wall_s)
            s.stopped_at, s.stopped_by = chunk + 1, reason
            break
    return state


def _summary(s: _Session, state: Any) -> dict[str, Any]:
    """summary.json: the last row, the run's identity and timings, and the algorithm's extras."""
    alg, exp = s.alg, s.exp
    final = s.rows[-1] if s.rows else {}
    summary: dict[str, Any] = {
        "algorithm": exp.algorithm,
        "task": alg.task,
        "name": exp.name,
        "seed": exp.seed,
        "env_steps": int(final.get("env_steps", 0)),
        "wall_s": final.get("wall_s", 0.0),
        "compile_s": s.compile_s,
        "startup_s": s.startup_s,
        "run_s": s.run_s,
    }
    if s.stopped_at:  # why the run ended before its length
        limit = {"time_limit_s": s.exp.time_limit_s} if s.stopped_by == "time_limit" else {
            "env_steps_limit": s.exp.env_steps_limit
        }
        summary.update({
            "stopped_by": s.stopped_by, **limit, "log_points": s.stopped_at, "num_log_points": alg.num_chunks,
        })
    if "env_steps_per_s" in final:
        summary["env_steps_per_s"] = final["env_steps_per_s"]
    if "evaluations" in final:
        summary["evaluations"] = int(final["evaluations"])
    summary.update({k: v for k, v in final.items() if k not in summary and k != "log_point"})
    if alg.descriptor_space is not None:  # for reports that draw repertoires without rebuilding the run
        space = alg.descriptor_space
        summary["descriptor_low"] = [float(v) for v in space.low]
        summary["descriptor_high"] = [float(v) for v in space.high]
        summary["descriptor_names"] = list(space.names)
    if placement.is_distributed():
        state = placement.fetch(state)  # finish reads every part on process 0
    if not s.primary:
        return summary
    summary.update(alg.finish(state, s.rows, s.out_dir))
    if s.log.plots and alg.plot is not None:
        alg.plot(state, s.rows, s.out_dir)
    if s.log.plots and s.rows:
        plotting.plot_curves(
            s.rows, s.out_dir / "plots", x_keys=plotting.default_x_keys(s.rows), y_keys=alg.curves,
            title=f"{exp.algorithm} on {alg.task}",
        )
    summary = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in summary.items()}
    (s.out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")
    return summary


def run(
    spec: Mapping[str, Any], out_dir: Path, resume: bool = False, overwrite: bool = False,
    label: str = "", on_start: Callable[[Path], None] | None = None,
) -> dict[str, Any]:
    """Run a parsed spec into `out_dir`; see the module docstring for what it writes.

    `label` is added to the progress line (a sweep names the seed there);
    `on_start(out_dir)` is called once the spec and any resume are checked, before
    compiling (`qdrl run` says there where it writes).

    Raises:
      ConfigError: a bad spec, or a --resume that cannot be honoured; before any compilation.
      RunInterrupted: Ctrl-C stopped the run (after checkpointing its last complete chunk).
      KeyboardInterrupt: a second Ctrl-C aborted it; the newest checkpoint on disk is kept.
    """
    s = _open(spec, out_dir, resume, overwrite, time.perf_counter())
    if on_start is not None:
        on_start(out_dir)
    finished = _finished_summary(s) if resume else None
    if finished is not None:
        length_key = ALGORITHMS[s.exp.algorithm].length_key
        print(
            f"qdrl: --resume: {out_dir} is a finished run ({s.alg.num_chunks} of "
            f"{s.alg.num_chunks} log points); nothing to run (to extend it, resume with a "
            f"larger {length_key}: --set {length_key}=...)", file=sys.stderr,
        )
        return finished
    alg, exp, log = s.alg, s.exp, s.log
    what = f"{exp.algorithm} on {alg.task}" + (f" ({label})" if label else "")
    progress = RunProgress(log.progress and s.primary, what, alg.progress.unit, alg.progress.total)
    key = compile_cache.spec_key(s.config_text, ALGORITHMS[exp.algorithm].length_key)
    stop_message = (
        "qdrl: stopping after the chunk in flight and saving a checkpoint "
        "(press Ctrl-C again to abort at once; the checkpoints on disk are kept)"
    )
    # Loggers start before compiling, so a missing package fails at once.
    with _make_loggers(log if s.primary else _NO_LOGGERS, out_dir, exp, s.config_text) as dashboards, \
            compile_cache.enabled(log.compile_cache), interrupt.Interrupts(stop_message) as stop, \
            interrupt.Worker() as worker:
        t0 = time.perf_counter()
        try:
            if alg.prepare is not None:  # a host computation of its own (a CVT's k-means), timed apart
                what, compute = alg.prepare
                progress.preparing(what)
                worker.call(compute, tick=progress.tick)
                progress.prepared(time.perf_counter() - t0)
            progress.compiling(compile_cache.estimate(key, exp.algorithm, alg.task))
            with compile_cache.cache_hits() as cache:
                state, chunk_fn, meta, restored, skipped = worker.call(
                    lambda: _prepare(s, resume), tick=progress.tick
                )
        except KeyboardInterrupt:
            progress.close()
            raise RunInterrupted(out_dir, *_newest_log_point(s.ckpt_dir), alg.num_chunks) from None
        except checkpoint.CheckpointError as e:
            progress.close()
            raise ConfigError(f"--resume: {e}{_written_by(s.ckpt_dir)}") from None
        s.startup_s = time.perf_counter() - t0
        placement.barrier("compiled")  # processes that compiled faster wait for the others
        progress.compiled(s.compile_s, s.startup_s)
        if s.primary:
            compile_cache.record(key, exp.algorithm, alg.task, s.startup_s, cold=cache["hits"] == 0)
        if restored is not None:
            _resume_rows(s, meta, restored, skipped)
        elif s.primary and (out_dir / "metrics.csv").exists():
            (out_dir / "metrics.csv").unlink()
        if s.primary:
            (out_dir / "summary.json").unlink(missing_ok=True)  # rewritten when the run ends
        stop.abort_at_once = False
        progress.start(s.progress_value(s.rows[-1], s.start_chunk - 1) if s.rows else 0)
        try:
            state = _loop(s, state, chunk_fn, restored, progress, dashboards, stop, worker)
        finally:
            progress.close()
    if s.stopped_at and s.stopped_by == "time_limit":
        print(
            f"qdrl: stopped at the time limit ({s.exp.time_limit_s:g} s) after log point {s.stopped_at} "
            f"of {alg.num_chunks} ({s.rows[-1]['wall_s']:.0f} s); --resume with a larger "
            f"{TIME_LIMIT_KEY} (--time-limit) continues it", file=sys.stderr,
        )
    elif s.stopped_at:
        print(
            f"qdrl: stopped at the environment-steps limit ({s.exp.env_steps_limit:,}) after log point "
            f"{s.stopped_at} of {alg.num_chunks} ({int(s.rows[-1]['env_steps']):,} steps); --resume with "
            f"a larger {ENV_STEPS_LIMIT_KEY} continues it", file=sys.stderr,
        )
    return _summary(s, state)


def _finished_summary(s: _Session) -> dict[str, Any] | None:
    """The summary of a run whose newest checkpoint is its last log point and whose summary.json
    was written (nothing to load or compile on --resume), else None."""
    newest = checkpoint.latest(s.ckpt_dir)
    try:
        done = newest is not None and int(checkpoint.read_metadata(newest)["chunk"]) + 1 >= s.alg.num_chunks
        summary = json.loads((s.out_dir / "summary.json").read_text()) if done else None
    except (OSError, ValueError, KeyError, TypeError, checkpoint.CheckpointError):
        return None
    return summary if isinstance(summary, dict) else None


def _written_by(ckpt_dir: Path) -> str:
    """Which qdrl wrote the newest checkpoint, when it is not this one (a checkpoint that no
    longer loads was most likely written by a qdrl whose state layout differs)."""
    for path in checkpoint.checkpoints(ckpt_dir):
        try:
            version = checkpoint.read_metadata(path).get("qdrl_version", "0.1.0")
        except (checkpoint.CheckpointError, ValueError, TypeError):
            continue
        if version != __version__:
            return f"; the checkpoints were written by qdrl {version}, this is qdrl {__version__}"
        return ""
    return ""


def _fmt(x: float) -> str:
    if isinstance(x, int):
        return str(x)
    return f"{x:.4g}" if math.isfinite(x) else "nan"


def _make_loggers(log: LogConfig, out_dir: Path, exp: ExperimentConfig, config_text: str) -> loggers.Loggers:
    """The TensorBoard and W&B loggers that `[log]` asks for (none by default)."""
    chosen: list[loggers.Logger] = []
    if log.tensorboard:
        chosen.append(loggers.TensorBoardLogger(out_dir / "tensorboard", config_text))
    if log.wandb:
        chosen.append(loggers.WandbLogger(
            out_dir, tomllib.loads(config_text), name=f"{exp.name} seed {exp.seed}",
            group=log.wandb_group or exp.name, project=log.wandb_project, entity=log.wandb_entity,
            mode=log.wandb_mode,
        ))
    return loggers.Loggers(chosen)


_NO_LOGGERS = LogConfig()  # processes other than 0 log nowhere (TensorBoard and W&B are off by default)


def _json_default(x: Any) -> Any:
    if isinstance(x, np.generic | np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x)}")
