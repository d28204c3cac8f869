"""QD metrics of a repertoire: QD score, coverage, max and mean fitness, number of elites.

The metrics of the QDax paper (Chalumeau, Lim et al.), computed alike for every
algorithm from its repertoire or its passive archive.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from qdrl.types import Array

__all__ = ["qd_metrics", "range_qd_score"]


def qd_metrics(repertoire: Any, qd_offset: float) -> dict[str, Array]:
    """QD metrics of any repertoire whose `fitnesses` (C,) are -inf in empty cells; jittable.

    Args:
      repertoire: a cell repertoire, an unstructured repertoire or a passive archive
        (only `fitnesses` is read; C is the number of cells, or the capacity).
      qd_offset: subtracted from every stored fitness in the QD score. It is fixed per
        task, chosen as a lower bound of the fitness so that every elite counts
        positively and filling a new cell always raises the score.

    Returns:
      float32 `qd_score` = sum over filled cells of (fitness - qd_offset) (0 when
      empty); `normalised_qd_score` = qd_score / C (the QD score per cell of the
      CMA-ME and CMA-MAE papers' tables); `coverage` = filled / C in [0, 1]; `max_fitness` (-inf when empty);
      `mean_fitness` over the filled cells (NaN when empty: there is no mean; plots
      and logs skip it); int32 `num_elites`.
    """
    fitnesses = jnp.asarray(repertoire.fitnesses, jnp.float32)
    filled = fitnesses > -jnp.inf
    num_elites = jnp.sum(filled, dtype=jnp.int32)
    count = num_elites.astype(jnp.float32)
    # Three reductions over the cells (count, sum, max); the QD score and the mean
    # follow from them, so a step computes no second sum of the same fitnesses.
    total = jnp.sum(jnp.where(filled, fitnesses, 0.0))
    return {
        "qd_score": total - qd_offset * count,
        "coverage": count / fitnesses.shape[0],
        "max_fitness": jnp.max(fitnesses),
        "mean_fitness": jnp.where(num_elites > 0, total / jnp.maximum(count, 1.0), jnp.nan),
        "num_elites": num_elites,
        "normalised_qd_score": (total - qd_offset * num_elites.astype(jnp.float32))
        / fitnesses.shape[0],
    }


def range_qd_score(repertoire: Any, fitness_range: tuple[float, float]) -> Array:
    """The QD score on a fixed scale: each filled cell's fitness clipped to `fitness_range`
    = (min, max) and mapped to [0, 1], summed and divided by the number of cells; jittable.

    1.0 is every cell filled with a fitness of at least `max`. The fitness ranges of
    Chalumeau, Boige et al. 2023 (the skill-discovery benchmark's `fitness_range`, also the
    colour scale of its archive figures) put every method of one task on this scale.
    """
    lo, hi = float(fitness_range[0]), float(fitness_range[1])
    if not lo < hi:
        raise ValueError(f"fitness_range: expected (min, max) with min < max, got {fitness_range}")
    fitnesses = jnp.asarray(repertoire.fitnesses, jnp.float32)
    filled = fitnesses > -jnp.inf
    scaled = jnp.clip((fitnesses - lo) / (hi - lo), 0.0, 1.0)
    return jnp.sum(jnp.where(filled, scaled, 0.0)) / fitnesses.shape[0]
