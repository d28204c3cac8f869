"""The `cma_es` recipe: one CMA-ES maximising a task's fitness, no archive (`qdrl.qd.cma_es`).

Single-objective optimisation with the one CMA-ES of qdrl, e.g. on `sphere` and
`rastrigin`. Sections: `[task]`, `[cma_es]`. Logged: the best fitness found so
far, the best and mean of the last generation, sigma and the restarts; the end
writes the best genotype found to best.npz.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import jax
import numpy as np

from qdrl.algorithms.base import (
    Algorithm,
    BuildContext,
    ExperimentConfig,
    Progress,
    Recipe,
    Row,
    Sections,
    last_values,
)
from qdrl.algorithms.task_spec import make_task_of, parse_task
from qdrl.config import Nested, PositiveInt, build
from qdrl.lapack_threads import single_threaded_lapack
from qdrl.qd.cma_es import CMAESRunState, CMAESSearchConfig, cma_es_search

__all__ = ["CMA_ES", "CMAESConfig"]


@dataclasses.dataclass(frozen=True)
class CMAESConfig:
    """The `[cma_es]` section: the length of the run and the search."""

    num_generations: PositiveInt = 1000  # CMA-ES generations (lambda evaluations each)
    log_every: PositiveInt = 50  # generations between log points (one compiled chunk)
    search: Annotated[CMAESSearchConfig, Nested()] = CMAESSearchConfig()

    def check(self) -> None:
        self.search.check("cma_es")
        if self.num_generations % self.log_every:
            raise ValueError(
                f"cma_es.num_generations: expected a multiple of cma_es.log_every={self.log_every}, "
                f"got {self.num_generations}"
            )


def _parse(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    del exp
    cfg: CMAESConfig = build(CMAESConfig, spec.get("cma_es", {}), "cma_es")
    task = parse_task(spec.get("task", {"name": "sphere"}), {"eval_batch": cfg.search.population_size or 1})
    return {"task": task, "cma_es": cfg}


def _log_row(state: CMAESRunState, metrics: Any) -> Row:
    return {
        "generation": int(state.generation),
        "evaluations": int(state.evaluations),
        "env_steps": int(state.env_steps),
        "best_fitness": float(state.best_fitness),
        **last_values(jax.device_get(metrics), ("generation_best_fitness", "generation_mean_fitness")),
        "sigma": float(state.es.sigma),
        "restarts": int(state.restarts),
    }


def _build(sections: Sections, ctx: BuildContext) -> Algorithm:
    cfg: CMAESConfig = sections["cma_es"]
    task = make_task_of(sections["task"])
    search = cma_es_search(task, cfg.search)

    def finish(state: CMAESRunState, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        """Writes the best genotype found to best.npz."""
        del rows
        best = np.asarray(jax.device_get(state.best_genotype))
        np.savez(out_dir / "best.npz", genotype=best, fitness=float(state.best_fitness))
        return {"population_size": search.es.lam}

    return Algorithm(
        task=task.name,
        sections=sections,
        num_chunks=cfg.num_generations // cfg.log_every,
        progress=Progress(("best_fitness", "sigma", "evaluations_per_s"), "generation", cfg.num_generations),
        init=search.init,
        chunk=lambda state: jax.lax.scan(lambda s, _: search.step(s), state, None, length=cfg.log_every),
        log_row=_log_row,
        finish=finish,
        placement=ctx.placement,
        # The eigendecompositions run on one OpenBLAS thread (qdrl.lapack_threads).
        run_context=single_threaded_lapack,
    )


CMA_ES = Recipe(
    parse=_parse, build=_build, length_key="cma_es.num_generations",
    description="CMA-ES (Hansen 2016) with restarts, maximising a task's fitness",
)
