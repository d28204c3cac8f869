"""Fixed-size Pareto populations with a survival rule: NSGA-II and SPEA2.

A population is a container like the repertoires (`add` / `sample`, a pytree), so
NSGA-II and SPEA2 run on the one QD loop (`qdrl.qd.map_elites.MapElites`): each
iteration the emitter makes N offspring from parents that `sample` draws by binary
tournaments between neighbours of the shuffled population (as Deb's NSGA-II code
and pymoo draw them: every member competes equally often), and `add` merges the N
members with the offspring and keeps N by the survival rule:

- "nsga2" (Deb, Pratap, Agarwal & Meyarivan 2002, "A fast and elitist
  multiobjective genetic algorithm: NSGA-II"): whole fronts of the non-dominated
  sorting in order, the last one cut by decreasing crowding distance (clones, copies
  of the objectives of an earlier member, after the distinct members of their front,
  which pymoo's duplicate elimination also does); the
  tournament prefers the lower front, then the larger crowding distance (both as
  computed in the merged population, as pymoo does). With `crowding="pruning"` the
  last front is thinned one member at a time, the distances computed again after
  each removal (Kukkonen & Deb 2006; pymoo's `crowding_func="pcd"`,
  `qdrl.qd.pareto.prune_crowding`).
- "spea2" (Zitzler, Laumanns & Thiele 2001, "SPEA2: Improving the strength Pareto
  evolutionary algorithm"): the population is SPEA2's external archive. Fitness
  F = R + D, with raw fitness R(i) the sum of the strengths (number of solutions
  dominated) of i's dominators and density D(i) = 1 / (sigma_k(i) + 2), sigma_k the
  distance in objective space to the k-th nearest neighbour, k = floor(sqrt(N + n)).
  The non-dominated (F < 1) survive; too few, the best F fill up; too many, the
  truncation removes one at a time the member whose sorted distances to the others
  are lexicographically smallest. The tournament prefers the smaller F.

Objectives are maximised; fitnesses (N, M), -inf rows are empty slots (a first
population smaller than N leaves some).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.pareto import crowding_distance, dominance_matrix, front_ranks, prune_crowding
from qdrl.qd.repertoires.cells import check_batch, init_storage
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = ["Crowding", "ParetoPopulation", "Survival", "pareto_population", "spea2_fitness", "tournament_pool"]

Survival = Literal["nsga2", "spea2"]
Crowding = Literal["distance", "pruning"]


def _concat(a: Genotype, b: Genotype) -> Genotype:
    return jax.tree.map(lambda x, y: jnp.concatenate([x, y.astype(x.dtype)]), a, b)


def spea2_fitness(points: Array, mask: Array, k: int) -> tuple[Array, Array]:
    """SPEA2's fitness F = R + D (lower is better) and the (n, n) SQUARED distances in objective space.

    Non-members get F = +inf and distances +inf. (The truncation only compares
    distances, which squaring keeps in order: the square root is taken of the k-th
    nearest alone.)
    """
    dom = dominance_matrix(points, mask)
    strength = jnp.sum(dom, axis=1).astype(jnp.float32)  # solutions each one dominates
    raw = jnp.sum(jnp.where(dom, strength[:, None], 0.0), axis=0)  # strengths of its dominators
    diff = points[:, None, :] - points[None, :, :]
    sq_dist = jnp.sum(diff * diff, axis=-1)
    n = points.shape[0]
    pair = mask[:, None] & mask[None, :] & ~jnp.eye(n, dtype=bool)
    sq_dist = jnp.where(pair, sq_dist, jnp.inf)
    if n > 1:
        # The k-th smallest of each row, as the smallest of the k largest of the negated row:
        # XLA:CPU keeps this a TopK call, while slicing one column of top_k's output is
        # rewritten into a full sort of every row, many times slower.
        kth = jnp.sqrt(-jnp.min(jax.lax.top_k(-sq_dist, min(k, n - 1))[0], axis=1))
    else:
        kth = jnp.full((n,), jnp.inf)
    density = 1.0 / (jnp.where(jnp.isfinite(kth), kth, 0.0) + 2.0)
    return jnp.where(mask, raw + density, jnp.inf), sq_dist


def tournament_pool(key: PRNGKey, members: Array, length: int) -> Array:
    """(length,) int32 member slots: the members in random orders, one order after another.

    Entry i is entry i mod m of order i // m (m members), so with m even consecutive
    pairs are two distinct members, and over the pool each member appears as often as
    any other, +-1. ceil(length / N) + 1 orders are drawn (N slots); when fewer than N
    slots hold members, later entries reuse them in turn. With no member, every entry
    is slot 0.
    """
    n = members.shape[0]
    reps = -(-length // n) + 1
    # Members first, in random order: argsort of uniform keys, +inf on empty slots.
    keys = jnp.where(members[None, :], jax.random.uniform(key, (reps, n)), jnp.inf)
    orders = jnp.argsort(keys, axis=1).astype(jnp.int32)
    count = jnp.maximum(jnp.sum(members, dtype=jnp.int32), 1)
    i = jnp.arange(length, dtype=jnp.int32)
    return orders[(i // count) % reps, i % count]


_Truncation = tuple[Array, Array, Array, Array, Array]  # alive, candidates, last value, uses, j


def _spea2_truncate(points: Array, dist: Array, keep: Array, size: int) -> Array:
    """Removes, while more than `size` remain, the member whose sorted distances to the other
    remaining members are lexicographically smallest (ties: the lowest index).

    Each row's sorted distances are walked one column at a time, and only while
    candidates tie (the two members of the closest pair always tie on the first
    column): column j of a row repeats the value of column j - 1 while the row holds
    more remaining members at that distance than already read, else it is the
    smallest distance above it. Masked reductions over the remaining members, no
    sort. One flat loop: each step reads one more column or removes a member.
    Candidates with equal objectives (clones) have equal rows and tie on every column:
    the lowest index goes at once.
    """
    n = dist.shape[0]

    def column(alive: Array, last_v: Array, used: Array) -> tuple[Array, Array]:
        live = alive[None, :]
        same = jnp.sum(live & (dist == last_v[:, None]), axis=1)
        above = jnp.min(jnp.where(live & (dist > last_v[:, None]), dist, jnp.inf), axis=1)
        repeat = same > used
        return jnp.where(repeat, last_v, above), jnp.where(repeat, used + 1, 1)

    def first(alive: Array) -> _Truncation:
        v, used = column(alive, jnp.full((n,), -jnp.inf), jnp.zeros((n,), jnp.int32))
        cand = alive & (v == jnp.min(jnp.where(alive, v, jnp.inf)))
        return alive, cand, v, used, jnp.ones((), jnp.int32)

    def narrow(c: _Truncation) -> _Truncation:
        alive, cand, last_v, used, j = c
        v, used = column(alive, last_v, used)
        return alive, cand & (v == jnp.min(jnp.where(cand, v, jnp.inf))), v, used, j + 1

    def remove(c: _Truncation) -> _Truncation:
        alive, cand = c[0], c[1]
        # The closest pair ties on the first column whatever the rest: read the second at
        # once (narrowing a single candidate keeps it), one loop step per removal instead of two.
        return narrow(first(alive.at[jnp.argmax(cand)].set(False)))

    def step(c: _Truncation) -> _Truncation:
        cand = c[1]
        clones = jnp.all(jnp.where(cand[:, None], points == points[jnp.argmax(cand)], True))
        tie = (jnp.sum(cand) > 1) & (c[4] < n) & ~clones
        return jax.lax.cond(tie, narrow, remove, c)

    return jax.lax.while_loop(lambda c: jnp.sum(c[0]) > size, step, narrow(first(keep)))[0]


@dataclasses.dataclass(frozen=True, eq=False)
class ParetoPopulation:
    """N solutions with vector fitnesses, kept by a survival rule ("nsga2" or "spea2").

    Attributes:
      genotypes: pytree, leaves (N, ...).
      fitnesses: (N, M) float32, -inf rows for empty slots.
      descriptors: (N, D) float32 (kept for plots and metrics; the rules ignore them).
      rank: (N,) int32 tournament key, lower wins first (NSGA-II: the front).
      score: (N,) float32 tournament key, higher wins on equal rank (NSGA-II:
        crowding distance; SPEA2: -F).
      survival: "nsga2" or "spea2".
      crowding: NSGA-II's cut of the last front: "distance" (Deb et al. 2002, one
        cut by the crowding distance) or "pruning" (one member at a time).
    """

    genotypes: Genotype
    fitnesses: Array
    descriptors: Array
    rank: Array
    score: Array
    survival: Survival = "nsga2"
    crowding: Crowding = "distance"

    @property
    def size(self) -> int:
        """N (static)."""
        return int(self.fitnesses.shape[0])

    @property
    def num_objectives(self) -> int:
        """M (static)."""
        return int(self.fitnesses.shape[1])

    @property
    def members(self) -> Array:
        """(N,) bool: slots holding a solution."""
        return jnp.all(self.fitnesses > -jnp.inf, axis=-1)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[ParetoPopulation, AddResult]:
        """Merges n offspring (fitnesses (n, M)) with the population and keeps N survivors.

        Offspring with a non-finite objective or a NaN descriptor never survive.
        `AddResult.added` says which offspring survived (`cell`: their slot, -1 if
        not); `improvement` is 1.0 for a survivor, 0.0 otherwise (-inf if invalid).
        """
        fitnesses = jnp.asarray(fitnesses, jnp.float32)
        m, size = self.num_objectives, self.size
        if fitnesses.ndim != 2 or fitnesses.shape[1] != m:
            raise ValueError(f"add: fitnesses must have shape (n, {m}), got {fitnesses.shape}")
        n = fitnesses.shape[0]
        descriptors, _ = check_batch(
            self.genotypes, self.descriptors.shape[1], genotypes, descriptors,
            jnp.zeros((n,), jnp.float32), "add",
        )
        valid = jnp.all(jnp.isfinite(fitnesses), axis=1) & ~jnp.any(jnp.isnan(descriptors), axis=1)
        f = jnp.concatenate([self.fitnesses, jnp.where(valid[:, None], fitnesses, -jnp.inf)])
        mask = jnp.concatenate([self.members, valid])
        total = size + n
        if self.survival == "nsga2":
            ranks = front_ranks(f, mask)
            crowd = crowding_distance(f, mask, ranks)
            # A copy of an earlier member's objectives (a clone) goes after the distinct members
            # of its front, as pymoo's duplicate elimination keeps clones out of the population.
            same = jnp.all(f[:, None, :] == f[None, :, :], axis=-1) & mask[None, :]
            clone = jnp.any(jnp.tril(same, k=-1), axis=1)
            if self.crowding == "pruning":
                crowd = self._pruned(f, mask, clone, ranks, crowd)
            order = jnp.lexsort((jnp.arange(total), -crowd, clone, ranks))
            chosen = order[:size]
            rank, score = ranks[chosen], crowd[chosen]
        else:
            k = int(math.sqrt(total))
            fit, dist = spea2_fitness(f, mask, k)
            non_dominated = fit < 1.0
            truncated = _spea2_truncate(f, dist, non_dominated, size)
            # Too many non-dominated: the truncation's survivors; else the best F.
            key = jnp.where(jnp.sum(non_dominated) > size, jnp.where(truncated, 0.0, jnp.inf), fit)
            order = jnp.lexsort((jnp.arange(total), key))
            chosen = order[:size]
            rank, score = jnp.zeros((size,), jnp.int32), -fit[chosen]
        in_mask = mask[chosen]
        new = dataclasses.replace(
            self,
            genotypes=jax.tree.map(lambda x: x[chosen], _concat(self.genotypes, genotypes)),
            fitnesses=jnp.where(in_mask[:, None], f[chosen], -jnp.inf),
            descriptors=jnp.concatenate([self.descriptors, descriptors])[chosen],
            rank=jnp.where(in_mask, rank, total).astype(jnp.int32),
            score=jnp.where(in_mask, score, -jnp.inf).astype(jnp.float32),
        )
        slot_of = jnp.full((total,), -1, jnp.int32).at[chosen].set(
            jnp.where(in_mask, jnp.arange(size, dtype=jnp.int32), -1)
        )
        survived = slot_of[size:] >= 0
        result = AddResult(
            added=survived,
            new_cell=jnp.zeros((n,), bool),
            improvement=jnp.where(valid, survived.astype(jnp.float32), -jnp.inf),
            cell=slot_of[size:],
        )
        return new, result

    def _pruned(self, f: Array, mask: Array, clone: Array, ranks: Array, crowd: Array) -> Array:
        """`crowd` with the front that the cut splits thinned by `prune_crowding`.

        The cut takes whole fronts, then the split front's distinct members, then its
        clones. The distinct members the pruning keeps get their distances among
        themselves, the removed ones -1 (after every kept one; clones come after both).
        """
        total, size = f.shape[0], self.size
        per_front = jax.ops.segment_sum(mask.astype(jnp.int32), ranks, num_segments=total + 1)
        before = jnp.cumsum(per_front) - per_front  # members in the fronts before
        overflow = before + per_front > size
        split = jnp.argmax(overflow)  # the first front that does not fit whole
        front = mask & ~clone & (ranks == split) & jnp.any(overflow)
        kept, dist = prune_crowding(f, front, size - before[split])
        return jnp.where(front, jnp.where(kept, dist, -1.0), crowd)

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` parents, each the winner of a binary tournament between two members.

        The tournaments pair neighbours in the members shuffled, shuffled again, and so
        on (`tournament_pool`): Deb's NSGA-II code and pymoo draw them so, and every
        member meets as many rivals as the others (in a full population drawn for N
        parents, exactly two), where independent draws leave some members out of
        every tournament. Lower `rank` wins, then higher `score`, then the first drawn.
        """
        pool = tournament_pool(key, self.members, 2 * num_samples)
        a, b = pool[0::2], pool[1::2]
        b_wins = (self.rank[b] < self.rank[a]) | (
            (self.rank[b] == self.rank[a]) & (self.score[b] > self.score[a])
        )
        idx = jnp.where(b_wins, b, a)
        return jax.tree.map(lambda x: x[idx], self.genotypes)


jax.tree_util.register_dataclass(
    ParetoPopulation,
    data_fields=["genotypes", "fitnesses", "descriptors", "rank", "score"],
    meta_fields=["survival", "crowding"],
)


def pareto_population(
    genotype_example: Genotype,
    population_size: int,
    num_objectives: int,
    descriptor_size: int,
    survival: Survival,
    crowding: Crowding = "distance",
) -> ParetoPopulation:
    """An empty population of `population_size` slots for NSGA-II ("nsga2") or SPEA2 ("spea2").

    `crowding` ("distance" or "pruning") is NSGA-II's cut of its last front.
    """
    if population_size < 1:
        raise ValueError(f"population_size: expected a positive integer, got {population_size}")
    if num_objectives < 2:
        raise ValueError(f"num_objectives: expected at least 2, got {num_objectives}")
    if survival not in ("nsga2", "spea2"):
        raise ValueError(f"survival: expected 'nsga2' or 'spea2', got {survival!r}")
    if crowding not in ("distance", "pruning"):
        raise ValueError(f"crowding: expected 'distance' or 'pruning', got {crowding!r}")
    if crowding != "distance" and survival != "nsga2":
        raise ValueError(f"crowding: {crowding!r} is NSGA-II's (survival 'nsga2'), got survival {survival!r}")
    return ParetoPopulation(
        genotypes=init_storage(genotype_example, population_size),
        fitnesses=jnp.full((population_size, num_objectives), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((population_size, descriptor_size), jnp.float32),
        rank=jnp.full((population_size,), population_size, jnp.int32),
        score=jnp.full((population_size,), -jnp.inf, jnp.float32),
        survival=survival,
        crowding=crowding,
    )
