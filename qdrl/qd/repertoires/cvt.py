"""Centroids of a centroidal Voronoi tessellation (CVT) of a descriptor box, by k-means.

CVT-MAP-Elites (Vassiliades et al. 2018) partitions the descriptor space into
`num_centroids` cells of roughly equal volume: sample many points uniformly in the
box and run Lloyd's k-means on them; the cluster centres are the centroids. The
centres start from greedy k-means++ seeding: Lloyd's iterations from a random subset
of the samples stall in a visibly uneven tessellation (the number of uniform points per
cell varies clearly more than with the seeding, which scikit-learn's k-means, QDax's,
also uses; figures in docs/benchmarks.md).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.repertoires.cells import as_bounds, nearest_centroid
from qdrl.types import Array, PRNGKey

__all__ = ["cvt_cells", "cvt_centroids", "nearest_centroid"]


def _kmeans_plus_plus(key: PRNGKey, points: Array, num_centroids: int) -> Array:
    """Greedy k-means++ seeding (Arthur & Vassilvitskii 2007; greedy variant as in scikit-learn).

    The first centre is a uniform sample; each next one is the best, by the sum of
    squared distances to the nearest centre, of `2 + ln(num_centroids)` candidates
    drawn with probability proportional to the squared distance to the nearest centre.
    """
    num_candidates = 2 + int(np.log(num_centroids))
    first_key, key = jax.random.split(key)
    first = points[jax.random.randint(first_key, (), 0, points.shape[0])]
    nearest = jnp.sum((points - first) ** 2, axis=-1)
    keys = jax.random.split(key, num_centroids)

    def add_centre(i: Array, carry: tuple[Array, Array]) -> tuple[Array, Array]:
        centres, nearest = carry
        # Inverse-CDF draws (a Gumbel draw per point and candidate costs far more on a CPU).
        cdf = jnp.cumsum(nearest)
        u = jax.random.uniform(keys[i], (num_candidates,), maxval=cdf[-1])
        picks = jnp.minimum(jnp.searchsorted(cdf, u, side="right"), points.shape[0] - 1)
        to_candidates = jnp.sum((points[:, None, :] - points[picks][None]) ** 2, axis=-1)  # (N, L)
        with_candidate = jnp.minimum(nearest[:, None], to_candidates)
        best = jnp.argmin(jnp.sum(with_candidate, axis=0))
        return centres.at[i].set(points[picks[best]]), with_candidate[:, best]

    centres = jnp.zeros((num_centroids, points.shape[1]), points.dtype).at[0].set(first)
    centres, _ = jax.lax.fori_loop(1, num_centroids, add_centre, (centres, nearest))
    return centres


@partial(jax.jit, static_argnames=("num_centroids", "num_samples", "num_iters"))
def _kmeans(
    key: PRNGKey, low: Array, high: Array, num_centroids: int, num_samples: int, num_iters: int
) -> Array:
    sample_key, init_key = jax.random.split(key)
    points = jax.random.uniform(
        sample_key, (num_samples, low.shape[0]), jnp.float32, minval=low, maxval=high
    )
    init = _kmeans_plus_plus(init_key, points, num_centroids)

    def lloyd_step(centroids: Array) -> Array:
        assign = nearest_centroid(points, centroids)
        sums = jax.ops.segment_sum(points, assign, num_segments=num_centroids)
        counts = jax.ops.segment_sum(
            jnp.ones((num_samples,), jnp.float32), assign, num_segments=num_centroids
        )
        # An empty cluster keeps its previous centroid rather than collapsing to 0/0.
        return jnp.where(counts[:, None] > 0, sums / jnp.maximum(counts, 1.0)[:, None], centroids)

    def not_done(carry: tuple[Array, Array, Array]) -> Array:
        i, _, moved = carry
        return (i < num_iters) & moved

    def step(carry: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        i, centroids, _ = carry
        new = lloyd_step(centroids)
        return i + 1, new, jnp.any(new != centroids)

    # Lloyd's iterations until no centroid moves (a fixed point), at most `num_iters`.
    _, centroids, _ = jax.lax.while_loop(not_done, step, (jnp.int32(0), init, jnp.bool_(True)))
    return centroids


def cvt_centroids(
    key: PRNGKey,
    num_centroids: int,
    num_samples: int,
    low: float | Sequence[float],
    high: float | Sequence[float],
    num_iters: int = 50,
    num_descriptors: int | None = None,
) -> Array:
    """(num_centroids, D) CVT centroids of the box `[low, high]` by Lloyd's k-means (jitted).

    Seeded and reproducible: the same key and arguments give identical centroids.
    Memory is O(num_samples * num_centroids) (one distance matrix per iteration).

    Args:
      key: PRNG key for the uniform samples and the initial centroids (greedy
        k-means++ seeding among the samples).
      num_centroids: number of cells C (<= num_samples).
      num_samples: uniform points in the box that k-means clusters, e.g. 50_000.
      low, high: box bounds, D values each (scalars need `num_descriptors`).
      num_iters: at most this many Lloyd iterations (fewer when the centroids stop
        moving).
      num_descriptors: D, when `low` and `high` are scalars.

    Returns:
      float32 centroids, each inside the box (a mean of points of the box).
    """
    if num_centroids <= 0 or num_samples < num_centroids:
        raise ValueError(
            f"need 0 < num_centroids <= num_samples, got {num_centroids} and {num_samples}"
        )
    if num_iters < 0:
        raise ValueError(f"num_iters must be >= 0, got {num_iters}")
    if num_descriptors is None:
        sizes = [int(np.size(v)) for v in (low, high) if np.ndim(v) > 0]
        if not sizes:
            raise ValueError("low and high are scalars: give num_descriptors (D)")
        num_descriptors = sizes[0]  # as_bounds checks that both agree
    lo = as_bounds(low, num_descriptors, "low")
    hi = as_bounds(high, num_descriptors, "high")
    if any(h <= a for a, h in zip(lo, hi, strict=True)):
        raise ValueError(f"need low < high in every dimension, got low={lo}, high={hi}")
    return _kmeans(
        key,
        jnp.asarray(lo, jnp.float32),
        jnp.asarray(hi, jnp.float32),
        num_centroids=int(num_centroids),
        num_samples=int(num_samples),
        num_iters=int(num_iters),
    )


@functools.lru_cache(maxsize=8)
def cvt_cells(
    seed: int, num_centroids: int, samples: int, low: tuple[float, ...], high: tuple[float, ...], iters: int
) -> np.ndarray:
    """The CVT cells (k-means centroids, host array) of a run of seed `seed`: the first of three
    keys split from the seed's, as the cells of every CVT run since qdrl 0.1. Kept for the
    process, so the seeds of a sweep that share `repertoire.cvt_seed` compute them once."""
    key = jax.random.split(jax.random.PRNGKey(seed), 3)[0]
    return np.asarray(cvt_centroids(key, num_centroids, samples, low, high, num_iters=iters))
