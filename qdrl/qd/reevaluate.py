"""Corrected QD metrics: re-score every elite several times and rebuild the repertoire.

Flageat & Cully 2023, "Uncertain Quality-Diversity: evaluation methodology and new
methods for Quality-Diversity in uncertain domains" (IEEE TEVC), the corrected
repertoire of its evaluation methodology (QDax `reevaluation_function`): in a noisy
or start-state-dependent task an elite's stored fitness and descriptor come from
one lucky evaluation, so the stored QD score, coverage and max fitness overstate
what the repertoire holds. Each elite is re-scored `num_samples` times with
independent keys; its expected fitness and descriptor are the medians of the
samples (per descriptor dimension); the elites are then added, with these
values, to an empty copy of the repertoire through its own `add`: an elite moves
to the cell of its median descriptor, and where several land in one cell the
best median fitness is kept.

Where evaluations do not depend on the key (a deterministic function task), the
corrected repertoire is the stored one and its metrics are equal.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.envs.skills import SkillSpace
from qdrl.qd.base import ScoringFn
from qdrl.qd.metrics import qd_metrics
from qdrl.qd.repertoires.cells import CellRepertoire
from qdrl.skill_metrics import archive_skill_metrics, picked_elite_metrics
from qdrl.types import Array, Genotype, PRNGKey

__all__ = [
    "Reevaluation",
    "corrected_repertoire",
    "default_key",
    "emptied",
    "reevaluate",
    "reevaluation_report",
    "report",
    "sample_scores",
    "write_reevaluation",
]

# Mixed into the run's seed so that re-evaluations draw keys no run draws.
_KEY_SALT = 0x5EED_C0DE


class Reevaluation(NamedTuple):
    """A repertoire's elites re-scored: samples, medians and the corrected repertoire."""

    cells: np.ndarray  # (n,) the stored cell of each elite, increasing
    fitness_samples: np.ndarray  # (num_samples, n)
    descriptor_samples: np.ndarray  # (num_samples, n, D)
    median_fitness: np.ndarray  # (n,)
    median_descriptor: np.ndarray  # (n, D)
    corrected_cells: np.ndarray  # (n,) the cell of each median descriptor (-1: NaN median)
    corrected: CellRepertoire  # the elites at their median descriptors, best median per cell
    stored_metrics: dict[str, float]  # qd_metrics of the stored repertoire
    corrected_metrics: dict[str, float]  # qd_metrics of the corrected one


def default_key(seed: int) -> PRNGKey:
    """The key of a run's re-evaluations: derived from its seed, apart from its own keys."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), _KEY_SALT)


def sample_scores(
    scoring_fn: ScoringFn, genotypes: Genotype, key: PRNGKey, num_samples: int
) -> tuple[Array, Array]:
    """Fitnesses (num_samples, n) and descriptors (num_samples, n, D) of n genotypes, each
    scored `num_samples` times, sample j with its own key; jittable.

    Samples are scored one after the other (`lax.map`), each as one batch of the n
    genotypes, so memory is that of one evaluation of the batch.
    """
    if num_samples < 1:
        raise ValueError(f"num_samples: expected a positive integer, got {num_samples}")

    def one(k: PRNGKey) -> tuple[Array, Array]:
        evaluation = scoring_fn(genotypes, k)
        return evaluation.fitnesses, evaluation.descriptors

    fitnesses, descriptors = jax.lax.map(one, jax.random.split(key, num_samples))
    return fitnesses, descriptors


def emptied(repertoire: CellRepertoire) -> CellRepertoire:
    """The same cells (centroids, bounds, lookup) with no elite."""
    return dataclasses.replace(
        repertoire,
        genotypes=jax.tree.map(jnp.zeros_like, repertoire.genotypes),
        fitnesses=jnp.full_like(repertoire.fitnesses, -jnp.inf),
        descriptors=jnp.zeros_like(repertoire.descriptors),
    )


def corrected_repertoire(
    repertoire: CellRepertoire,
    genotypes: Genotype,
    fitness_samples: Array,
    descriptor_samples: Array,
) -> tuple[CellRepertoire, Array, Array, Array]:
    """The corrected repertoire of n elites from their samples; jittable.

    Args:
      repertoire: gives the cells (its elites are not kept).
      genotypes: the n elites, leaves (n, ...).
      fitness_samples: (num_samples, n).
      descriptor_samples: (num_samples, n, D).

    Returns:
      (corrected repertoire, median fitness (n,), median descriptor (n, D), cell of
      each median descriptor (n,), -1 where a median is NaN).
    """
    fitness = jnp.median(fitness_samples, axis=0)
    descriptor = jnp.median(descriptor_samples, axis=0)
    corrected, result = emptied(repertoire).add(genotypes, descriptor, fitness)
    return corrected, fitness, descriptor, result.cell


def reevaluate(
    repertoire: CellRepertoire,
    scoring_fn: ScoringFn,
    key: PRNGKey,
    num_samples: int,
    qd_offset: float,
) -> Reevaluation:
    """Re-scores every elite of `repertoire` `num_samples` times and corrects the repertoire.

    `scoring_fn` should draw what varies from its key: for policy tasks, the
    random-start scoring (`task.policy_scoring(None, fixed_start=False)`); a plain
    noisy task's own scoring function. One compilation per number of elites.
    """
    if repertoire.genotypes is None:
        raise ValueError("reevaluate: the repertoire stores no genotypes (a passive archive)")
    filled = np.asarray(repertoire.fitnesses) > -np.inf
    cells = np.flatnonzero(filled)
    genotypes = jax.tree.map(lambda x: jnp.asarray(x)[cells], repertoire.genotypes)

    @jax.jit
    def correct(rep: CellRepertoire, genotypes: Genotype, key: PRNGKey) -> Any:
        if len(cells):
            fitnesses, descriptors = sample_scores(scoring_fn, genotypes, key, num_samples)
            out = corrected_repertoire(rep, genotypes, fitnesses, descriptors)
        else:  # nothing to re-score
            dim = rep.descriptors.shape[-1]
            fitnesses, descriptors = jnp.zeros((num_samples, 0)), jnp.zeros((num_samples, 0, dim))
            out = (emptied(rep), jnp.zeros(0), jnp.zeros((0, dim)), jnp.zeros(0, jnp.int32))
        return fitnesses, descriptors, *out, qd_metrics(rep, qd_offset), qd_metrics(out[0], qd_offset)

    fit_s, desc_s, corrected, fit, desc, new_cells, stored_m, corrected_m = jax.device_get(
        correct(repertoire, genotypes, key)
    )
    return Reevaluation(
        cells=cells,
        fitness_samples=np.asarray(fit_s),
        descriptor_samples=np.asarray(desc_s),
        median_fitness=np.asarray(fit),
        median_descriptor=np.asarray(desc),
        corrected_cells=np.asarray(new_cells, np.int64),
        corrected=corrected,
        stored_metrics={k: float(v) for k, v in stored_m.items()},
        corrected_metrics={k: float(v) for k, v in corrected_m.items()},
    )


def report(result: Reevaluation, num_samples: int, seed: int) -> dict[str, Any]:
    """The JSON-ready summary of a re-evaluation: stored and corrected QD metrics side by side."""
    keys = ("qd_score", "coverage", "max_fitness", "num_elites")

    def pick(m: dict[str, float]) -> dict[str, Any]:
        out: dict[str, Any] = {k: (int(m[k]) if k == "num_elites" else m[k]) for k in keys}
        if not np.isfinite(out["max_fitness"]):
            out["max_fitness"] = None
        return out

    moved = int(np.sum(result.corrected_cells != result.cells))
    return {
        "samples": num_samples,
        "seed": seed,
        "elites_reevaluated": len(result.cells),
        "elites_moved": moved,
        "stored": pick(result.stored_metrics),
        "corrected": pick(result.corrected_metrics),
    }


def reevaluation_report(
    repertoire: CellRepertoire,
    scoring_fn: ScoringFn,
    qd_offset: float,
    samples: int,
    seed: int,
    labels: dict[str, Any],
    random_starts: bool,
    space: SkillSpace | None = None,
) -> dict[str, Any]:
    """`report` of `reevaluate` with the run's `labels` (algorithm, task) and wall time, as
    `qdrl reevaluate` and `qd.reevaluate_samples` write it (non-finite floats as None). On a
    feature task (`space`), also `skills`: the repertoire read as a library of skills, stored
    and corrected (`archive_skill_metrics`), and the elite nearest each target played again
    (`picked_elite_metrics`)."""
    t0 = time.perf_counter()
    result = reevaluate(repertoire, scoring_fn, default_key(seed), samples, qd_offset)
    out = {**labels, **report(result, samples, seed)}
    if space is not None:
        stored_desc = np.asarray(repertoire.descriptors)[result.cells]
        stored_fit = np.asarray(repertoire.fitnesses)[result.cells]
        out["skills"] = {
            "stored": {k: float(v) for k, v in archive_skill_metrics(
                repertoire.descriptors, repertoire.fitnesses, space).items()},
            "corrected": {k: float(v) for k, v in archive_skill_metrics(
                result.corrected.descriptors, result.corrected.fitnesses, space).items()},
            **picked_elite_metrics(stored_desc, stored_fit, result.descriptor_samples, result.fitness_samples, space),
        }
    out["qd_offset"] = qd_offset
    out["start_states"] = "random" if random_starts else "the task's own scoring"
    out["wall_s"] = time.perf_counter() - t0
    return _finite_or_none(out)


def _finite_or_none(value: Any) -> Any:
    """`value` with every non-finite float, in nested dicts too, as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    return None if isinstance(value, float) and not math.isfinite(value) else value


def write_reevaluation(report_: dict[str, Any], out_dir: Path) -> None:
    """Writes a `reevaluation_report` to `out_dir/reevaluation.json`."""
    (out_dir / "reevaluation.json").write_text(json.dumps(report_, indent=2) + "\n")
