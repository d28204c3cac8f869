"""The linear-projection (LP) benchmarks of CMA-ME, DQD and CMA-MAE: sphere, rastrigin, plateau.

Fontaine et al. 2020 (CMA-ME, Section 4), Fontaine & Nikolaidis 2021 ("Differentiable
Quality Diversity") and 2023 (CMA-MAE); the definitions of their experiment code
(`lin_proj.py`) and of pyribs' `examples/sphere.py`:

- genotype x in R^n, unbounded (`genotype_low`, `genotype_high` = -inf, inf: no
  emitter clips it; searches start at x0 = 0, MAP-Elites from N(0, I) samples);
- descriptors: the sums of the "clipped" halves of x, where a gene inside
  [-5.12, 5.12] counts as itself and one outside as 5.12 / x_i; each lies in
  [-5.12 n/2, 5.12 n/2], the archive's bounds;
- fitness normalised so that 100 is the optimum, with s = 0.4 * 5.12 = 2.048:
  sphere 100 (1 - sum (x_i - s)^2 / (n (5.12 + s)^2)); rastrigin the same with
  Rastrigin's function of x - s over its value at x = -5.12 everywhere; plateau
  100 - mean_i max(|x_i| - 5.12, 0)^2 (flat, 100, inside the box). Fitness drops
  below 0 far outside the box, as in the papers.

The QD score of the papers is computed with offset 0 and normalised by the
number of cells (`normalised_qd_score`). `task.gradient_scoring_fn` evaluates
with the fitness gradient and the descriptor Jacobian (autodiff of these very
functions) in the extras, for the MEGA emitters.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp

from qdrl.tasks.base import Task, batched_scoring_fn
from qdrl.tasks.functions import NumDims, _project, _rastrigin_f, _sphere_f
from qdrl.types import Array, PRNGKey

__all__ = ["lp_plateau", "lp_rastrigin", "lp_sphere"]

BOUND = 5.12
SHIFT = 0.4 * BOUND  # the optimum, x_i = 2.048


def lp_descriptors(x: Array) -> Array:
    """(2,) sums of the clipped first and second halves of x (n // 2 genes in the first)."""
    half = x.shape[-1] // 2
    p = _project(x, -BOUND, BOUND)
    return jnp.stack([jnp.sum(p[:half]), jnp.sum(p[half:])])


def _normal_init(num_dims: int) -> Callable[[PRNGKey, int], Array]:
    def init(key: PRNGKey, n: int) -> Array:
        return jax.random.normal(key, (n, num_dims), jnp.float32)

    return init


def _lp_task(name: str, fitness: Callable[[Array], Array], num_dims: int) -> Task:
    if not (isinstance(num_dims, int) and num_dims >= 2):
        raise ValueError(f"{name}: num_dims must be an integer >= 2, got {num_dims!r}")

    def evaluate(x: Array) -> tuple[Array, Array]:
        return fitness(x), lp_descriptors(x)

    box = BOUND * num_dims / 2.0
    return Task(
        name=name,
        scoring_fn=batched_scoring_fn(evaluate, num_dims),
        gradient_scoring_fn=batched_scoring_fn(evaluate, num_dims, gradients=True),
        descriptor_low=(-box, -box),
        descriptor_high=(box, box),
        descriptor_names=("projection of the first half", "projection of the second half"),
        genotype_size=num_dims,
        genotype_low=-math.inf,  # unbounded, as in the papers: no emitter clips
        genotype_high=math.inf,
        qd_offset=0.0,
        max_fitness=100.0,
        init_fn=_normal_init(num_dims),
    )


def lp_sphere(num_dims: NumDims = 100) -> Task:
    """LP sphere: 100 (1 - sum (x_i - 2.048)^2 / (n 7.168^2)); 100 at x = 2.048, 0 at x = -5.12."""
    worst = num_dims * (-BOUND - SHIFT) ** 2

    def fitness(x: Array) -> Array:
        return 100.0 * (1.0 - _sphere_f(x - SHIFT) / worst)

    return _lp_task("lp_sphere", fitness, num_dims)


def lp_rastrigin(num_dims: NumDims = 100) -> Task:
    """LP rastrigin: 100 (1 - R(x - 2.048) / R(-7.168 ...)), R Rastrigin's function (A = 10)."""
    d = -BOUND - SHIFT
    worst = num_dims * (10.0 + d * d - 10.0 * math.cos(2.0 * math.pi * d))

    def fitness(x: Array) -> Array:
        return 100.0 * (1.0 - _rastrigin_f(x - SHIFT) / worst)

    return _lp_task("lp_rastrigin", fitness, num_dims)


def lp_plateau(num_dims: NumDims = 100) -> Task:
    """LP plateau: 100 - mean_i max(|x_i| - 5.12, 0)^2 (100 everywhere inside the box)."""

    def fitness(x: Array) -> Array:
        excess = jnp.maximum(jnp.abs(x) - BOUND, 0.0)
        return 100.0 - jnp.mean(excess * excess)

    return _lp_task("lp_plateau", fitness, num_dims)
