"""MOME's repertoire: a Pareto front of at most P solutions in every cell.

Pierrot, Richard, Beguir & Cully 2022, "Multi-objective quality diversity
optimization" (MOME). The cells are those of a grid or a CVT archive (the layout
of a `CellRepertoire`, whose indexing is reused as it is); each cell keeps the
non-dominated set of every solution it was offered, capped at
`pareto_front_max_length` = P. Fitnesses are vectors of M objectives, all
maximised.

Insertion is by batch: for every cell that the batch touches, the cell's front and
the batch's candidates of that cell are merged and their non-dominated members kept
(`qdrl.qd.pareto`). When more than P remain, the rule `overflow` picks which leave:

- "crowding" (default): the members with the smallest crowding distance in the
  merged front leave (the two extremes of each objective always stay), which keeps
  the front spread; MOME's paper asks for fronts that cover the objective space.
- "index": the first P in index order stay (the cell's members, then the batch in
  its order), i.e. new solutions are dropped: what QDax's `MOMERepertoire` does
  (it inserts one solution at a time and truncates by index).

QDax inserts the batch one solution at a time (`lax.scan`); merging a cell's
candidates at once gives the same fronts whenever no front overflows, and costs
one (P + n) x (P + n) dominance test per touched cell instead of n sequential steps.

Sampling (`sample`) draws a filled cell uniformly, then a member of its front
uniformly, as in the paper.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.pareto import crowding_distance, non_dominated
from qdrl.qd.repertoires.cells import (
    CellRepertoire,
    check_batch,
    init_storage,
    sample_filled_indices,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = ["MOMERepertoire", "Overflow", "mome_repertoire"]

Overflow = Literal["crowding", "index"]


@dataclasses.dataclass(frozen=True, eq=False)
class MOMERepertoire:
    """A Pareto front of at most P solutions in each of C cells (MOME).

    Attributes:
      genotypes: pytree, every leaf (C, P, ...); zeros in empty slots.
      fitnesses: (C, P, M) float32, -inf in every objective of an empty slot. A
        cell's members fill its first slots (slots 0 .. count - 1).
      descriptors: (C, P, D) float32, each member's own descriptor.
      cells: the layout: an empty `CellRepertoire` without genotypes whose
        centroids, grid or CVT lookup say which cell a descriptor falls in.
      overflow: which members leave a front that exceeds P ("crowding" or "index").
    """

    genotypes: Genotype
    fitnesses: Array
    descriptors: Array
    cells: CellRepertoire
    overflow: Overflow = "crowding"

    @property
    def num_cells(self) -> int:
        """C (static)."""
        return int(self.fitnesses.shape[0])

    @property
    def pareto_front_max_length(self) -> int:
        """P (static)."""
        return int(self.fitnesses.shape[1])

    @property
    def num_objectives(self) -> int:
        """M (static)."""
        return int(self.fitnesses.shape[2])

    @property
    def centroids(self) -> Array:
        """(C, D) cell centres."""
        return self.cells.centroids

    @property
    def members(self) -> Array:
        """(C, P) bool: slots that hold a solution."""
        return jnp.all(self.fitnesses > -jnp.inf, axis=-1)

    @property
    def front_sizes(self) -> Array:
        """(C,) int32 number of solutions in each cell's front."""
        return jnp.sum(self.members, axis=1, dtype=jnp.int32)

    @property
    def filled(self) -> Array:
        """(C,) bool: cells holding at least one solution."""
        return self.front_sizes > 0

    @property
    def num_filled(self) -> Array:
        """() int32 number of filled cells."""
        return jnp.sum(self.filled, dtype=jnp.int32)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[MOMERepertoire, AddResult]:
        """Offers n candidates (fitnesses (n, M)); every touched cell keeps a non-dominated front.

        Candidates with a non-finite objective or a NaN descriptor are rejected (cell
        -1). Descriptors outside the bounds go to the edge cells, as in
        `CellRepertoire.add`. `AddResult.added` says which candidates are members of
        their cell's front afterwards, `new_cell` which filled an empty cell;
        `improvement` is 1.0 for an added candidate, 0.0 for one that was not and
        -inf for a rejected one (a vector fitness has no scalar gain).
        """
        fitnesses = jnp.asarray(fitnesses, jnp.float32)
        m = self.num_objectives
        if fitnesses.ndim != 2 or fitnesses.shape[1] != m:
            raise ValueError(f"add: fitnesses must have shape (n, {m}), got {fitnesses.shape}")
        n = fitnesses.shape[0]
        storage = jax.tree.map(lambda x: x[0], self.genotypes)
        descriptors, _ = check_batch(
            storage, self.cells.descriptor_dim, genotypes, descriptors,
            jnp.zeros((n,), jnp.float32), "add",
        )
        valid = jnp.all(jnp.isfinite(fitnesses), axis=1) & ~jnp.any(jnp.isnan(descriptors), axis=1)
        cell = jnp.where(valid, self.cells.cell_index(descriptors), -1)
        c, p = self.num_cells, self.pareto_front_max_length
        k = min(n, c)  # cells this batch can touch
        touched = jnp.unique(jnp.where(valid, cell, c), size=k, fill_value=c)
        safe = jnp.clip(touched, 0, c - 1)

        def merge(t: Array, t_safe: Array) -> tuple[Array, Array]:
            """Sources (P,) of cell t's new front (index into its P members then the n candidates,
            P + n for an empty slot) and which of the n candidates are in it."""
            old_f = self.fitnesses[t_safe]
            f = jnp.concatenate([old_f, fitnesses])
            mask = jnp.concatenate([jnp.all(old_f > -jnp.inf, axis=1), (cell == t) & (t < c)])
            front = non_dominated(f, mask)
            if self.overflow == "crowding":
                score = crowding_distance(f, front)
            else:
                score = jnp.zeros((p + n,), jnp.float32)
            # Front members by decreasing score, ties (and "index") in index order.
            order = jnp.lexsort((jnp.arange(p + n), -score, ~front))
            rank = jnp.zeros((p + n,), jnp.int32).at[order].set(jnp.arange(p + n, dtype=jnp.int32))
            kept = front & (rank < p)
            slot = jnp.cumsum(kept) - 1
            sources = jnp.full((p,), p + n, jnp.int32)
            sources = sources.at[jnp.where(kept, slot, p)].set(
                jnp.arange(p + n, dtype=jnp.int32), mode="drop"
            )
            return sources, kept[p:]

        sources, kept = jax.vmap(merge)(touched, safe)  # (k, P), (k, n)
        from_old = sources < p
        from_new = (sources >= p) & (sources < p + n)
        old_idx = jnp.clip(sources, 0, p - 1)
        new_idx = jnp.clip(sources - p, 0, n - 1)

        def pick(old: Array, new: Array) -> Array:
            """(k, P, ...) rows of the new fronts from the old cells' rows and the batch."""
            o = old[safe[:, None], old_idx]
            w = new[new_idx]
            shape = (*sources.shape, *([1] * (o.ndim - 2)))
            zero = jnp.zeros((), o.dtype)
            return jnp.where(
                from_old.reshape(shape), o, jnp.where(from_new.reshape(shape), w.astype(o.dtype), zero)
            )

        new_fit = jnp.where(
            (from_old | from_new)[..., None], pick(self.fitnesses, fitnesses), -jnp.inf
        )
        new = dataclasses.replace(
            self,
            genotypes=jax.tree.map(
                lambda s, g: s.at[touched].set(pick(s, g), mode="drop"), self.genotypes, genotypes
            ),
            fitnesses=self.fitnesses.at[touched].set(new_fit, mode="drop"),
            descriptors=self.descriptors.at[touched].set(
                pick(self.descriptors, descriptors), mode="drop"
            ),
        )
        added = jnp.any(kept, axis=0)
        was_filled = jnp.where(valid, self.filled[jnp.clip(cell, 0)], True)
        result = AddResult(
            added=added,
            new_cell=added & ~was_filled,
            improvement=jnp.where(valid, added.astype(jnp.float32), -jnp.inf),
            cell=cell.astype(jnp.int32),
        )
        return new, result

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` genotypes: a filled cell uniformly, then a member of its front uniformly.

        An empty repertoire gives copies of cell 0's slot 0 (zeros); check `num_filled`.
        """
        cell_key, member_key = jax.random.split(key)
        cells = sample_filled_indices(cell_key, self.filled, num_samples)
        sizes = jnp.maximum(self.front_sizes[cells], 1)
        slots = jax.random.randint(member_key, (num_samples,), 0, sizes)
        return jax.tree.map(lambda x: x[cells, slots], self.genotypes)


jax.tree_util.register_dataclass(
    MOMERepertoire,
    data_fields=["genotypes", "fitnesses", "descriptors", "cells"],
    meta_fields=["overflow"],
)


def mome_repertoire(
    cells: CellRepertoire,
    genotype_example: Genotype,
    num_objectives: int,
    pareto_front_max_length: int,
    overflow: Overflow = "crowding",
) -> MOMERepertoire:
    """An empty MOME repertoire on the cells of `cells` (a `grid_repertoire` or `cvt_repertoire`).

    Args:
      cells: any cell repertoire; only its layout is used (its genotypes are dropped).
      genotype_example: one genotype without batch axis.
      num_objectives: M >= 2.
      pareto_front_max_length: P >= 1, the most solutions a cell's front holds.
      overflow: "crowding" (the paper's spread) or "index" (QDax's truncation).
    """
    if num_objectives < 2:
        raise ValueError(f"num_objectives: expected at least 2, got {num_objectives}")
    if pareto_front_max_length < 1:
        raise ValueError(
            f"pareto_front_max_length: expected a positive integer, got {pareto_front_max_length}"
        )
    if overflow not in ("crowding", "index"):
        raise ValueError(f"overflow: expected 'crowding' or 'index', got {overflow!r}")
    c, p, d = cells.num_cells, pareto_front_max_length, cells.descriptor_dim
    layout = dataclasses.replace(cells, genotypes=None)
    storage = init_storage(genotype_example, c * p)
    return MOMERepertoire(
        genotypes=jax.tree.map(lambda x: x.reshape(c, p, *x.shape[1:]), storage),
        fitnesses=jnp.full((c, p, num_objectives), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((c, p, d), jnp.float32),
        cells=layout,
        overflow=overflow,
    )
