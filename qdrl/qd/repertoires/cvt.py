"""Centroids of a centroidal Voronoi tessellation (CVT) of a descriptor box, by k-means.

CVT-MAP-Elites (Vassiliades et al. 2018) partitions the descriptor space into
`num_centroids` cells of roughly equal volume: sample many points uniformly in the
box and run Lloyd's k-means on them; the cluster centres are the centroids.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.repertoires.cells import as_bounds, nearest_centroid
from qdrl.types import Array, PRNGKey

__all__ = ["cvt_centroids", "nearest_centroid"]


@partial(jax.jit, static_argnames=("num_centroids", "num_samples", "num_iters"))
def _kmeans(
    key: PRNGKey, low: Array, high: Array, num_centroids: int, num_samples: int, num_iters: int
) -> Array:
    sample_key, init_key = jax.random.split(key)
    points = jax.random.uniform(
        sample_key, (num_samples, low.shape[0]), jnp.float32, minval=low, maxval=high
    )
    init = points[jax.random.choice(init_key, num_samples, (num_centroids,), replace=False)]

    def lloyd_step(_: int, centroids: Array) -> Array:
        assign = nearest_centroid(points, centroids)
        sums = jax.ops.segment_sum(points, assign, num_segments=num_centroids)
        counts = jax.ops.segment_sum(
            jnp.ones((num_samples,), jnp.float32), assign, num_segments=num_centroids
        )
        # An empty cluster keeps its previous centroid rather than collapsing to 0/0.
        return jnp.where(counts[:, None] > 0, sums / jnp.maximum(counts, 1.0)[:, None], centroids)

    return jax.lax.fori_loop(0, num_iters, lloyd_step, init)


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
      key: PRNG key for the uniform samples and the initial centroids (a random
        subset of the samples).
      num_centroids: number of cells C (<= num_samples).
      num_samples: uniform points in the box that k-means clusters, e.g. 50_000.
      low, high: box bounds, D values each (scalars need `num_descriptors`).
      num_iters: Lloyd iterations.
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
