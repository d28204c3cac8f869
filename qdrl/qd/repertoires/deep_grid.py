"""Deep-Grid: each cell keeps a population of up to `depth` solutions, not one elite.

Flageat & Cully 2020, "Fast and stable MAP-Elites in noisy domains using deep grids" (ALIFE;
the rules of its code, `Deep_disordered_grid` and `Deep_disordered_proportional`, depth 50 in
its experiments). In a noisy task one lucky evaluation makes an elite; a deep grid keeps
every recent solution of a cell instead, so the solutions that stay in a cell are those whose
offspring keep landing there:

- insertion: every candidate with a finite fitness and descriptor enters the cell of its
  (noisy) descriptor: into an empty slot while the cell has one, else in place of one of the
  cell's solutions drawn uniformly. No fitness comparison: a solution lives in the grid until
  it is drawn for replacement, and a genotype whose evaluations land in several cells
  spreads its offspring over them. Of the candidates of one batch that reach one cell, the
  first `depth` (in batch order) take distinct slots, empty ones first, then filled ones in
  a random order; the rest are dropped (the batched form of the paper's one-at-a-time rule,
  as the Uncertain-QD code of Flageat & Cully 2023 places them).
- parents: a filled cell drawn uniformly, then one of its solutions with probability
  proportional to its fitness minus the cell's worst fitness (uniformly when they are all
  equal), the paper's in-cell selector.
- the cell's reported elite, which metrics, plots, exports and re-evaluation read as
  `genotypes`, `fitnesses` and `descriptors` (C, ...), is its fittest solution (the paper's
  `best_indiv`; the lowest slot of equals).

The random replacements draw from a key kept in the repertoire (split at every insertion),
so a run resumed from a checkpoint replaces the same solutions. The repertoire is a
`CellRepertoire` whose top layer is the reported elites; its `add` is the plain best-per-cell
insertion into that layer (what `qdrl.qd.reevaluate` builds the corrected repertoire with);
the QD loop offers batches through `add_evaluation` (`qdrl.qd.base.add_evaluation`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.repertoires.cells import (
    CellRepertoire,
    check_batch,
    init_storage,
    sample_filled_indices,
    valid_candidates,
)
from qdrl.qd.repertoires.mels import register_cells_subclass
from qdrl.types import Array, Genotype, PRNGKey

__all__ = ["DeepGrid", "deep_grid", "in_cell_weights"]


def in_cell_weights(fitnesses: Array) -> Array:
    """(..., depth) selection weights of a cell's solutions (fitnesses -inf in empty slots):
    fitness minus the cell's worst, normalised; uniform over the solutions when these are all
    0 (one solution, or equal fitnesses); all 0 for an empty cell."""
    occupied = fitnesses > -jnp.inf
    worst = jnp.min(jnp.where(occupied, fitnesses, jnp.inf), axis=-1, keepdims=True)
    above = jnp.where(occupied, fitnesses - worst, 0.0)
    total = jnp.sum(above, axis=-1, keepdims=True)
    count = jnp.sum(occupied, axis=-1, keepdims=True)
    uniform = occupied / jnp.maximum(count, 1)
    return jnp.where(total > 0, above / jnp.where(total > 0, total, 1.0), uniform)


def _batch_ranks(segment: Array, num_segments: int) -> Array:
    """(n,) each candidate's rank among the earlier candidates of its segment (0 for the first)."""
    n = segment.shape[0]
    order = jnp.argsort(segment, stable=True)
    counts = jnp.zeros((num_segments,), jnp.int32).at[segment].add(1)
    starts = jnp.cumsum(counts) - counts
    sorted_rank = jnp.arange(n, dtype=jnp.int32) - starts[segment[order]]
    return jnp.zeros((n,), jnp.int32).at[order].set(sorted_rank)


@dataclasses.dataclass(frozen=True, eq=False)
class DeepGrid(CellRepertoire):
    """A `CellRepertoire` (its fields: the reported elites, the fittest solution of each cell)
    over the populations of the cells.

    Attributes (beside CellRepertoire's):
      deep_genotypes: every leaf (C, depth, ...), the stored solutions (zeros in empty slots).
      deep_fitnesses: (C, depth) float32, -inf in empty slots.
      deep_descriptors: (C, depth, D) float32.
      key: the PRNG key of the random replacements.
    """

    deep_genotypes: Genotype = None
    deep_fitnesses: Array = dataclasses.field(default_factory=lambda: jnp.zeros((0, 1), jnp.float32))
    deep_descriptors: Array = dataclasses.field(default_factory=lambda: jnp.zeros((0, 1, 1), jnp.float32))
    key: PRNGKey = dataclasses.field(default_factory=lambda: jax.random.PRNGKey(0))

    @property
    def depth(self) -> int:
        """Solutions a cell keeps at most (static)."""
        return int(self.deep_fitnesses.shape[1])

    def add_evaluation(self, genotypes: Genotype, evaluation: Evaluation) -> tuple[DeepGrid, AddResult]:
        """Every valid candidate enters the cell of its descriptor by Deep-Grid's rule (module
        docstring); `AddResult.added` marks those that took a slot."""
        descriptors, fitnesses = check_batch(
            self.genotypes, self.descriptor_dim, genotypes, evaluation.descriptors, evaluation.fitnesses,
            "add_evaluation",
        )
        num_cells, depth = self.num_cells, self.depth
        valid = valid_candidates(descriptors, fitnesses)
        cell = jnp.where(valid, self.cell_index(descriptors), -1).astype(jnp.int32)
        segment = jnp.where(valid, cell, num_cells)
        rank = _batch_ranks(segment, num_cells + 1)
        placed = valid & (rank < depth)
        key, order_key = jax.random.split(self.key)
        # Each candidate's cell's slots in the order they are taken: empty ones first (slot
        # order), then filled ones in a random order drawn once per cell (so candidates of one
        # cell share it and take distinct slots).
        safe = jnp.clip(cell, 0)
        cell_fit = self.deep_fitnesses[safe]  # (n, depth)
        noise = jax.vmap(lambda c: jax.random.uniform(jax.random.fold_in(order_key, c), (depth,)))(safe)
        priority = jnp.where(cell_fit > -jnp.inf, 1.0 + noise, jnp.arange(depth) / depth)
        slots = jnp.argsort(priority, axis=1)
        slot = jnp.take_along_axis(slots, jnp.clip(rank, 0, depth - 1)[:, None], axis=1)[:, 0]
        row = jnp.where(placed, cell, num_cells)  # out of range: dropped
        deep_genotypes = jax.tree.map(
            lambda s, g: s.at[row, slot].set(g.astype(s.dtype), mode="drop"), self.deep_genotypes, genotypes
        )
        deep_fitnesses = self.deep_fitnesses.at[row, slot].set(fitnesses, mode="drop")
        deep_descriptors = self.deep_descriptors.at[row, slot].set(descriptors, mode="drop")
        best = jnp.argmax(deep_fitnesses, axis=1)  # first of equals; 0 in an empty cell
        cells = jnp.arange(num_cells)
        new = dataclasses.replace(
            self,
            genotypes=jax.tree.map(lambda s: s[cells, best], deep_genotypes),
            fitnesses=deep_fitnesses[cells, best],
            descriptors=deep_descriptors[cells, best],
            deep_genotypes=deep_genotypes,
            deep_fitnesses=deep_fitnesses,
            deep_descriptors=deep_descriptors,
            key=key,
        )
        old_fit = jnp.where(valid, self.fitnesses[safe], -jnp.inf)
        old_filled = old_fit > -jnp.inf
        return new, AddResult(
            added=placed,
            new_cell=placed & ~old_filled,
            improvement=jnp.where(valid, jnp.where(old_filled, fitnesses - old_fit, fitnesses), -jnp.inf).astype(
                jnp.float32
            ),
            cell=cell,
        )

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` parents: a filled cell drawn uniformly, then one of its solutions with
        probability `in_cell_weights` (the paper's fitness-proportional in-cell selector).

        An EMPTY repertoire gives NaN in every floating-point leaf (as `CellRepertoire.sample`).
        """
        cell_key, slot_key = jax.random.split(key)
        cells = sample_filled_indices(cell_key, self.filled, num_samples)
        weights = in_cell_weights(self.deep_fitnesses[cells])  # (num_samples, depth)
        logits = jnp.where(weights > 0, jnp.log(jnp.where(weights > 0, weights, 1.0)), -jnp.inf)
        slot = jax.random.categorical(slot_key, logits, axis=-1)
        empty = self.is_empty

        def take(store: Array) -> Array:
            rows = store[cells, slot]
            if jnp.issubdtype(rows.dtype, jnp.floating):
                rows = jnp.where(empty, jnp.asarray(jnp.nan, rows.dtype), rows)
            return rows

        return jax.tree.map(take, self.deep_genotypes)

    def log_metrics(self) -> dict[str, Array]:
        """How many solutions the cells hold in all, logged beside the QD metrics."""
        return {"deep_solutions": jnp.sum(self.deep_fitnesses > -jnp.inf, dtype=jnp.int32)}


register_cells_subclass(DeepGrid)


def deep_grid(cells: CellRepertoire, depth: int = 50, seed: int = 0) -> DeepGrid:
    """An empty Deep-Grid of `depth` solutions per cell on the cells (grid or CVT) of the empty
    `cells`; `seed` seeds the random replacements."""
    if not isinstance(depth, int) or depth < 1:
        raise ValueError(f"deep_grid.depth: expected a positive integer, got {depth!r}")
    if not isinstance(cells, CellRepertoire) or cells.thresholds is not None:
        raise ValueError(
            "repertoire.kind: Deep-Grid keeps its solutions on a grid or CVT repertoire without CMA-MAE's "
            f"thresholds, got {type(cells).__name__}"
        )
    num_cells, dim = cells.num_cells, cells.descriptor_dim
    example = jax.tree.map(lambda x: jax.ShapeDtypeStruct((depth, *x.shape[1:]), x.dtype), cells.genotypes)
    fields = {f.name: getattr(cells, f.name) for f in dataclasses.fields(CellRepertoire)}
    return DeepGrid(
        **fields,
        deep_genotypes=init_storage(example, num_cells),
        deep_fitnesses=jnp.full((num_cells, depth), -jnp.inf, jnp.float32),
        deep_descriptors=jnp.zeros((num_cells, depth, dim), jnp.float32),
        key=jax.random.PRNGKey(seed),
    )
