"""Pareto utilities: dominance, non-dominated sorting, crowding distance, hypervolume.

Every objective is MAXIMISED (qdrl's convention for fitness); a problem stated as
minimisation (ZDT, DTLZ) is scored as minus its objectives. Points are rows of an
(n, M) array; a boolean `mask` (n,) marks the rows that are members of the set
(fronts and populations are padded to fixed shapes under jit), and rows outside it
never dominate, are never dominated, and count for nothing.

Everything here is jittable except `hypervolume_exact`, which runs on the host and
calls moocore (López-Ibáñez et al., the C implementations of the exact
hypervolume algorithms: HV3D+ for three objectives, WFG / HV4D+ beyond) for any
number of objectives. Inside jit the hypervolume is exact for two objectives
(`hypervolume_2d`) and a Monte-Carlo estimate for more (`hypervolume_mc`).
MOME's repertoire, NSGA-II, SPEA2 and the multi-objective metrics all use this
module.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import moocore
import numpy as np

from qdrl.types import Array, PRNGKey

__all__ = [
    "crowding_distance",
    "dominance_matrix",
    "dominates",
    "front_ranks",
    "hypervolume_2d",
    "hypervolume_exact",
    "hypervolume_mc",
    "non_dominated",
    "prune_crowding",
]


def _mask(points: Array, mask: Array | None) -> Array:
    if mask is None:
        return jnp.ones(points.shape[:1], bool)
    return jnp.asarray(mask, bool)


def dominates(a: Array, b: Array) -> Array:
    """Whether a dominates b (maximisation): a >= b everywhere and a > b somewhere.

    Broadcasts over leading axes; equal points do not dominate each other.
    """
    return jnp.all(a >= b, axis=-1) & jnp.any(a > b, axis=-1)


def dominance_matrix(points: Array, mask: Array | None = None) -> Array:
    """(n, n) bool, entry [i, j] True when member i dominates member j."""
    mask = _mask(points, mask)
    d = dominates(points[:, None, :], points[None, :, :])
    return d & mask[:, None] & mask[None, :]


def non_dominated(points: Array, mask: Array | None = None) -> Array:
    """(n,) bool: members that no other member dominates (duplicates are all kept)."""
    mask = _mask(points, mask)
    return mask & ~jnp.any(dominance_matrix(points, mask), axis=0)


def front_ranks(points: Array, mask: Array | None = None) -> Array:
    """(n,) int32 non-dominated sorting: 0 for the first front, 1 for the next, ...

    Deb et al. 2002 (NSGA-II), fast non-dominated sort: the domination counts of the
    remaining members drop by what each peeled front dominated. Non-members get n.
    """
    mask = _mask(points, mask)
    n = points.shape[0]
    dom = dominance_matrix(points, mask).astype(jnp.int32)
    ranks0 = jnp.full((n,), n, jnp.int32)
    counts0 = jnp.sum(dom, axis=0)

    def cond(carry: tuple[Array, Array, Array]) -> Array:
        ranks, _, _ = carry
        return jnp.any(mask & (ranks == n))

    def body(carry: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        ranks, counts, level = carry
        front = mask & (ranks == n) & (counts == 0)
        ranks = jnp.where(front, level, ranks)
        counts = counts - front.astype(jnp.int32) @ dom
        return ranks, counts, level + 1

    ranks, _, _ = jax.lax.while_loop(cond, body, (ranks0, counts0, jnp.zeros((), jnp.int32)))
    return ranks


def crowding_distance(
    points: Array, mask: Array | None = None, ranks: Array | None = None
) -> Array:
    """(n,) crowding distance of each member within its front (Deb et al. 2002).

    Per objective, the members of a front are sorted; the two extremes get +inf and
    each other member adds (next - previous) / (front's max - min) of that objective.
    With `ranks` (from `front_ranks`) every front is treated apart; without, the
    members form one front. Non-members get -inf. Members with equal values are
    ordered by index, as a stable sort does.
    """
    mask = _mask(points, mask)
    n, m = points.shape
    rank = jnp.zeros((n,), jnp.int32) if ranks is None else jnp.asarray(ranks, jnp.int32)
    rank = jnp.where(mask, rank, n + 1)  # non-members after every front
    segments = n + 2
    dist = jnp.zeros((n,), points.dtype)
    for k in range(m):
        v = points[:, k]
        order = jnp.lexsort((v, rank))
        sv, sr = v[order], rank[order]
        hi = jax.ops.segment_max(jnp.where(mask, v, -jnp.inf), rank, num_segments=segments)
        lo = jax.ops.segment_min(jnp.where(mask, v, jnp.inf), rank, num_segments=segments)
        span = (hi - lo)[sr]
        prev_same = jnp.concatenate([jnp.array([False]), sr[1:] == sr[:-1]])
        next_same = jnp.concatenate([sr[:-1] == sr[1:], jnp.array([False])])
        prev_v = jnp.concatenate([sv[:1], sv[:-1]])
        next_v = jnp.concatenate([sv[1:], sv[-1:]])
        gap = jnp.where(span > 0, (next_v - prev_v) / jnp.where(span > 0, span, 1.0), 0.0)
        contrib = jnp.where(prev_same & next_same, gap, jnp.inf)
        dist = dist.at[order].add(contrib)
    return jnp.where(mask, dist, -jnp.inf)


def prune_crowding(points: Array, members: Array, keep: Array | int) -> tuple[Array, Array]:
    """Thins one front to `keep` members, removing the most crowded one at a time.

    The pruning crowding distance of Kukkonen & Deb 2006 ("Improved pruning of
    non-dominated solutions based on crowding distance for bi-objective
    optimization problems"; pymoo's `RankAndCrowding(crowding_func="pcd")`): the
    objectives are scaled by the members' ranges, the members with the lowest and the
    highest value of each objective are never removed, and after each removal the
    crowding distances of the rest are computed again, where a single cut by the
    first distances (`crowding_distance`) removes whole clusters of neighbours at once.

    Args:
      points: (n, M) objectives.
      members: (n,) bool, the front to thin (rows outside it are ignored).
      keep: how many members to keep (a traced scalar is fine).

    Returns:
      (kept, distance): (n,) bool, the members left (never fewer than the extremes),
      and their crowding distances among themselves (+inf for the extremes, -inf off
      `kept`). Equal distances remove the lowest index first.
    """
    points = jnp.asarray(points, jnp.float32)
    members = jnp.asarray(members, bool)
    n, m = points.shape
    lo = jnp.min(jnp.where(members[:, None], points, jnp.inf), axis=0)
    hi = jnp.max(jnp.where(members[:, None], points, -jnp.inf), axis=0)
    span = jnp.where(hi > lo, hi - lo, 1.0)
    scaled = jnp.where(members[:, None], (points - lo) / span, 0.0)
    orders = [jnp.lexsort((jnp.arange(n), jnp.where(members, scaled[:, k], jnp.inf))) for k in range(m)]
    extreme = jnp.zeros((n,), bool)
    for k in range(m):
        v = jnp.where(members, points[:, k], jnp.nan)
        extreme = extreme.at[jnp.nanargmin(v)].set(True).at[jnp.nanargmax(v)].set(True)
    extreme = extreme & members
    pos = jnp.arange(n)

    def distance(alive: Array) -> Array:
        dist = jnp.zeros((n,), jnp.float32)
        for k, order in enumerate(orders):
            on = alive[order]
            sv = scaled[order, k]
            before = jax.lax.cummax(jnp.where(on, pos, -1))  # last alive at or before i
            after = jax.lax.cummin(jnp.where(on, pos, n), reverse=True)  # first alive at or after i
            prev = jnp.concatenate([jnp.array([-1]), before[:-1]])
            nxt = jnp.concatenate([after[1:], jnp.array([n])])
            both = (prev >= 0) & (nxt < n)
            gap = jnp.where(both, sv[jnp.clip(nxt, 0, n - 1)] - sv[jnp.clip(prev, 0, n - 1)], jnp.inf)
            dist = dist.at[order].add(jnp.where(on, gap, 0.0))
        return jnp.where(alive, jnp.where(extreme, jnp.inf, dist), -jnp.inf)

    def removable(alive: Array) -> Array:
        return alive & ~extreme

    def cond(alive: Array) -> Array:
        return (jnp.sum(alive) > keep) & jnp.any(removable(alive))

    def body(alive: Array) -> Array:
        # Removable members at an end of some order (distance +inf) rank below every
        # finite distance but above non-removable rows, so argmin always picks a removable one.
        d = jnp.minimum(distance(alive), jnp.finfo(jnp.float32).max)
        return alive.at[jnp.argmin(jnp.where(removable(alive), d, jnp.inf))].set(False)

    kept = jax.lax.while_loop(cond, body, members)
    return kept, distance(kept)


def hypervolume_2d(points: Array, reference: Array, mask: Array | None = None) -> Array:
    """() exact hypervolume of two-objective points w.r.t. `reference` (maximisation); jittable.

    The area of the union of the boxes [reference, p] over members p that strictly
    dominate the reference in both objectives (others add nothing). Sorted by the
    first objective, descending, each point adds its width times how far it rises
    above every point before it. O(n log n); dominated members add 0.
    """
    mask = _mask(points, mask)
    ref = jnp.asarray(reference, points.dtype)
    inside = mask & jnp.all(points > ref, axis=-1)
    p = jnp.where(inside[:, None], points, ref)
    order = jnp.argsort(-p[:, 0])
    x, y = p[order, 0], p[order, 1]
    best_before = jnp.concatenate([ref[1:2], jax.lax.cummax(y)[:-1]])
    return jnp.sum((x - ref[0]) * jnp.maximum(y - best_before, 0.0))


def hypervolume_mc(
    points: Array,
    reference: Array,
    key: PRNGKey,
    num_samples: int = 100_000,
    mask: Array | None = None,
) -> Array:
    """() Monte-Carlo estimate of the hypervolume, any number of objectives; jittable.

    Uniform samples in the box [reference, max of the members]; the box's volume times
    the share of samples that some member weakly dominates. Standard error about
    volume x sqrt(q (1 - q) / num_samples), for q the dominated share.
    """
    mask = _mask(points, mask)
    ref = jnp.asarray(reference, points.dtype)
    inside = mask & jnp.all(points > ref, axis=-1)
    top = jnp.max(jnp.where(inside[:, None], points, ref), axis=0)
    u = jax.random.uniform(key, (num_samples, points.shape[1]), points.dtype)
    samples = ref + u * (top - ref)
    covered = jnp.any(
        jnp.all(points[None, :, :] >= samples[:, None, :], axis=-1) & inside[None, :], axis=1
    )
    return jnp.prod(top - ref) * jnp.mean(covered.astype(points.dtype))


def hypervolume_exact(
    points: np.ndarray | Array, reference: Sequence[float] | np.ndarray, mask: np.ndarray | None = None
) -> float:
    """Exact hypervolume on the host (moocore), any number of objectives (maximisation).

    Rows outside `mask`, rows with a NaN or -inf, and rows that do not strictly
    dominate the reference in every objective are left out (they add nothing).
    """

    p = np.asarray(points, np.float64)
    ref = np.asarray(reference, np.float64)
    if p.ndim != 2 or ref.shape != (p.shape[1],):
        raise ValueError(
            f"hypervolume_exact: expected points (n, M) and a reference of M values, got "
            f"{p.shape} and {ref.shape}"
        )
    keep = np.all(np.isfinite(p), axis=1) & np.all(p > ref, axis=1)
    if mask is not None:
        keep &= np.asarray(mask, bool)
    if not keep.any():
        return 0.0
    return float(moocore.hypervolume(p[keep], ref=ref, maximise=True))
