"""QD-suite tasks: Archimedean spiral, deceptive evolvability, self-similar function.

Salehi & Doncieux 2022, "Towards QD-suite: developing a set of benchmarks for
Quality-Diversity algorithms" (arXiv:2205.03162), as in QDax's
`qdax/tasks/qd_suite/`. None of them rewards quality: the fitness is the constant
1, so the QD score counts filled cells (qd_offset 0, max_fitness 1). Each probes a
way that the genotype-to-descriptor map makes exploration hard, which is why they
start from the single point QDax starts from, not from a uniform population.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.config import NonNegativeFloat, PositiveFloat, PositiveInt
from qdrl.tasks.base import Task, batched_scoring_fn
from qdrl.types import Array, PRNGKey

_CONSTANT_FITNESS = 1.0


def _repeat_init(point: Sequence[float]) -> Callable[[PRNGKey, int], Array]:
    row = np.asarray(point, np.float32)

    def init_fn(key: PRNGKey, n: int) -> Array:
        del key  # every QD-suite run starts from the same point
        return jnp.tile(jnp.asarray(row)[None], (n, 1))

    return init_fn


# --- Archimedean spiral ---------------------------------------------------------


def _spiral_point(angle: Array, amplitude: float) -> Array:
    """gamma(theta) = a theta (cos theta, sin theta)."""
    return amplitude * angle * jnp.stack([jnp.cos(angle), jnp.sin(angle)])


def spiral_arc_length(angle: Array, amplitude: float) -> Array:
    """L(theta) = (a / 2) (theta sqrt(1 + theta^2) + asinh(theta)), arc length from 0 to theta."""
    return 0.5 * amplitude * (angle * jnp.sqrt(1.0 + angle * angle) + jnp.arcsinh(angle))


def _spiral_angle(arc_length: Array, amplitude: float, max_angle: float) -> Array:
    """theta = L^{-1}(s): 40 bisection steps on [0, max_angle], then one Newton step.

    The bisection (QDax's `_approximate_angle_from_arc_length`) carries no gradient;
    the Newton step theta_0 - (L(theta_0) - s) / L'(theta_0), with theta_0 held
    constant, both polishes the value and gives the exact implicit derivative
    d theta / d s = 1 / L'(theta) = 1 / (a sqrt(1 + theta^2)).
    """
    s = jax.lax.stop_gradient(arc_length)

    def bisect(_: int, bounds: tuple[Array, Array]) -> tuple[Array, Array]:
        low, high = bounds
        middle = 0.5 * (low + high)
        below = spiral_arc_length(middle, amplitude) > s
        return jnp.where(below, low, middle), jnp.where(below, middle, high)

    low, high = jax.lax.fori_loop(0, 40, bisect, (jnp.zeros_like(s), jnp.full_like(s, max_angle)))
    theta_0 = 0.5 * (low + high)
    slope = amplitude * jnp.sqrt(1.0 + theta_0 * theta_0)
    theta = theta_0 - (spiral_arc_length(theta_0, amplitude) - arc_length) / slope
    return jnp.clip(theta, 0.0, max_angle)


def archimedean_spiral(
    parameterization: Literal["angle", "arc_length"] = "angle",
    descriptor: Literal["euclidean", "geodesic"] = "euclidean",
    amplitude: PositiveFloat = 0.01,
    alpha: PositiveFloat = 40.0,
) -> Task:
    """Archimedean spiral (QD-suite `archimedean-spiral-v0`, QDax `ArchimedeanSpiralV0`).

    The 1-D genotype is a position on the spiral gamma(theta) = a theta (cos theta,
    sin theta), theta in [0, alpha pi]: either the angle theta itself
    (`parameterization="angle"`) or the arc length s = L(theta) = (a/2)(theta
    sqrt(1 + theta^2) + asinh theta) (`"arc_length"`; theta is recovered by
    bisection). The descriptor is the point gamma(theta) in [-a alpha pi,
    a alpha pi]^2 (`descriptor="euclidean"`) or its arc length s in
    [0, L(alpha pi)] (`"geodesic"`). Genotypes are clipped to their bounds. All
    runs start at theta_0 = 2 pi (1 + floor(alpha pi / 2 / (2 pi))) (22 pi by
    default), as in QDax. Fitness is 1.
    """
    if parameterization not in ("angle", "arc_length"):
        raise ValueError(
            f"parameterization must be 'angle' or 'arc_length', got {parameterization!r}"
        )
    if descriptor not in ("euclidean", "geodesic"):
        raise ValueError(f"descriptor must be 'euclidean' or 'geodesic', got {descriptor!r}")
    max_angle = alpha * math.pi
    max_arc = 0.5 * amplitude * (max_angle * math.sqrt(1.0 + max_angle**2) + math.asinh(max_angle))
    max_radius = amplitude * max_angle
    genotype_high = max_angle if parameterization == "angle" else max_arc

    def evaluate(genotype: Array) -> tuple[Array, Array]:
        g = jnp.clip(genotype[0], 0.0, genotype_high)
        fitness = jnp.asarray(_CONSTANT_FITNESS, g.dtype)
        if descriptor == "geodesic":
            arc = spiral_arc_length(g, amplitude) if parameterization == "angle" else g
            return fitness, arc[None]
        angle = g if parameterization == "angle" else _spiral_angle(g, amplitude, max_angle)
        return fitness, _spiral_point(angle, amplitude)

    start_angle = 2.0 * math.pi * (1 + int(max_angle / 2.0 / (2.0 * math.pi)))
    if parameterization == "angle":
        start = start_angle
    else:
        start = (
            0.5
            * amplitude
            * (start_angle * math.sqrt(1.0 + start_angle**2) + math.asinh(start_angle))
        )
    low: tuple[float, ...] = (-max_radius, -max_radius) if descriptor == "euclidean" else (0.0,)
    high: tuple[float, ...] = (max_radius, max_radius) if descriptor == "euclidean" else (max_arc,)
    return Task(
        name=f"archimedean_spiral_{parameterization}_{descriptor}",
        scoring_fn=batched_scoring_fn(evaluate, 1),
        descriptor_low=low,
        descriptor_high=high,
        descriptor_names=("x", "y") if descriptor == "euclidean" else ("arc length",),
        genotype_size=1,
        genotype_low=0.0,
        genotype_high=genotype_high,
        qd_offset=0.0,
        max_fitness=_CONSTANT_FITNESS,
        init_fn=_repeat_init([start]),
    )


# --- Deceptive evolvability -----------------------------------------------------


def _gaussian(x: Array, mu: Array, sigma: float) -> Array:
    """Isotropic normal density N(x; mu, sigma^2 I), normalised as in QDax."""
    n = x.shape[-1]
    sq = jnp.sum(jnp.square(x - mu), axis=-1)
    return jnp.exp(-0.5 * sq / (sigma * sigma)) * (2.0 * jnp.pi * sigma * sigma) ** (-n / 2.0)


def _np_gaussian(x: np.ndarray, mu: np.ndarray, sigma: float) -> np.ndarray:
    n = x.shape[-1]
    sq = np.sum(np.square(x - mu), axis=-1)
    return np.exp(-0.5 * sq / sigma**2) * (2.0 * np.pi * sigma**2) ** (-n / 2.0)


# QD-suite's widths of the two bumps.
SIGMA_1 = math.sqrt(70.0)
SIGMA_2 = math.sqrt(1e3)


def deceptive_evolvability(
    mu_1: Sequence[float] = (50.0, 125.0),
    sigma_1: PositiveFloat = SIGMA_1,
    beta: NonNegativeFloat = 20.0,
    mu_2: Sequence[float] = (150.0, 125.0),
    sigma_2: PositiveFloat = SIGMA_2,
) -> Task:
    """Deceptive evolvability (QD-suite `deceptive-evolvability-v0`, QDax `DeceptiveEvolvabilityV0`).

    The 1-D descriptor of x in R^n (n = len(mu_1)) is a sum of two Gaussian bumps,
    d(x) = N(x; mu_1, sigma_1^2 I) + beta N(x; mu_2, sigma_2^2 I) with
    N(x; mu, s^2 I) = exp(-|x - mu|^2 / (2 s^2)) (2 pi s^2)^(-n/2): a narrow peak
    and a wide, higher one. Search starts at the saddle point between them (the
    minimiser of d over 1000 points of the segment mu_1 -> mu_2), from where
    the gradient of descriptor novelty leads towards the narrow peak. Genotype
    bounds are the scalars min_k min(mu_k - 3 sigma_k) and max_k max(mu_k +
    3 sigma_k); descriptor bounds [0, max(d(mu_1), d(mu_2))], both as QDax (for
    the defaults d reaches no higher than d(mu_2) to float precision). Fitness is 1.
    """
    m1 = np.asarray(mu_1, np.float64)
    m2 = np.asarray(mu_2, np.float64)
    if m1.ndim != 1 or m1.shape != m2.shape:
        raise ValueError(
            f"mu_1 and mu_2 must be vectors of one size, got {m1.shape} and {m2.shape}"
        )

    def np_descriptor(x: np.ndarray) -> np.ndarray:
        return _np_gaussian(x, m1, sigma_1) + beta * _np_gaussian(x, m2, sigma_2)

    segment = m1 + np.linspace(0.0, 1.0, 1000)[:, None] * (m2 - m1)
    saddle = segment[int(np.argmin(np_descriptor(segment)))]
    descriptor_high = float(max(np_descriptor(m1), np_descriptor(m2)))
    genotype_low = float(min(np.min(m1 - 3 * sigma_1), np.min(m2 - 3 * sigma_2)))
    genotype_high = float(max(np.max(m1 + 3 * sigma_1), np.max(m2 + 3 * sigma_2)))
    mu_1_j = jnp.asarray(m1, jnp.float32)
    mu_2_j = jnp.asarray(m2, jnp.float32)

    def evaluate(x: Array) -> tuple[Array, Array]:
        d = _gaussian(x, mu_1_j, sigma_1) + beta * _gaussian(x, mu_2_j, sigma_2)
        return jnp.asarray(_CONSTANT_FITNESS, x.dtype), d[None]

    return Task(
        name="deceptive_evolvability",
        scoring_fn=batched_scoring_fn(evaluate, m1.shape[0]),
        descriptor_low=(0.0,),
        descriptor_high=(descriptor_high,),
        genotype_size=m1.shape[0],
        genotype_low=genotype_low,
        genotype_high=genotype_high,
        qd_offset=0.0,
        max_fitness=_CONSTANT_FITNESS,
        init_fn=_repeat_init(saddle.tolist()),
    )


# --- Self-similar function ------------------------------------------------------


def ssf_radii(max_radius: float) -> np.ndarray:
    """The SSF radii r_1 < r_2 < ... up to the first even one >= max_radius.

    r_0 = 0, r_{2k+1} = r_{2k} + 2 k^3 + 1, r_{2k+2} = r_{2k+1} + 2 k^3 + 1
    (QDax `SsfV0`: 1, 2, 5, 8, 25, 42, 97, 152, ...); returned as pairs
    (r_{2k+1}, r_{2k+2}), shape (K, 2).
    """
    pairs = []
    r, k = 0.0, 0
    while True:
        odd = r + 2 * k**3 + 1
        even = odd + 2 * k**3 + 1
        pairs.append((odd, even))
        r, k = even, k + 1
        if even >= max_radius:
            return np.asarray(pairs, np.float64)


def ssf(num_dims: PositiveInt = 1, radius: PositiveFloat = 1000.0) -> Task:
    """Self-similar function (QD-suite `SSF-v0`, QDax `SsfV0`).

    With r = |x| and the radii of `ssf_radii`, the descriptor is r on
    [r_{2k}, r_{2k+1}) and the constant r_{2k+1} on [r_{2k+1}, r_{2k+2}]: a
    staircase whose flat steps grow like k^3, so progress needs ever larger jumps.
    QDax's genotype is unbounded and its descriptor bounded to [0, 1000] for
    grids; here the genotype box is [-radius / sqrt(n), radius / sqrt(n)]^n, so
    |x| <= radius and the descriptor (never above |x|) lies in [0, radius].
    Starts at x = 0. Fitness is 1.
    """
    if num_dims < 1:
        raise ValueError(f"ssf: num_dims must be >= 1, got {num_dims}")
    pairs = ssf_radii(radius)
    odd = jnp.asarray(pairs[:, 0], jnp.float32)
    even = jnp.asarray(pairs[:, 1], jnp.float32)
    bound = radius / math.sqrt(num_dims)

    def evaluate(x: Array) -> tuple[Array, Array]:
        x = jnp.clip(x, -bound, bound)
        sq = jnp.sum(x * x)
        positive = sq > 0.0
        norm = jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)
        # level k: the first with r_{2k+2} >= |x| (QDax's while loop)
        k = jnp.minimum(
            jnp.searchsorted(even, jax.lax.stop_gradient(norm), side="left"), odd.shape[0] - 1
        )
        descriptor = jnp.where(norm < odd[k], norm, odd[k])
        return jnp.asarray(_CONSTANT_FITNESS, x.dtype), descriptor[None]

    return Task(
        name="ssf",
        scoring_fn=batched_scoring_fn(evaluate, num_dims),
        descriptor_low=(0.0,),
        descriptor_high=(float(radius),),
        genotype_size=num_dims,
        genotype_low=-bound,
        genotype_high=bound,
        qd_offset=0.0,
        max_fitness=_CONSTANT_FITNESS,
        init_fn=_repeat_init([0.0] * num_dims),
    )
