"""QD metrics of a repertoire: QD score, coverage, max and mean fitness, number of elites.

The metrics of the QDax paper (Chalumeau, Lim et al.), computed alike for every
algorithm from its repertoire or its passive archive; and the CQD score, which needs
no cells (`cqd_score`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from qdrl.types import Array, PRNGKey

__all__ = ["cqd_score", "cqd_target_points", "qd_metrics", "range_qd_score"]


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


def cqd_score(
    descriptors: ArrayLike,
    fitnesses: ArrayLike,
    target_points: ArrayLike,
    penalties: int | ArrayLike | Sequence[float],
    obj_min: float,
    obj_max: float,
    dist_max: float,
    dist_ord: float = 2,
) -> Array:
    """The Continuous Quality-Diversity (CQD) score of a set of elites; jittable.

    Kent, Branke et al. 2022, "A discretization-free metric for assessing quality
    diversity algorithms" (GECCO Companion, doi 10.1145/3520304.3534018); computed as
    pyribs' `cqd_score` (0.12) computes it. Each target point t stands for a user who wants
    a solution at t, and each penalty theta for how much that user minds a descriptor
    away from t. For one set of n targets:

        CQD = sum over theta, sum over t, max over elites e of  f_e / (obj_max - obj_min)
                                                               - theta * |d_e - t| / dist_max

    with |.| the `dist_ord` norm. As in pyribs, `obj_min` only sets the scale (the
    objective is divided by obj_max - obj_min, not shifted), the terms are not clipped at
    0 (a far, poor elite counts negatively), and the penalties are summed, not averaged.
    Fitnesses on a scale from 0 (shift them by a task's `qd_offset` first) make every term
    at most 1 per target and penalty.

    Args:
      descriptors: (C, D) descriptors of the elites (a repertoire's, empty cells included).
      fitnesses: (C,) fitnesses; -inf (empty cells) and other non-finite rows are left out.
      target_points: (n, D) targets, or (I, n, D): I draws of n targets, whose scores are
        averaged (pyribs' `iterations`; `cqd_target_points` draws them).
      penalties: the thetas, a 1-D array, or a number k of them spread evenly over
        [0, 1] (`linspace(0, 1, k)`, pyribs' int form; static).
      obj_min, obj_max: the objective's range, `obj_min < obj_max`.
      dist_max: the largest distance in descriptor space (e.g. the box's diagonal,
        |high - low|), > 0.
      dist_ord: the order of the norm (`jnp.linalg.norm`'s vector `ord`: 1, 2, inf, ...;
        static).

    Returns:
      () float32, the mean over the I draws of the score; -inf when no elite is finite.
    """
    points = jnp.asarray(descriptors, jnp.float32)
    values = jnp.asarray(fitnesses, jnp.float32)
    if points.ndim != 2 or values.shape != (points.shape[0],):
        raise ValueError(
            "cqd_score: expected descriptors (C, D) and fitnesses (C,), got "
            f"{points.shape} and {values.shape}"
        )
    targets = jnp.asarray(target_points, jnp.float32)
    if targets.ndim == 2:
        targets = targets[None]
    if targets.ndim != 3 or targets.shape[-1] != points.shape[1]:
        raise ValueError(
            f"cqd_score: expected target_points (n, {points.shape[1]}) or (I, n, {points.shape[1]}), "
            f"got {jnp.shape(target_points)}"
        )
    if isinstance(penalties, int):
        if penalties < 1:
            raise ValueError(f"cqd_score: expected at least one penalty, got {penalties}")
        thetas = jnp.linspace(0.0, 1.0, penalties, dtype=jnp.float32)
    else:
        thetas = jnp.asarray(penalties, jnp.float32)
        if thetas.ndim != 1:
            raise ValueError(f"cqd_score: penalties must be an int or a 1-D array, got shape {thetas.shape}")
    if isinstance(obj_min, int | float) and isinstance(obj_max, int | float) and not obj_min < obj_max:
        raise ValueError(f"cqd_score: expected obj_min < obj_max, got {obj_min} and {obj_max}")
    if isinstance(dist_max, int | float) and not dist_max > 0:
        raise ValueError(f"cqd_score: expected dist_max > 0, got {dist_max}")
    keep = jnp.isfinite(values) & jnp.all(jnp.isfinite(points), axis=-1)
    quality = jnp.where(keep, values / (obj_max - obj_min), -jnp.inf)
    # Left-out rows sit at the origin so that their distances stay finite (no inf - inf).
    points = jnp.where(keep[:, None], points, 0.0)

    def one_draw(draw: Array) -> Array:
        distance = jnp.linalg.norm(points[:, None, :] - draw[None], ord=dist_ord, axis=-1) / dist_max

        def one_penalty(theta: Array) -> Array:
            return jnp.sum(jnp.max(quality[:, None] - theta * distance, axis=0))

        # One (C, n) matrix at a time, rather than (penalties, C, n).
        return jnp.sum(jax.lax.map(one_penalty, thetas))

    return jnp.mean(jax.lax.map(one_draw, targets))


def cqd_target_points(
    key: PRNGKey,
    low: ArrayLike | Sequence[float],
    high: ArrayLike | Sequence[float],
    num_points: int,
    iterations: int | None = None,
) -> Array:
    """Target points for `cqd_score`, uniform in the box [low, high] (D values each).

    Draw them once per run (one key) and reuse them at every log point, so that the
    score's changes come from the elites, not from the targets.

    Returns:
      (num_points, D) float32, or (iterations, num_points, D) when `iterations` is given.
    """
    lo = jnp.asarray(low, jnp.float32)
    hi = jnp.asarray(high, jnp.float32)
    if lo.ndim != 1 or hi.shape != lo.shape:
        raise ValueError(f"cqd_target_points: expected low and high of shape (D,), got {lo.shape} and {hi.shape}")
    shape = (num_points,) if iterations is None else (iterations, num_points)
    return jax.random.uniform(key, (*shape, lo.shape[0]), jnp.float32, lo, hi)
