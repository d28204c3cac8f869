"""Exact nearest-centroid search for low-dimensional CVT archives through a lookup grid.

Brute force compares every descriptor with every centroid: for 1024 descriptors
and 1024 centroids that is a (1024 x 1024) distance matrix per batch, which on a
CPU costs about as much as the rest of a MAP-Elites iteration several times over.
Instead, the descriptor box is cut into a regular grid of lookup cells and, once,
each lookup cell gets the short list of centroids that can be nearest to some
point in it. A centroid c can be nearest to a point of box B only if its smallest
distance to B is at most the smallest, over all centroids c', of the largest
distance from c' to B (any point of B is at most that far from c'). Keeping every
centroid that passes this test makes the search exact: a descriptor is binned
like in a grid, then compared with its cell's few candidates only. Candidates are
kept in increasing index order, so ties resolve to the lowest index, as brute
force does.

Descriptors outside the box are compared with the box's "hull": every centroid
that can be nearest to some point of the box's boundary (the union of the
boundary lookup cells' candidates), and every centroid outside the box. That is
exact: if c is a nearest centroid of a point p outside the box and c lies in the
box, the segment from p to c stays in c's (convex) Voronoi cell and crosses the
box's boundary at a point b, of which c is then a nearest centroid, so c is among
the candidates of b's lookup cell. In two dimensions the hull is a small share of
the centroids (156 of 1024, 331 of 4096): every row is compared with it and the
rows outside the box take that answer, with no control flow (a `lax.cond` costs
compile time). Where the hull holds more than a quarter of the centroids (three
dimensions: 737 of 1024), a `lax.cond` searches it only when some row is outside.

The lookup grid is a CPU device: `nearest` uses it only when lowering for the CPU.
On a GPU (or TPU) the direct search, the argmin of the (n, C) squared differences,
is one fused kernel that never writes the distance matrix, while the lookup grid
costs several gathers and its `lax.cond` copies a predicate to the host at every
call, stopping the device until the host launches the next kernels.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.neighbours import squared_distances
from qdrl.types import Array

MAX_LOOKUP_CELLS = 1 << 18  # bounds the one-off construction cost and the table's memory
MAX_DIM = 3  # beyond this, R^D lookup cells get too many for a fine grid
# Construction compares every lookup cell with every centroid (about 4 C^2 pairs), a
# one-off cost that grows too long beyond this; larger archives use brute force.
MAX_CENTROIDS = 4096


class Lookup(NamedTuple):
    """Candidate centroids per lookup cell: (L, K) int32, padded by repeating the first;
    `hull`: (H,) int32 increasing, the candidates of points outside the box."""

    table: Array
    hull: Array
    shape: tuple[int, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]


def grid_bins(points: Array, shape: tuple[int, ...], low: tuple[float, ...], high: tuple[float, ...]) -> Array:
    """(n,) int32 row-major index of the regular-grid bin of each point (n, D); clipped to the edges."""
    lo = jnp.asarray(low, jnp.float32)
    hi = jnp.asarray(high, jnp.float32)
    bins_per_dim = jnp.asarray(shape, jnp.float32)
    scaled = (points - lo) / (hi - lo) * bins_per_dim
    # Clipped as floats before the cast, so +-inf and huge values cannot overflow.
    bins = jnp.clip(jnp.floor(scaled), 0.0, bins_per_dim - 1.0).astype(jnp.int32)
    return jnp.ravel_multi_index(
        tuple(bins[:, i] for i in range(bins.shape[1])), shape, mode="clip"
    ).astype(jnp.int32)


def _candidate_mask(box_lo: Array, box_hi: Array, centroids: Array) -> Array:
    """(B, C) bool: centroid c can be the nearest to some point of box b."""
    c = centroids[None]
    gap = jnp.maximum(jnp.maximum(box_lo[:, None] - c, c - box_hi[:, None]), 0.0)
    min_d = jnp.sum(gap**2, -1)
    far = jnp.maximum(jnp.abs(c - box_lo[:, None]), jnp.abs(c - box_hi[:, None]))
    bound = jnp.min(jnp.sum(far**2, -1), axis=1, keepdims=True)
    # A relative margin keeps float32 near-ties on the safe side (extra candidates only).
    return min_d <= bound * (1.0 + 1e-4) + 1e-9


@jax.jit
def _count(box_lo: Array, box_hi: Array, centroids: Array) -> Array:
    return jnp.sum(_candidate_mask(box_lo, box_hi, centroids), axis=1)


@jax.jit
def _first_k(box_lo: Array, box_hi: Array, centroids: Array, k_holder: Array) -> Array:
    mask = _candidate_mask(box_lo, box_hi, centroids)
    num = centroids.shape[0]
    # Largest scores are the kept centroids, lowest index first; past the count,
    # repeat the first candidate (a harmless duplicate for the argmin).
    score = jnp.where(mask, num - jnp.arange(num), -1)
    _, idx = jax.lax.top_k(score, k_holder.shape[0])
    valid = jnp.take_along_axis(mask, idx, 1)
    return jnp.where(valid, idx, idx[:, :1]).astype(jnp.int32)


def build_lookup(
    centroids: np.ndarray,
    low: tuple[float, ...],
    high: tuple[float, ...],
    cells_per_centroid: int = 4,
) -> Lookup | None:
    """The lookup grid of `centroids` (C, D) over the box [low, high].

    None when D > MAX_DIM or C > MAX_CENTROIDS (then brute force is used).
    """
    c = jnp.asarray(centroids, jnp.float32)
    num, dim = c.shape
    if dim > MAX_DIM or num > MAX_CENTROIDS:
        return None
    per_dim = int(np.ceil((cells_per_centroid * num) ** (1.0 / dim)))
    per_dim = max(1, min(per_dim, int(MAX_LOOKUP_CELLS ** (1.0 / dim))))
    shape = (per_dim,) * dim
    lo, hi = np.asarray(low, np.float64), np.asarray(high, np.float64)
    edges = [np.linspace(lo[i], hi[i], per_dim + 1) for i in range(dim)]
    # Every lookup cell's box, in row-major order (matching `grid_bins`).
    box_lo = np.stack(np.meshgrid(*[e[:-1] for e in edges], indexing="ij"), -1).reshape(-1, dim)
    box_hi = np.stack(np.meshgrid(*[e[1:] for e in edges], indexing="ij"), -1).reshape(-1, dim)
    rows = max(1, (1 << 23) // num)  # boxes per chunk: about 8M box-centroid pairs
    chunks = [
        (jnp.asarray(box_lo[i : i + rows], jnp.float32), jnp.asarray(box_hi[i : i + rows], jnp.float32))
        for i in range(0, len(box_lo), rows)
    ]
    width = int(max(int(jnp.max(_count(a, b, c))) for a, b in chunks))
    holder = jnp.zeros((width,))
    table = jnp.concatenate([_first_k(a, b, c, holder) for a, b in chunks])
    hull = _hull(np.asarray(table), np.asarray(centroids), shape, lo, hi)
    return Lookup(table, hull, shape, tuple(map(float, lo)), tuple(map(float, hi)))


def _hull(
    table: np.ndarray, centroids: np.ndarray, shape: tuple[int, ...], lo: np.ndarray, hi: np.ndarray
) -> Array:
    """(H,) int32, increasing: the boundary lookup cells' candidates and the centroids outside the box."""
    cells = np.stack(np.unravel_index(np.arange(table.shape[0]), shape), -1)
    boundary = np.any((cells == 0) | (cells == np.asarray(shape) - 1), axis=1)
    outside = np.any((centroids < lo) | (centroids > hi), axis=1)
    return jnp.asarray(np.union1d(table[boundary].ravel(), np.flatnonzero(outside)), jnp.int32)


def brute_nearest(points: Array, centroids: Array) -> Array:
    """(n,) int32 nearest centroid of each point by comparing with all of them, through a matmul.

    |x - c|^2 = |x|^2 - 2 x.c + |c|^2, where |x|^2 is the same for every centroid of
    a row and drops out of the argmin: one (n, C) matmul, the fastest form on a CPU.
    HIGHEST precision keeps GPUs off TF32, which would misplace points near borders.
    """
    cross = jnp.matmul(points, centroids.T, precision=jax.lax.Precision.HIGHEST)
    sq_centroids = jnp.sum(centroids**2, axis=-1)
    return jnp.argmin(sq_centroids[None, :] - 2.0 * cross, axis=-1).astype(jnp.int32)


def direct_nearest(points: Array, centroids: Array) -> Array:
    """(n,) int32 nearest centroid of each point: argmin over c of sum_d (x_d - c_d)^2.

    No cancellation, and on a GPU one fused reduction (QDax's form).
    """
    sq_dist = jnp.sum(jnp.square(points[:, None, :] - centroids[None]), axis=-1)
    return jnp.argmin(sq_dist, axis=-1).astype(jnp.int32)


def lookup_nearest(points: Array, centroids: Array, lookup: Lookup) -> Array:
    """(n,) int32 nearest centroid of each point (n, D), exact, through the lookup grid.

    Points inside the box: their lookup cell's candidates; outside: the hull's.
    """
    cand = lookup.table[grid_bins(points, lookup.shape, lookup.low, lookup.high)]  # (n, K)
    best = jnp.argmin(squared_distances(points, centroids[cand]), -1)  # first of equals: lowest index
    fast = jnp.take_along_axis(cand, best[:, None], 1)[:, 0]
    lo = jnp.asarray(lookup.low, jnp.float32)
    hi = jnp.asarray(lookup.high, jnp.float32)
    # Non-finite rows are rejected by `add` whatever their cell.
    outside = jnp.any((points < lo) | (points > hi), axis=-1)

    def from_hull() -> Array:
        d = squared_distances(points, centroids[lookup.hull])  # (n, H)
        # The lowest index among the nearest: the minimum, then the smallest index at that
        # distance (an argmin over H runs several times slower on a CPU).
        at_min = d == jnp.min(d, axis=-1, keepdims=True)
        nearest_hull = jnp.min(jnp.where(at_min, lookup.hull[None, :], jnp.iinfo(jnp.int32).max), -1)
        return jnp.where(outside, nearest_hull, fast)

    if 4 * lookup.hull.shape[0] <= centroids.shape[0]:
        return from_hull().astype(jnp.int32)
    return jax.lax.cond(jnp.any(outside), from_hull, lambda: fast).astype(jnp.int32)


def nearest(points: Array, centroids: Array, lookup: Lookup | None) -> Array:
    """(n,) int32 exact nearest centroid of each point (n, D); the search depends on the backend.

    Chosen when the function is lowered (`lax.platform_dependent`, nothing at run
    time): on the CPU the lookup grid when there is one, else `brute_nearest`; on
    other backends `direct_nearest` (see the module docstring). Ties go to the
    lowest index everywhere; the backends agree up to float32 rounding of
    distances within about 1e-7 of each other.
    """

    def cpu() -> Array:
        if lookup is None:
            return brute_nearest(points, centroids)
        return lookup_nearest(points, centroids, lookup)

    return jax.lax.platform_dependent(cpu=cpu, default=lambda: direct_nearest(points, centroids))
