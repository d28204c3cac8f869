"""Run an experiment spec: the driver every algorithm, RL or QD, shares.

The algorithm is a `Run`: it builds its state, compiles its chunk function once
ahead of time, and turns a chunk's result into one row of metrics. The driver
owns everything around it: the output directory, the progress bar,
`metrics.csv`, periodic atomic checkpoints, `--resume`, `summary.json` and plots.
Python runs only between chunks.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, NamedTuple, Protocol

import jax
import numpy as np

from qdrl import checkpoint
from qdrl.config import (
    ConfigError,
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

    def check(self) -> None:
        check_fields(self, "experiment")


@dataclasses.dataclass(frozen=True)
class LogConfig:
    """The `[log]` section: how the driver records a run."""

    checkpoint_every: PositiveInt = 1  # log points between checkpoints
    keep_checkpoints: PositiveInt = 2  # newest checkpoints kept on disk
    progress: bool = True  # show a progress bar
    plots: bool = True  # write plots/*.png at the end

    def check(self) -> None:
        check_fields(self, "log")


class Run(Protocol):
    """What an algorithm provides to the driver."""

    algorithm: str
    task: str
    num_chunks: int  # log points in the whole run
    sections: dict[str, Any]  # resolved config dataclasses, by section name
    progress_keys: tuple[str, ...]  # row keys shown on the progress bar

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
        """One row of metrics after chunk `chunk`; must include `env_steps`."""
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


def register(name: str, parse: SpecParser, build: RunBuilder) -> None:
    """Register an algorithm: its spec parser and its run builder."""
    RUNS[name] = Algorithm(parse, build)


def _load_builtin_runs() -> None:
    from qdrl.runners import pbt, qd, rl, skills  # noqa: F401  (registers their algorithms)


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

    sections = {"experiment": as_table(exp), **{k: as_table(v) for k, v in run.sections.items()}}
    sections["log"] = as_table(log)
    return dump_toml(sections)


def _read_rows(path: Path) -> list[dict[str, float]]:
    if not path.exists():
        return []
    with path.open() as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


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
    return f"{x:.4g}" if math.isfinite(x) else "nan"


def run_spec(
    spec_path: str | Path,
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Run the spec at `spec_path` (with `--set` overrides) and return its summary."""
    spec = load_spec(spec_path, overrides)
    out = Path(out_dir) if out_dir else Path("runs") / Path(spec_path).stem
    return run(spec, out, resume, overwrite)


def load_spec(spec_path: str | Path, overrides: list[str] | None = None) -> dict[str, Any]:
    """The spec at `spec_path` with `--set` overrides; `experiment.name` defaults to the file's stem."""
    spec_path = Path(spec_path)
    spec = apply_overrides(load_toml(spec_path), overrides or [])
    exp = spec.setdefault("experiment", {})
    if isinstance(exp, dict) and not exp.get("name"):
        exp["name"] = spec_path.stem
    return spec


def check_spec_file(spec_path: str | Path, overrides: list[str] | None = None) -> str:
    """Check the spec at `spec_path` as `run_spec` would, building its run but compiling and
    running nothing; returns the resolved spec (every default filled in) as TOML."""
    return resolved_toml(*build_run(load_spec(spec_path, overrides)))


def run(
    spec: Mapping[str, Any], out_dir: Path, resume: bool = False, overwrite: bool = False
) -> dict[str, Any]:
    """Run a parsed spec into `out_dir`; see the module docstring for what it writes."""
    started = time.perf_counter()
    run_, exp, log = build_run(spec)
    config_text = resolved_toml(run_, exp, log)
    ckpt_dir = out_dir / "checkpoints"
    latest = checkpoint.latest(ckpt_dir)
    if latest is not None and not resume and not overwrite:
        raise ConfigError(
            f"{out_dir} already holds a run with checkpoints; pass --resume to continue it, "
            "--overwrite to discard it, or --out for a new directory"
        )
    if resume and latest is None:
        raise ConfigError(f"--resume: no checkpoint found in {ckpt_dir}")
    if resume:
        old = (out_dir / "config.toml").read_text() if (out_dir / "config.toml").exists() else ""
        if old != config_text:
            raise ConfigError(
                f"--resume: the spec differs from the one in {out_dir / 'config.toml'}; "
                "resume with the same spec and --set values"
            )
    if overwrite and not resume and out_dir.exists():
        import shutil

        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.toml").write_text(config_text)

    state = run_.init(jax.random.PRNGKey(exp.seed))
    start_chunk, wall_offset, run_s, rows = 0, 0.0, 0.0, []
    metrics_path = out_dir / "metrics.csv"
    if resume and latest is not None:
        state, meta = checkpoint.restore(latest, state)
        start_chunk = int(meta["chunk"]) + 1
        wall_offset, run_s = float(meta["wall_s"]), float(meta["run_s"])
        rows = _read_rows(metrics_path)[:start_chunk]
        _write_rows(metrics_path, rows)
    elif metrics_path.exists():
        metrics_path.unlink()

    compile_s = run_.compile(state)
    progress = None
    if log.progress:
        from tqdm import tqdm

        progress = tqdm(total=run_.num_chunks, initial=start_chunk, unit="log", dynamic_ncols=True)
        progress.set_description(f"{exp.algorithm} {run_.task}")
    for chunk in range(start_chunk, run_.num_chunks):
        t0 = time.perf_counter()
        state, metrics = run_.run_chunk(state)
        jax.block_until_ready(state)
        run_s += time.perf_counter() - t0
        row = run_.log_row(state, metrics, chunk)
        # Wall time since the run's start, compilation included; a resumed run adds
        # the time of its earlier sessions.
        wall_s = wall_offset + time.perf_counter() - started
        row = {"log_point": float(chunk), **row, "wall_s": wall_s}
        # Throughput excludes compilation; QD runs also count evaluations.
        row["env_steps_per_s"] = row["env_steps"] / run_s if run_s > 0 else math.nan
        if "evaluations" in row:
            row["evaluations_per_s"] = row["evaluations"] / run_s if run_s > 0 else math.nan
        rows.append(row)
        _append_row(metrics_path, row)
        last = chunk == run_.num_chunks - 1
        if (chunk + 1) % log.checkpoint_every == 0 or last:
            checkpoint.save(
                ckpt_dir,
                int(row["env_steps"]),
                jax.device_get(state),
                {"chunk": chunk, "wall_s": wall_s, "run_s": run_s},
                keep=log.keep_checkpoints,
            )
        if progress is not None:
            progress.update(1)
            shown = {k: _fmt(v) for k, v in row.items() if k in run_.progress_keys}
            progress.set_postfix(steps_per_s=f"{row['env_steps_per_s']:.0f}", **shown)
    if progress is not None:
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
        "env_steps_per_s": final.get("env_steps_per_s", math.nan),
    }
    if "evaluations" in final:
        summary["evaluations"] = int(final["evaluations"])
    summary.update({k: v for k, v in final.items() if k not in summary and k != "log_point"})
    summary.update(run_.finish(state, rows, out_dir))
    if log.plots and rows:
        from qdrl import plotting

        plotting.plot_curves(rows, out_dir / "plots", title=f"{exp.algorithm} on {run_.task}")
    summary = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in summary.items()}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")
    return summary


def _json_default(x: Any) -> Any:
    if isinstance(x, np.generic | np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x)}")
