"""Run an experiment spec: the driver every algorithm, RL or QD, shares.

The algorithm is a `Run`: it builds its state, compiles its chunk function once
ahead of time, and turns a chunk's result into one row of metrics. The driver
owns everything around it: the output directory, the progress line (a compile
timer, then a bar over iterations or env steps), `metrics.csv`, checkpoints
named by log point, `--resume` (falling back past unusable checkpoints, and
extending a run when only its length changed), Ctrl-C, `summary.json` and plots.
Python runs only between chunks.
"""

from __future__ import annotations

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
from typing import Annotated, Any, NamedTuple, Protocol

import jax
import numpy as np

from qdrl import checkpoint, compile_cache, interrupt, loggers, placement, specs
from qdrl.config import (
    ConfigError,
    NonNegativeInt,
    OneOf,
    PositiveInt,
    Range,
    apply_overrides,
    build,
    check_fields,
    check_table,
    dump_toml,
    load_toml,
)
from qdrl.progress import RunProgress


def algorithm_names() -> list[str]:
    """The algorithms a spec may name (`experiment.algorithm`)."""
    _load_builtin_runs()
    return sorted(RUNS)


AlgorithmName = Annotated[str, OneOf(algorithm_names)]
Seed = Annotated[int, Range(0, 2**32 - 1)]  # jax.random.PRNGKey keeps the low 32 bits


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """The `[experiment]` section: what to run and with which seed."""

    algorithm: AlgorithmName  # a name from `qdrl list`
    seed: Seed = 0  # seeds every random choice of the run
    name: str = ""  # a label for plots and summaries; default: the spec file's stem
    # Devices the run spreads its batch over (qdrl.placement); 0: every visible device
    # (of every process under jax.distributed). Batch sizes must divide by it.
    devices: NonNegativeInt = 0

    def check(self) -> None:
        check_fields(self, "experiment")

    @property
    def num_devices(self) -> int:
        """`devices` resolved against the visible devices; ConfigError when too many are asked for."""
        from qdrl.placement import resolve_devices

        return resolve_devices(self.devices)


@dataclasses.dataclass(frozen=True)
class LogConfig:
    """The `[log]` section: how the driver records a run.

    metrics.csv is always written and is the source of truth; TensorBoard and
    Weights & Biases receive the same rows as they are logged (`qdrl.loggers`).
    """

    checkpoint_every: PositiveInt = 1  # log points between checkpoints
    keep_checkpoints: PositiveInt = 2  # newest checkpoints kept on disk
    progress: bool = True  # show a progress bar
    plots: bool = True  # write plots/*.png at the end
    compile_cache: bool = True  # jax's persistent compilation cache (qdrl.compile_cache)
    tensorboard: bool = False  # also write TensorBoard event files to <run>/tensorboard/ (tensorboardX)
    wandb: bool = False  # also log to Weights & Biases (pip install "qdrl[wandb]")
    wandb_project: str = "qdrl"  # W&B project
    wandb_entity: str = ""  # W&B entity (user or team); default: the logged-in user's
    wandb_group: str = ""  # W&B group; default: the experiment's name, so seeds group together
    wandb_mode: loggers.WandbMode = "online"  # "offline" writes to <run>/wandb/ for `wandb sync`

    def check(self) -> None:
        check_fields(self, "log")


class Run(Protocol):
    """What an algorithm provides to the driver."""

    algorithm: str
    task: str
    num_chunks: int  # log points in the whole run
    sections: dict[str, Any]  # resolved config dataclasses, by section name
    progress_keys: tuple[str, ...]  # row keys shown on the progress bar
    # What the progress bar counts: a row key ("iteration", "env_steps"), or
    # "log_point" for log points, and its value at the end of the run.
    progress_unit: str
    progress_total: int

    def init(self, key: jax.Array) -> Any:
        """The run's initial state (a pytree), before any compilation."""
        ...

    def compile(self, state: Any) -> float:
        """Compile every jitted function of the run ahead of time; returns seconds taken."""
        ...

    def run_chunk(self, state: Any) -> tuple[Any, Any]:
        """One chunk of iterations (compiled): (state, device metrics)."""
        ...

    def log_row(self, state: Any, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        """One row of metrics after chunk `chunk`; must include `env_steps`.

        Counts are Python ints (see `scalar`), so metrics.csv writes them as integers.
        """
        ...

    def finish(self, state: Any, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        """Write any final artefacts (extra plots, exports); returns extra summary fields."""
        ...


Sections = dict[str, Any]  # section name -> its checked config dataclass (or table)
# The parse-and-check phase of an algorithm: a spec -> its own sections, every value
# checked (`qdrl.config.build`). Pure Python: builds no task, environment or network.
SpecParser = Callable[[Mapping[str, Any], ExperimentConfig], Sections]
# The build phase: checked sections -> a `Run` (tasks, environments, networks); compiles nothing.
RunBuilder = Callable[[Sections, ExperimentConfig], Run]


class Algorithm(NamedTuple):
    """How a spec of one algorithm is parsed and checked, then built."""

    parse: SpecParser
    build: RunBuilder


RUNS: dict[str, Algorithm] = {}
# Sections written as arrays of tables ([[name]], e.g. a QD pool's [[emitters]]); the
# runners that read them add their names and check them (a list of tables) themselves.
ARRAY_SECTIONS: set[str] = set()


def register(name: str, parse: SpecParser, build: RunBuilder) -> None:
    """Register an algorithm: its spec parser and its run builder."""
    RUNS[name] = Algorithm(parse, build)


def scalar(x: Any) -> int | float:
    """A 0-d metric as a Python number: an int for integer and bool dtypes, else a float."""
    a = np.asarray(x)
    return int(a) if a.dtype.kind in "biu" else float(a)


# The keys that set a run's length: the only ones (with [log]) that may change on
# --resume, which then extends (or finishes) the run.
LENGTH_KEYS: tuple[str, ...] = ("qd.num_iterations", "train.total_env_steps", "cma_es.num_generations")


def _load_builtin_runs() -> None:
    from qdrl.runners import cma_es, mo, pbt, qd, rl, skills  # noqa: F401  (registers their algorithms)


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
    _load_builtin_runs()
    for name, table in spec.items():
        if not isinstance(table, list) and name not in ARRAY_SECTIONS:
            check_table(table, name)
    if "experiment" not in spec:
        raise ConfigError("experiment: missing section; expected [experiment] with algorithm = ...")
    exp = build(ExperimentConfig, spec["experiment"], "experiment")
    log = build(LogConfig, spec.get("log", {}), "log")
    sections = RUNS[exp.algorithm].parse(spec, exp)
    known = {"experiment", "log", *sections}
    unknown = sorted(set(spec) - known)
    if unknown:
        raise ConfigError(
            f"{unknown[0]}: unknown section for algorithm {exp.algorithm!r}; "
            f"expected sections {sorted(known)}"
        )
    return CheckedSpec(exp, log, sections)


def build_run(spec: Mapping[str, Any]) -> tuple[Run, ExperimentConfig, LogConfig]:
    """Check a whole spec (`check_spec`), then build its run (no compilation); raises ConfigError."""
    checked = check_spec(spec)
    run = RUNS[checked.experiment.algorithm].build(checked.sections, checked.experiment)
    return run, checked.experiment, checked.log


def resolved_toml(run: Run, exp: ExperimentConfig, log: LogConfig) -> str:
    """The spec with every default filled in, as TOML."""
    from qdrl.config import as_table

    sections: dict[str, Any] = {"experiment": as_table(exp)}
    for k, v in run.sections.items():  # a tuple of configs is an array of tables ([[k]])
        sections[k] = [as_table(x) for x in v] if isinstance(v, tuple) else as_table(v)
    sections["log"] = as_table(log)
    return dump_toml(sections)


def _parse_cell(text: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        return float(text)


def _read_rows(path: Path) -> list[dict[str, float]]:
    if not path.exists():
        return []
    with path.open() as f:
        return [{k: _parse_cell(v) for k, v in row.items()} for row in csv.DictReader(f)]


def _write_rows(path: Path, rows: list[dict[str, float]]) -> None:
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        if rows:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    tmp.replace(path)


def _append_row(path: Path, row: dict[str, float]) -> None:
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)


def _fmt(x: float) -> str:
    if isinstance(x, int):
        return str(x)
    return f"{x:.4g}" if math.isfinite(x) else "nan"


def _flat(toml_text: str) -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for s, table in tomllib.loads(toml_text).items():
        tables = {f"{s}[{i}]": t for i, t in enumerate(table)} if isinstance(table, list) else {s: table}
        flat.update({f"{name}.{k}": v for name, t in tables.items() for k, v in t.items()})
    return flat


def _show(value: Any) -> str:
    return "(absent)" if value is _ABSENT else json.dumps(value)


_ABSENT = object()


def spec_changes(old_toml: str, new_toml: str) -> list[tuple[str, Any, Any]]:
    """`(section.key, old, new)` for each key whose value differs (`_ABSENT` where missing)."""
    old, new = _flat(old_toml), _flat(new_toml)
    keys = [*old, *(k for k in new if k not in old)]
    return [(k, old.get(k, _ABSENT), new.get(k, _ABSENT)) for k in keys if old.get(k, _ABSENT) != new.get(k, _ABSENT)]


def _check_resume_spec(config_path: Path, config_text: str) -> None:
    """Raises ConfigError naming each differing key unless only length keys and [log] differ."""
    if not config_path.is_file():
        raise ConfigError(f"--resume: {config_path} is missing; expected the resolved spec of the run")
    changes = spec_changes(config_path.read_text(), config_text)
    fixed = [c for c in changes if c[0] not in LENGTH_KEYS and not c[0].startswith("log.")]
    if fixed:
        listed = ", ".join(f"{k} {_show(a)} -> {_show(b)}" for k, a, b in changes)
        raise ConfigError(
            f"--resume: the spec differs from {config_path}: {listed}; only "
            f"{' or '.join(LENGTH_KEYS)} (to extend the run) and [log] may change on resume"
        )


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


def parse_seeds(text: str) -> list[int]:
    """The seeds of `--seeds`: a range "0-4" (both ends included), a list "0,3,7", or both
    ("0-2,7"); ConfigError saying what was expected otherwise."""
    seeds: list[int] = []
    expected = 'expected seeds as "0-4" (a range) or "0,3,7" (a list)'
    for part in text.split(","):
        bounds = part.strip().split("-")
        try:
            if len(bounds) > 2:
                raise ValueError
            lo, hi = int(bounds[0]), int(bounds[-1])
        except ValueError:
            raise ConfigError(f"--seeds: {expected}, got {text!r}") from None
        if lo > hi or lo < 0 or hi > 2**32 - 1:
            raise ConfigError(f"--seeds: {expected}, increasing and in [0, 2**32), got {text!r}")
        seeds.extend(s for s in range(lo, hi + 1) if s not in seeds)
    return seeds


def seed_dir(out_dir: str | Path, seed: int) -> Path:
    """Where seed `seed` of a sweep into `out_dir` writes: `out_dir/seed_<seed>`."""
    return Path(out_dir) / f"seed_{seed}"


def _with_seed(spec: Mapping[str, Any], seed: int) -> dict[str, Any]:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in spec.items()}
    out.setdefault("experiment", {})["seed"] = seed
    return out


def _finished_as_given(out_dir: Path, spec: Mapping[str, Any]) -> dict[str, Any] | None:
    """The summary of a finished run in `out_dir` whose resolved spec agrees with every key
    `spec` gives, or None (not finished, or another length or setting)."""
    summary, config = out_dir / "summary.json", out_dir / "config.toml"
    if not (summary.is_file() and config.is_file()):
        return None
    given = {f"{s}.{k}": v for s, table in spec.items() if isinstance(table, dict) for k, v in table.items()}
    resolved = _flat(config.read_text())
    if any(k not in resolved or resolved[k] != v for k, v in given.items()):
        return None
    loaded: dict[str, Any] = json.loads(summary.read_text())
    return loaded


def run_seeds(
    spec_path: str | Path,
    seeds: list[int],
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_start: Callable[[Path], None] | None = None,
) -> dict[str, Any]:
    """Run a spec once per seed, one after the other, each into `out_dir/seed_<n>/`.

    Each seed is a complete run (`run`), as `qdrl run SPEC --set experiment.seed=n`
    would make it, so a seed of a sweep is bit-identical to the same seed run alone.
    Seeds run one after the other: for MAP-Elites on the arm (5 seeds, 1,000
    iterations, 2-core CPU) vmapping them in one compiled chunk was 1.11-1.17x
    slower and not bit-identical to single-seed runs
    (`benchmarks/seeds_sequential_vs_vmap.py`). With `resume`, finished seeds are
    skipped, interrupted ones resume from their checkpoints and the others start.

    Returns {"out": the sweep directory, "runs": {seed: summary}}; `on_start` is called
    as each seed's run starts (`run`).
    Raises ConfigError (a bad spec, or a seed directory that already holds a run
    without `resume` or `overwrite`) before anything compiles, and RunInterrupted
    as `run` does.
    """
    if not seeds:
        raise ConfigError("--seeds: expected at least one seed, got none")
    base = load_spec(spec_path, overrides)
    out = Path(out_dir) if out_dir else default_out_dir(spec_path)
    check_spec(_with_seed(base, seeds[0]))
    if not resume and not overwrite:
        for seed in seeds:
            if checkpoint.checkpoints(seed_dir(out, seed) / "checkpoints"):
                raise ConfigError(
                    f"{seed_dir(out, seed)} already holds a run with checkpoints; pass --resume to "
                    "continue the sweep, --overwrite to discard its runs, or --out for a new directory"
                )
    summaries: dict[int, dict[str, Any]] = {}
    for i, seed in enumerate(seeds):
        spec, where = _with_seed(base, seed), seed_dir(out, seed)
        finished = _finished_as_given(where, spec) if resume else None
        if finished is not None:
            print(f"qdrl: seed {seed} ({i + 1} of {len(seeds)}): finished in {where}, skipped", file=sys.stderr)
            summaries[seed] = finished
            continue
        started = bool(checkpoint.checkpoints(where / "checkpoints"))
        summaries[seed] = run(
            spec, where, resume=resume and started, overwrite=overwrite,
            label=f"seed {seed}, {i + 1} of {len(seeds)}", on_start=on_start,
        )
    return {"out": str(out), "runs": summaries}


def load_spec(spec_path: str | Path, overrides: list[str] | None = None) -> dict[str, Any]:
    """The spec at `spec_path` (a path, or a packaged spec's name: `qdrl.specs.resolve`) with
    `--set` overrides; `experiment.name` defaults to the file's stem."""
    spec_path = specs.resolve(spec_path)
    spec = apply_overrides(load_toml(spec_path), overrides or [])
    exp = spec.setdefault("experiment", {})
    if isinstance(exp, dict) and not exp.get("name"):
        exp["name"] = spec_path.stem
    return spec


def check_spec_file(spec_path: str | Path, overrides: list[str] | None = None) -> str:
    """Check the spec at `spec_path` as `run_spec` would, building its run but compiling and
    running nothing; returns the resolved spec (every default filled in) as TOML."""
    return resolved_toml(*build_run(load_spec(spec_path, overrides)))


def _progress_value(run_: Run, row: Mapping[str, float], chunk: int) -> int:
    return chunk + 1 if run_.progress_unit == "log_point" else int(row[run_.progress_unit])


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
    started = time.perf_counter()
    run_, exp, log = build_run(spec)
    # Under jax.distributed every process runs the same spec; process 0 alone writes
    # the run directory (read by all on --resume: it must be on a shared filesystem).
    primary = placement.is_primary()
    config_text = resolved_toml(run_, exp, log)
    ckpt_dir = out_dir / "checkpoints"
    found = checkpoint.checkpoints(ckpt_dir)
    if found and not resume and not overwrite:
        raise ConfigError(
            f"{out_dir} already holds a run with checkpoints; pass --resume to continue it, "
            "--overwrite to discard it, or --out for a new directory"
        )
    if resume:
        if not found:
            raise ConfigError(f"--resume: no checkpoint found in {ckpt_dir}")
        _check_resume_spec(out_dir / "config.toml", config_text)
        _check_resume_checkpoints(found, run_)
    if primary and overwrite and not resume and out_dir.exists():
        shutil.rmtree(out_dir)
    if primary:
        out_dir.mkdir(parents=True, exist_ok=True)
    if primary and not resume:
        (out_dir / "config.toml").write_text(config_text)
    if on_start is not None:
        on_start(out_dir)

    what = f"{exp.algorithm} on {run_.task}" + (f" ({label})" if label else "")
    progress = RunProgress(log.progress and primary, what, run_.progress_unit, run_.progress_total)
    key = compile_cache.spec_key(config_text)
    stop_message = (
        "qdrl: stopping after the chunk in flight and saving a checkpoint "
        "(press Ctrl-C again to abort at once; the checkpoints on disk are kept)"
    )
    # Loggers start before compiling, so a missing package fails at once.
    with _make_loggers(log if primary else _NO_LOGGERS, out_dir, exp, config_text) as dashboards, \
            compile_cache.enabled(log.compile_cache), interrupt.Interrupts(stop_message) as stop, \
            interrupt.Worker() as worker:

        def prepare() -> tuple[Any, dict[str, Any], Path | None, list[tuple[Path, str]], float]:
            state = run_.init(jax.random.PRNGKey(exp.seed))
            meta: dict[str, Any] = {}
            path: Path | None = None
            skipped: list[tuple[Path, str]] = []
            if resume:
                state, meta, path, skipped = checkpoint.restore_newest(ckpt_dir, state)
                if int(meta["chunk"]) + 1 >= run_.num_chunks:  # finished: nothing to compile
                    return state, meta, path, skipped, 0.0
            return state, meta, path, skipped, run_.compile(state)

        progress.compiling(compile_cache.estimate(key, exp.algorithm, run_.task))
        t0 = time.perf_counter()
        try:
            with compile_cache.cache_hits() as cache:
                state, meta, restored, skipped, compile_s = worker.call(prepare, tick=progress.tick)
        except KeyboardInterrupt:
            progress.close()
            raise RunInterrupted(out_dir, *_newest_log_point(ckpt_dir), run_.num_chunks) from None
        except checkpoint.CheckpointError as e:
            progress.close()
            raise ConfigError(f"--resume: {e}") from None
        startup_s = time.perf_counter() - t0
        placement.barrier("compiled")  # processes that compiled faster wait for the others
        progress.compiled(startup_s)
        if primary:
            compile_cache.record(key, exp.algorithm, run_.task, startup_s, cold=cache["hits"] == 0)

        start_chunk, wall_offset, run_s, rows = 0, 0.0, 0.0, []
        metrics_path = out_dir / "metrics.csv"
        if restored is not None:
            for path, why in skipped if primary else ():
                checkpoint.remove(path)
                print(f"qdrl: --resume: {path.name} is unusable ({why}); removed it", file=sys.stderr)
            start_chunk = int(meta["chunk"]) + 1
            if skipped:
                print(
                    f"qdrl: --resume: resuming from {restored.name} (log point {start_chunk} of "
                    f"{run_.num_chunks})", file=sys.stderr,
                )
            wall_offset, run_s = float(meta["wall_s"]), float(meta["run_s"])
            rows = _read_rows(metrics_path)[:start_chunk]
            if primary:
                _write_rows(metrics_path, rows)
                (out_dir / "config.toml").write_text(config_text)
        elif primary and metrics_path.exists():
            metrics_path.unlink()
        if primary:
            (out_dir / "summary.json").unlink(missing_ok=True)  # rewritten when the run ends

        stop.abort_at_once = False
        progress.start(_progress_value(run_, rows[-1], start_chunk - 1) if rows else 0)
        last_saved = restored

        def save(chunk: int, row: Mapping[str, float], wall_s: float) -> Path:
            meta = {"chunk": chunk, "env_steps": int(row["env_steps"]), "wall_s": wall_s, "run_s": run_s}
            host = placement.fetch(state)  # every process takes part: parts may live in others
            if not primary:
                return ckpt_dir / checkpoint.step_name(chunk + 1)
            return checkpoint.save(ckpt_dir, chunk + 1, host, meta, keep=log.keep_checkpoints)

        try:
            for chunk in range(start_chunk, run_.num_chunks):
                t0 = time.perf_counter()
                state, metrics = run_.run_chunk(state)
                worker.wait_ready((state, metrics))
                run_s += time.perf_counter() - t0
                row = run_.log_row(state, metrics, chunk)
                # Wall time since the run's start, compilation included; a resumed run adds
                # the time of its earlier sessions.
                wall_s = wall_offset + time.perf_counter() - started
                row = {"log_point": chunk, **row, "wall_s": wall_s}
                # Throughput excludes compilation; QD runs also count evaluations. Tasks that
                # step no environment (functions, the arm) have no env steps per second.
                if row["env_steps"] > 0:
                    row["env_steps_per_s"] = row["env_steps"] / run_s if run_s > 0 else math.nan
                if "evaluations" in row:
                    row["evaluations_per_s"] = row["evaluations"] / run_s if run_s > 0 else math.nan
                rows.append(row)
                if primary:
                    _append_row(metrics_path, row)
                dashboards.log(row, _progress_value(run_, row, chunk))
                last = chunk == run_.num_chunks - 1
                saved = (chunk + 1) % log.checkpoint_every == 0 or last
                if saved:
                    last_saved = save(chunk, row, wall_s)
                progress.update(
                    _progress_value(run_, row, chunk),
                    {k: _fmt(v) for k, v in row.items() if k in run_.progress_keys},
                )
                if stop.requested and not last:
                    if not saved:
                        last_saved = save(chunk, row, wall_s)
                    raise RunInterrupted(out_dir, last_saved, chunk + 1, run_.num_chunks)
        finally:
            progress.close()

    final = rows[-1] if rows else {}
    summary: dict[str, Any] = {
        "algorithm": exp.algorithm,
        "task": run_.task,
        "name": exp.name,
        "seed": exp.seed,
        "env_steps": int(final.get("env_steps", 0)),
        "wall_s": final.get("wall_s", 0.0),
        "compile_s": compile_s,
        "run_s": run_s,
    }
    if "env_steps_per_s" in final:
        summary["env_steps_per_s"] = final["env_steps_per_s"]
    if "evaluations" in final:
        summary["evaluations"] = int(final["evaluations"])
    summary.update({k: v for k, v in final.items() if k not in summary and k != "log_point"})
    summary.update(_descriptor_space(run_))
    if placement.is_distributed():
        state = placement.fetch(state)  # finish reads every part on process 0
    if not primary:
        return summary
    summary.update(run_.finish(state, rows, out_dir))
    if log.plots and rows:
        from qdrl import plotting

        plotting.plot_curves(
            rows, out_dir / "plots", x_keys=plotting.default_x_keys(rows), title=f"{exp.algorithm} on {run_.task}"
        )
    summary = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in summary.items()}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")
    return summary


def _descriptor_space(run_: Run) -> dict[str, Any]:
    """The bounds and names of the run's descriptor space (a QD run's task, or an RL run's
    passive archive), for reports that draw repertoires without rebuilding the run."""
    task = getattr(run_, "qd_task", None)
    if task is not None:
        low, high, names = task.descriptor_low, task.descriptor_high, task.descriptor_names
    elif hasattr(run_, "archive_cfg") and hasattr(run_, "archive_labels"):
        cfg = run_.archive_cfg
        low, high, names = cfg.low, cfg.high, run_.archive_labels
    else:
        return {}
    return {
        "descriptor_low": [float(v) for v in low],
        "descriptor_high": [float(v) for v in high],
        "descriptor_names": list(names),
    }


_NO_LOGGERS = LogConfig()  # processes other than 0 log nowhere (TensorBoard and W&B are off by default)


def _newest_log_point(ckpt_dir: Path) -> tuple[Path | None, int]:
    """The newest checkpoint that verifies and the log points it holds; (None, 0) without one."""
    for path in checkpoint.checkpoints(ckpt_dir):
        try:
            checkpoint.verify(path)
            return path, int(checkpoint.read_metadata(path)["chunk"]) + 1
        except (checkpoint.CheckpointError, KeyError, TypeError, ValueError):
            continue
    return None, 0


def _check_resume_checkpoints(found: list[Path], run_: Run) -> None:
    """Fails fast (before compiling) when no checkpoint verifies or the new length is too short."""
    reasons = []
    for path in found:
        try:
            checkpoint.verify(path)
            done = int(checkpoint.read_metadata(path)["chunk"]) + 1
        except (checkpoint.CheckpointError, KeyError, TypeError, ValueError) as e:
            reasons.append(f"{path.name}: {e}")
            continue
        if done > run_.num_chunks:
            raise ConfigError(
                f"--resume: expected a length of at least the {done} log points already run "
                f"({path.name}), got {run_.num_chunks}; only a longer or equal "
                f"{' or '.join(LENGTH_KEYS)} may be given"
            )
        return
    raise ConfigError(f"--resume: no usable checkpoint in {found[0].parent} ({'; '.join(reasons)})")


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


def _json_default(x: Any) -> Any:
    if isinstance(x, np.generic | np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x)}")
