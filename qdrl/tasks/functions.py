"""Standard optimisation functions as QD tasks: sphere, rastrigin, and their projection variants.

Two conventions coexist in the literature and both are here:

- `sphere`, `rastrigin` follow QDax's `standard_functions` (Cully-style
  MAP-Elites benchmarks): genotype g in [0, 1]^n, rescaled to x = 10 g - 5 in
  [-5, 5]^n; the descriptor is the first two genes (g_0, g_1) in [0, 1]^2.
- `sphere_proj`, `rastrigin_proj` follow CMA-ME (Fontaine et al. 2020, "Covariance
  Matrix Adaptation for the Rapid Illumination of Behavior Space") as implemented
  by pyribs and QDax's `rastrigin_proj_scoring_function` (used by OMG-MEGA /
  CMA-MEGA, Fontaine & Nikolaidis 2021): genotype x in [-5.12, 5.12]^n, optimum
  moved to x* = 0.4 * 5.12 = 2.048 in every dimension, descriptors the projection
  of x onto two halves of its genes.

Fitness is always `-f(x)` (maximised). Every function is pure JAX, batched and
differentiable inside the search bounds (the scoring functions of MEGA emitters
differentiate them with `jax.jacrev`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Annotated

import jax.numpy as jnp

from qdrl.config import Range
from qdrl.tasks.base import Task, batched_scoring_fn
from qdrl.types import Array

# What a `[task]` section may set (checked before the task is built): at least two
# dimensions (the descriptors need them), and projection bounds [-m, m] with m >= 1.
NumDims = Annotated[int, Range(low=2)]
MinVal = Annotated[float, Range(high=-1.0)]
MaxVal = Annotated[float, Range(low=1.0)]

_RASTRIGIN_A = 10.0


def _sphere_f(x: Array) -> Array:
    return jnp.sum(x * x, axis=-1)


def _rastrigin_f(x: Array) -> Array:
    n = x.shape[-1]
    return _RASTRIGIN_A * n + jnp.sum(x * x - _RASTRIGIN_A * jnp.cos(2.0 * jnp.pi * x), axis=-1)


def _check_dims(name: str, num_dims: int, minimum: int) -> None:
    if num_dims < minimum:
        raise ValueError(f"{name}: num_dims must be >= {minimum}, got {num_dims}")


def _unit_cube_task(
    name: str, f: Callable[[Array], Array], num_dims: int, qd_offset: float
) -> Task:
    _check_dims(name, num_dims, 2)

    def evaluate(g: Array) -> tuple[Array, Array]:
        g = jnp.clip(g, 0.0, 1.0)
        x = 10.0 * g - 5.0
        return -f(x), g[:2]

    return Task(
        name=name,
        scoring_fn=batched_scoring_fn(evaluate, num_dims),
        descriptor_low=(0.0, 0.0),
        descriptor_high=(1.0, 1.0),
        descriptor_names=("gene 0", "gene 1"),
        genotype_size=num_dims,
        genotype_low=0.0,
        genotype_high=1.0,
        qd_offset=qd_offset,
        max_fitness=0.0,
    )


def sphere(num_dims: NumDims = 100) -> Task:
    """Sphere on [0, 1]^n (QDax `sphere_scoring_function`).

    g is clipped to [0, 1]^n, x = 10 g - 5; fitness = -sum_i x_i^2 (max 0 at
    g = 0.5); descriptor = (g_0, g_1). qd_offset = -25 n: the lowest fitness,
    reached at the corners of the cube (|x_i| = 5).
    """
    return _unit_cube_task("sphere", _sphere_f, num_dims, qd_offset=-25.0 * num_dims)


def rastrigin(num_dims: NumDims = 100) -> Task:
    """Rastrigin on [0, 1]^n (QDax `rastrigin_scoring_function`).

    g is clipped to [0, 1]^n, x = 10 g - 5; fitness = -(10 n + sum_i (x_i^2 -
    10 cos(2 pi x_i))) (max 0 at g = 0.5); descriptor = (g_0, g_1). qd_offset =
    -45 n: each term is at most 25 + 10 + 10 on [-5, 5] (the true minimum is about
    -40.35 n).
    """
    return _unit_cube_task("rastrigin", _rastrigin_f, num_dims, qd_offset=-45.0 * num_dims)


def _project(x: Array, minval: float, maxval: float) -> Array:
    """pyribs / QDax descriptor "clip": x inside [minval, maxval], else maxval / x."""
    inside = (x >= minval) & (x <= maxval)
    safe_x = jnp.where(inside, 1.0, x)  # keeps maxval / x (and its gradient) finite at x = 0
    return jnp.where(inside, x, maxval / safe_x)


def _projection_task(
    name: str,
    f: Callable[[Array], Array],
    num_dims: int,
    minval: float,
    maxval: float,
    max_term: float,
) -> Task:
    _check_dims(name, num_dims, 2)
    if not (minval == -maxval and maxval >= 1.0):
        raise ValueError(
            f"{name}: the projection needs symmetric bounds with maxval >= 1 so that "
            f"maxval / x stays in [minval, maxval]; got [{minval}, {maxval}]"
        )
    shift = -0.4 * minval
    half = num_dims // 2

    def evaluate(x: Array) -> tuple[Array, Array]:
        fitness = -f(x - shift)
        p = _project(x, minval, maxval)
        descriptors = jnp.stack([jnp.mean(p[:half]), jnp.mean(p[half:])])
        return fitness, descriptors

    return Task(
        name=name,
        scoring_fn=batched_scoring_fn(evaluate, num_dims),
        descriptor_low=(minval, minval),
        descriptor_high=(maxval, maxval),
        descriptor_names=("projection of the first half", "projection of the second half"),
        genotype_size=num_dims,
        genotype_low=minval,
        genotype_high=maxval,
        qd_offset=-max_term * num_dims,
        max_fitness=0.0,
    )


def sphere_proj(num_dims: NumDims = 100, minval: MinVal = -5.12, maxval: MaxVal = 5.12) -> Task:
    """Sphere with projection descriptors (CMA-ME's sphere; QDax CMA-ME tests).

    fitness = -sum_i (x_i - s)^2 with s = -0.4 minval (2.048 by default; max 0 at
    x = s). Descriptors (d_1, d_2) = (mean_{i < n//2} p(x_i), mean_{i >= n//2}
    p(x_i)) with p(v) = v inside [minval, maxval], maxval / v outside, so both lie
    in [minval, maxval]. pyribs sums instead of averaging: the same grid up to a
    linear rescale of the bounds. qd_offset = -n ceil((maxval + s)^2) (-52 n by
    default): (maxval + s)^2 is the largest term, at the far corner x = minval;
    rounding up keeps float32 evaluations of that corner above the offset.
    """
    shift = -0.4 * minval
    return _projection_task(
        "sphere_proj",
        _sphere_f,
        num_dims,
        minval,
        maxval,
        max_term=math.ceil((maxval + shift) ** 2),
    )


def rastrigin_proj(num_dims: NumDims = 100, minval: MinVal = -5.12, maxval: MaxVal = 5.12) -> Task:
    """Rastrigin with projection descriptors (QDax `rastrigin_proj_scoring_function`, CMA-ME).

    fitness = -(10 n + sum_i ((x_i - s)^2 - 10 cos(2 pi (x_i - s)))) with s =
    -0.4 minval (2.048 by default; max 0 at x = s); descriptors as `sphere_proj`
    (QDax averages over each half of the genes). Genotypes are not clipped (the
    projection is what keeps descriptors bounded, as in pyribs); emitters clip to
    the search bounds. qd_offset = -n ceil(20 + (maxval + s)^2) (-72 n by default):
    each term is at most (maxval + s)^2 + 10 + 10 inside the bounds.
    """
    shift = -0.4 * minval
    return _projection_task(
        "rastrigin_proj",
        _rastrigin_f,
        num_dims,
        minval,
        maxval,
        max_term=math.ceil(2.0 * _RASTRIGIN_A + (maxval + shift) ** 2),
    )
