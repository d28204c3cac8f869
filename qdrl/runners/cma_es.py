"""The `cma_es` baseline: one CMA-ES maximising a task's fitness, no archive.

Single-objective optimisation with the one CMA-ES of qdrl (`qdrl.qd.cma_es`),
e.g. on `sphere` and `rastrigin`: each generation samples lambda genotypes,
clips them to the task's genotype bounds (when finite, as CMA-ME's emitter
does), scores them with the task's scoring function (descriptors are ignored), ranks
them by fitness and updates the search. When a stop condition fires (and
`cma_es.restarts` is on) the search starts again from a new random genotype
with sigma0. Logged: the best fitness found so far, the best and mean of the
last generation, sigma and the restarts.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from qdrl.compiling import compile_timed
from qdrl.config import NonNegativeInt, PositiveFloat, PositiveInt, build
from qdrl.experiment import ExperimentConfig, Sections, register
from qdrl.lapack_threads import single_threaded_lapack
from qdrl.qd.cma_es import CMAES, CMAESState, EigenGapRule
from qdrl.runners.qd import make_task_of, parse_task
from qdrl.types import Array


@dataclasses.dataclass(frozen=True)
class CMAESConfig:
    """The `[cma_es]` section: the search and the length of the run."""

    num_generations: PositiveInt = 1000  # CMA-ES generations (lambda evaluations each)
    log_every: PositiveInt = 50  # generations between log points (one compiled chunk)
    population_size: NonNegativeInt = 0  # lambda; 0: 4 + floor(3 ln n)
    sigma0: PositiveFloat = 0.3  # initial step size (in genotype units) of every (re)start
    separable: bool = False  # sep-CMA-ES: diagonal covariance, for thousands of parameters
    # Generations between eigendecompositions, or 0.5 lambda / (n (c_1 + c_mu)) counted in
    # "generations" (as QDax counts it) or in "evaluations" (as pyribs' code does).
    eigen_gap: PositiveInt | EigenGapRule = "generations"
    update_rule: Literal["pyribs", "tutorial"] = "pyribs"
    restarts: bool = True  # start again from a random genotype when a stop condition fires

    def check(self) -> None:
        if self.population_size == 1:
            raise ValueError("cma_es.population_size: expected 0 (the default) or an integer >= 2, got 1")
        if self.num_generations % self.log_every:
            raise ValueError(
                f"cma_es.num_generations: expected a multiple of cma_es.log_every={self.log_every}, "
                f"got {self.num_generations}"
            )


class CMAESRunState(NamedTuple):
    """The search, its key and what the log reports; checkpointing saves exactly this."""

    es: CMAESState
    key: Array
    generation: Array  # int32 generations done
    evaluations: Array  # int32
    env_steps: Array  # int32
    best_fitness: Array  # () best fitness ever evaluated
    best_genotype: Array  # (n,) flat genotype of best_fitness
    restarts: Array  # int32


def parse_cma_es(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    """The checked `[task]` and `[cma_es]` sections of a `cma_es` spec."""
    del exp
    cfg = build(CMAESConfig, spec.get("cma_es", {}), "cma_es")
    task = parse_task(spec.get("task", {"name": "sphere"}), {"eval_batch": cfg.population_size or 1})
    return {"task": task, "cma_es": cfg}


class CMAESRun:
    """CMA-ES on one task (the driver's `Run`)."""

    progress_keys: tuple[str, ...] = ("best_fitness", "sigma", "evaluations_per_s")

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        self.sections = dict(sections)
        self.cfg: CMAESConfig = sections["cma_es"]
        self._task = make_task_of(sections["task"])
        self.algorithm, self.task, self.seed = exp.algorithm, str(sections["task"]["name"]), exp.seed
        flat, self._unravel = ravel_pytree(self._task.example_genotype())
        c = self.cfg
        self.es = CMAES(
            int(flat.shape[0]), c.population_size or None, c.sigma0, c.separable, c.eigen_gap, c.update_rule
        )
        self._clip = bool(np.isfinite(self._task.genotype_low) or np.isfinite(self._task.genotype_high))
        self.num_chunks = c.num_generations // c.log_every
        self.progress_unit, self.progress_total = "generation", c.num_generations
        self._chunk: Any = None

    def _start(self, key: Array) -> Array:
        """A random flat genotype of the task (its initial distribution)."""
        return ravel_pytree(jax.tree.map(lambda x: x[0], self._task.init_genotypes(key, 1)))[0]

    def init(self, key: jax.Array) -> CMAESRunState:
        start_key, key = jax.random.split(key)
        n = self.es.num_dims
        return CMAESRunState(
            es=self.es.init(self._start(start_key)),
            key=key,
            generation=jnp.zeros((), jnp.int32),
            evaluations=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
            best_fitness=jnp.asarray(-jnp.inf, jnp.float32),
            best_genotype=jnp.zeros((n,), jnp.float32),
            restarts=jnp.zeros((), jnp.int32),
        )

    def step(self, state: CMAESRunState) -> tuple[CMAESRunState, dict[str, Array]]:
        """One generation: sample, score, rank by fitness (NaN last), update, maybe restart."""
        key, sample_key, eval_key, restart_key = jax.random.split(state.key, 4)
        x = self.es.sample(state.es, sample_key)
        if self._clip:  # as CMA-ME's emitter: samples clipped to the task's finite bounds
            x = jnp.clip(x, self._task.genotype_low, self._task.genotype_high)
        evaluation = self._task.scoring_fn(jax.vmap(self._unravel)(x), eval_key)
        fitness = jnp.where(jnp.isnan(evaluation.fitnesses), -jnp.inf, evaluation.fitnesses)
        order = jnp.argsort(-fitness, stable=True)
        es = self.es.update(state.es, x[order], self.es.lam // 2)
        restart = self.es.stop(es, fitness[order]) & self.cfg.restarts
        es = jax.lax.cond(restart, lambda: self.es.init(self._start(restart_key)), lambda: es)
        best = fitness[order[0]]
        improved = best > state.best_fitness
        new = CMAESRunState(
            es=es,
            key=key,
            generation=state.generation + 1,
            evaluations=state.evaluations + self.es.lam,
            env_steps=state.env_steps + jnp.asarray(evaluation.env_steps, jnp.int32),
            best_fitness=jnp.where(improved, best, state.best_fitness),
            best_genotype=jnp.where(improved, x[order[0]], state.best_genotype),
            restarts=state.restarts + restart.astype(jnp.int32),
        )
        finite = jnp.isfinite(fitness)
        mean = jnp.sum(jnp.where(finite, fitness, 0.0)) / jnp.maximum(jnp.sum(finite), 1)
        return new, {"generation_best_fitness": best, "generation_mean_fitness": mean}

    def compile(self, state: CMAESRunState) -> float:
        n = self.cfg.log_every
        with single_threaded_lapack():
            compiled = compile_timed(lambda s: jax.lax.scan(lambda c, _: self.step(c), s, None, length=n), state)
        self._chunk = compiled.fn
        return compiled.seconds

    def run_chunk(self, state: CMAESRunState) -> tuple[CMAESRunState, Any]:
        with single_threaded_lapack():  # the eigendecompositions on one OpenBLAS thread
            return jax.block_until_ready(self._chunk(state))

    def log_row(self, state: CMAESRunState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        m = jax.device_get(chunk_metrics)
        return {
            "generation": int(state.generation),
            "evaluations": int(state.evaluations),
            "env_steps": int(state.env_steps),
            "best_fitness": float(state.best_fitness),
            "generation_best_fitness": float(np.asarray(m["generation_best_fitness"])[-1]),
            "generation_mean_fitness": float(np.asarray(m["generation_mean_fitness"])[-1]),
            "sigma": float(state.es.sigma),
            "restarts": int(state.restarts),
        }

    def finish(self, state: CMAESRunState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        """Writes the best genotype found to best.npz."""
        best = np.asarray(jax.device_get(state.best_genotype))
        np.savez(out_dir / "best.npz", genotype=best, fitness=float(state.best_fitness))
        return {"population_size": self.es.lam}


register("cma_es", parse_cma_es, CMAESRun)
