"""QD runs (MAP-Elites, CVT-MAP-Elites) on the standard tasks, for the experiment driver."""

from __future__ import annotations

import dataclasses
import inspect
import time
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import jax
import numpy as np

from qdrl.config import ConfigError, build, coerce
from qdrl.experiment import ExperimentConfig, register

if TYPE_CHECKING:
    from qdrl.qd.map_elites import MapElites, QDState


@dataclasses.dataclass(frozen=True)
class RepertoireConfig:
    """The `[repertoire]` section: the container of elites."""

    kind: Literal["grid", "cvt"] = "grid"  # regular grid (direct indexing) or CVT
    grid_shape: tuple[int, ...] = (32, 32)  # grid: cells per descriptor dimension
    num_centroids: int = 1024  # cvt: number of cells
    cvt_samples: int = 50_000  # cvt: uniform samples clustered by k-means into centroids
    kmeans_iters: int = 50  # cvt: Lloyd iterations

    def check(self) -> None:
        if any(n <= 0 for n in self.grid_shape) or not self.grid_shape:
            raise ValueError(
                f"repertoire.grid_shape: expected a list of positive integers, got {list(self.grid_shape)}"
            )
        for name in ("num_centroids", "cvt_samples", "kmeans_iters"):
            if getattr(self, name) <= 0:
                raise ValueError(f"repertoire.{name}: expected a positive integer, got {getattr(self, name)}")
        if self.kind == "cvt" and self.cvt_samples < self.num_centroids:
            raise ValueError(
                f"repertoire.cvt_samples: expected at least repertoire.num_centroids="
                f"{self.num_centroids}, got {self.cvt_samples}"
            )


@dataclasses.dataclass(frozen=True)
class EmitterConfig:
    """The `[emitter]` section: how offspring are made."""

    kind: Literal["isoline", "polynomial"] = "isoline"
    batch_size: int = 1024  # offspring per iteration
    iso_sigma: float = 0.05  # isoline: isotropic Gaussian noise (Vassiliades & Mouret 2018)
    line_sigma: float = 0.1  # isoline: noise along the line between two parents
    variation_percentage: float = 1.0  # share of the batch made by crossover/variation
    eta: float = 0.05  # polynomial mutation: distribution index
    proportion_to_mutate: float = 0.5  # polynomial mutation: share of genes mutated
    crossover_proportion: float = 0.5  # polynomial crossover: share of genes exchanged

    def check(self) -> None:
        if self.batch_size <= 0:
            raise ValueError(f"emitter.batch_size: expected a positive integer, got {self.batch_size}")
        for name in ("iso_sigma", "line_sigma", "eta"):
            if getattr(self, name) < 0:
                raise ValueError(f"emitter.{name}: expected a non-negative number, got {getattr(self, name)}")
        for name in ("variation_percentage", "proportion_to_mutate", "crossover_proportion"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"emitter.{name}: expected a number in [0, 1], got {getattr(self, name)}")


@dataclasses.dataclass(frozen=True)
class QDConfig:
    """The `[qd]` section: length of the run and logging."""

    num_iterations: int = 1000  # emitter batches evaluated after the initial population
    log_every: int = 50  # iterations between log points (one compiled chunk)
    init_batch_size: int = 1024  # random genotypes evaluated to seed the repertoire

    def check(self) -> None:
        for name in ("num_iterations", "log_every", "init_batch_size"):
            if getattr(self, name) <= 0:
                raise ValueError(f"qd.{name}: expected a positive integer, got {getattr(self, name)}")
        if self.num_iterations % self.log_every:
            raise ValueError(
                f"qd.num_iterations: expected a multiple of qd.log_every={self.log_every}, "
                f"got {self.num_iterations}"
            )


def build_task(data: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The task named by `data["name"]`, its other keys checked against the builder's signature."""
    from qdrl.tasks import TASKS

    if "name" not in data:
        raise ConfigError(f"task.name: missing; expected one of {sorted(TASKS)}")
    name = data["name"]
    if name not in TASKS:
        raise ConfigError(f"task.name: unknown task {name!r}; expected one of {sorted(TASKS)}")
    builder: Callable[..., Any] = TASKS[name]
    sig = inspect.signature(builder)
    hints = typing.get_type_hints(builder)
    params = {k: p for k, p in sig.parameters.items() if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key == "name":
            continue
        if key not in params:
            raise ConfigError(f"task.{key}: unknown key for task {name!r}; expected one of {sorted(params)}")
        kwargs[key] = coerce(value, hints.get(key, type(value)), f"task.{key}")
    try:
        task = builder(**kwargs)
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith("task.") else f"task: {msg}") from e
    resolved = {"name": name}
    for key, p in params.items():
        value = kwargs.get(key, p.default)
        if value is not inspect.Parameter.empty:
            resolved[key] = list(value) if isinstance(value, tuple) else value
    return task, resolved


class QDRun:
    """MAP-Elites (grid or CVT repertoire) with a GA emitter on a standard task."""

    progress_keys: tuple[str, ...] = ("qd_score", "coverage", "max_fitness", "evaluations_per_s")

    def __init__(self, spec: Mapping[str, Any], exp: ExperimentConfig, default_kind: str) -> None:
        rep_data = dict(spec.get("repertoire", {}))
        rep_data.setdefault("kind", default_kind)
        self._task, task_table = build_task(spec.get("task", {"name": "arm"}))
        rep_cfg = build(RepertoireConfig, rep_data, "repertoire")
        emitter_cfg = build(EmitterConfig, spec.get("emitter", {}), "emitter")
        qd_cfg = build(QDConfig, spec.get("qd", {}), "qd")
        dim = len(self._task.descriptor_low)
        if rep_cfg.kind == "grid" and len(rep_cfg.grid_shape) != dim:
            raise ConfigError(
                f"repertoire.grid_shape: expected {dim} entries (the descriptor size of task "
                f"{self._task.name!r}), got {list(rep_cfg.grid_shape)}"
            )
        self.algorithm = exp.algorithm
        self.task = str(task_table["name"])
        self.sections = {"task": task_table, "repertoire": rep_cfg, "emitter": emitter_cfg, "qd": qd_cfg}
        self.rep_cfg, self.emitter_cfg, self.qd_cfg = rep_cfg, emitter_cfg, qd_cfg
        self.num_chunks = qd_cfg.num_iterations // qd_cfg.log_every
        self.seed = exp.seed
        self._chunk: Any = None
        self.map_elites: MapElites | None = None

    def _build(self, key: jax.Array) -> MapElites:
        from qdrl.qd.emitters.ga import isoline_emitter, polynomial_emitter
        from qdrl.qd.map_elites import MapElites
        from qdrl.qd.repertoires import cvt_repertoire, grid_repertoire
        from qdrl.qd.repertoires.cvt import cvt_centroids

        task, rc, ec = self._task, self.rep_cfg, self.emitter_cfg
        # Unbounded genotypes (policy parameters) are not clipped.
        lo = task.genotype_low if np.isfinite(task.genotype_low) else None
        hi = task.genotype_high if np.isfinite(task.genotype_high) else None
        example = task.example_genotype()
        if rc.kind == "grid":
            repertoire = grid_repertoire(example, rc.grid_shape, task.descriptor_low, task.descriptor_high)
        else:
            centroids = cvt_centroids(
                key, rc.num_centroids, rc.cvt_samples, task.descriptor_low, task.descriptor_high,
                num_iters=rc.kmeans_iters,
            )
            repertoire = cvt_repertoire(example, centroids, task.descriptor_low, task.descriptor_high)
        if ec.kind == "isoline":
            emitter = isoline_emitter(
                ec.batch_size, ec.iso_sigma, ec.line_sigma, lo, hi,
                variation_percentage=ec.variation_percentage,
            )
        else:
            emitter = polynomial_emitter(
                ec.batch_size, ec.eta, ec.proportion_to_mutate, task.genotype_low, task.genotype_high,
                variation_percentage=ec.variation_percentage,
                proportion_var_to_change=ec.crossover_proportion,
            )
        return MapElites(task.scoring_fn, emitter, repertoire, qd_offset=task.qd_offset)

    def init(self, key: jax.Array) -> QDState:
        cvt_key, init_key, run_key = jax.random.split(key, 3)
        self.map_elites = self._build(cvt_key)
        me = self.map_elites

        def start(k1: jax.Array, k2: jax.Array) -> QDState:
            genotypes = self._task.init_genotypes(k1, self.qd_cfg.init_batch_size)
            return me.init(genotypes, k2)

        return jax.jit(start)(init_key, run_key)

    def compile(self, state: QDState) -> float:
        assert self.map_elites is not None
        me, n = self.map_elites, self.qd_cfg.log_every
        t0 = time.perf_counter()
        self._chunk = jax.jit(lambda s: me.run(s, n), donate_argnums=0).lower(state).compile()
        return time.perf_counter() - t0

    def run_chunk(self, state: QDState) -> tuple[QDState, Any]:
        return self._chunk(state)

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        m = jax.device_get(chunk_metrics)
        row = {
            "iteration": float(state.iteration),
            "evaluations": float(state.evaluations),
            "env_steps": float(state.env_steps),
        }
        for key in ("qd_score", "coverage", "max_fitness", "mean_fitness", "num_elites"):
            row[key] = float(np.asarray(m[key])[-1])
        row["added_per_iter"] = float(np.mean(m["added"]))
        return row

    def finish(self, state: QDState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        from qdrl import plotting
        from qdrl.qd.repertoires import export_npz, write_csv

        rep = jax.device_get(state.repertoire)
        export_npz(rep, out_dir / "repertoire.npz")
        write_csv(rep, out_dir / "repertoire.csv")
        plotting.plot_repertoire(
            rep, out_dir / "plots" / "repertoire.png", self._task.descriptor_low,
            self._task.descriptor_high, title=f"{self.algorithm} on {self.task}",
        )
        return {"qd_offset": self._task.qd_offset}


@register("map_elites")
def _map_elites(spec: Mapping[str, Any], exp: ExperimentConfig) -> QDRun:
    return QDRun(spec, exp, default_kind="grid")


@register("cvt_map_elites")
def _cvt_map_elites(spec: Mapping[str, Any], exp: ExperimentConfig) -> QDRun:
    return QDRun(spec, exp, default_kind="cvt")
