"""The sliding-boundaries archive: a grid whose bin edges follow the recent descriptors.

Fontaine, Lee, Soros, de Mesentier Silva, Togelius & Hoover 2019, "Mapping Hearthstone
Deck Spaces through MAP-Elites with Sliding Boundaries" (GECCO). The descriptor box
starts cut into `dims` equal bins per dimension, as a MAP-Elites grid. The archive keeps
a buffer of the `buffer_capacity` most recent candidates; every `remap_frequency`
candidates it REMAPS: the edges of dimension i move to percentiles of the buffered
descriptors (edge j of `dims[i]` is the buffer's sorted value of rank
`floor(j * size / dims[i])`, the last edge its largest value), the archive is emptied,
and its former elites then every buffered candidate are offered again to the new grid.
Where descriptors crowd, cells get narrow; the archive's resolution follows the
distribution the search actually reaches.

The rules are pyribs' `SlidingBoundariesArchive` (0.12), which inserts candidates one at
a time; here a batch is inserted at once, with the same outcome:

- a candidate whose fitness or descriptor is not finite is rejected (cell -1); it
  neither counts towards `remap_frequency` nor enters the buffer (pyribs raises);
- the k-th finite candidate ever offered (k = 1, 2, ...) enters the buffer, evicting the
  oldest when full; when k is a multiple of `remap_frequency` it triggers a remap
  instead of being inserted itself: the edges move, the former elites (in cell order)
  then the buffer (oldest first, the trigger last) are re-inserted;
- a candidate's cell along dimension i is the number of inner edges at or below
  `d_i + epsilon` (the outer edges are the grid's bounds; descriptors outside them go
  to the edge cells, as pyribs' clipping does);
- insertion is MAP-Elites' (`CellRepertoire`'s): one elite per cell, replaced only by a
  strictly fitter candidate; within a batch, between two remaps, the fittest candidate
  of a cell wins and ties go to the earlier one, which is what inserting them one by one
  gives.

A batch that crosses several multiples of `remap_frequency` remaps several times, in
order: candidates before a remap are inserted into the grid as it was, those after into
the remapped one. The `AddResult` carries pyribs' one-at-a-time judgement in `status` (0
not added, 1 improved, 2 new cell) and `value`: each candidate against its cell's elite
at its turn, i.e. the best of the elite before the batch and the earlier candidates of
the batch in that cell (the trigger: against the re-inserted archive), so emitters rank
candidates as pyribs' archive would. `added`, `new_cell`, `improvement` and `cell` are
those of the insertion the candidate took part in, as `CellRepertoire.add` gives them
(`added`: the elite of its cell once that insertion is done); across a remap `cell`
numbers refer to different edges.

Memory: beside the C elites the archive stores the buffer, `buffer_capacity` genotypes
with their descriptors and fitnesses (1000 policies of 10^4 float32 parameters: 40 MB);
a remap re-inserts C + buffer_capacity rows, so it briefly holds that many genotypes
once more.

Typical use::

    archive = sliding_boundaries_archive(example_params, dims=(20, 20), low=0.0, high=1.0)
    archive, result = archive.add(genotypes, descriptors, fitnesses)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.base import AddResult
from qdrl.qd.repertoires.cells import (
    CellRepertoire,
    as_bounds,
    check_batch,
    cvt_repertoire,
    grid_centroids,
    init_storage,
    valid_candidates,
    write_rows,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = ["SlidingBoundariesArchive", "sliding_boundaries_archive"]

NOT_ADDED, IMPROVED, NEW = 0, 1, 2  # pyribs' add statuses


@dataclasses.dataclass(frozen=True, eq=False)
class SlidingBoundariesArchive:
    """A grid with per-dimension edges re-placed at percentiles of recent descriptors.

    Attributes:
      cells: the prod(dims) cells and their elites, in row-major grid order; its
        `centroids` are the cells' midpoints under the current edges. Cells are found
        through `boundaries` (`cell_index`), never through `cells.cell_index`.
      boundaries: (D, max(dims) + 1) float32; row i holds the dims[i] + 1 edges of
        dimension i in increasing order, then +inf padding.
      buffer_genotypes, buffer_descriptors, buffer_fitnesses: the ring buffer of the
        `buffer_capacity` most recent finite candidates; the k-th (from 0) is in slot
        k % buffer_capacity.
      count: () int32, finite candidates offered so far.
      dims: bins per dimension (static).
      remap_frequency: candidates between remaps (static).
      epsilon: added to descriptors before binning, as pyribs (static).
    """

    cells: CellRepertoire
    boundaries: Array
    buffer_genotypes: Genotype
    buffer_descriptors: Array
    buffer_fitnesses: Array
    count: Array
    dims: tuple[int, ...]
    remap_frequency: int
    epsilon: float

    @property
    def genotypes(self) -> Genotype:
        """The elites' genotypes, leaves (C, ...)."""
        return self.cells.genotypes

    @property
    def fitnesses(self) -> Array:
        """(C,) float32, -inf where empty."""
        return self.cells.fitnesses

    @property
    def descriptors(self) -> Array:
        """(C, D) float32 descriptors of the elites (stale where empty)."""
        return self.cells.descriptors

    @property
    def centroids(self) -> Array:
        """(C, D) float32 midpoints of the cells under the current edges."""
        return self.cells.centroids

    @property
    def num_cells(self) -> int:
        """Number of cells C = prod(dims) (static)."""
        return self.cells.num_cells

    @property
    def descriptor_dim(self) -> int:
        """Descriptor dimension D (static)."""
        return len(self.dims)

    @property
    def buffer_capacity(self) -> int:
        """Candidates the buffer holds (static)."""
        return int(self.buffer_fitnesses.shape[0])

    @property
    def buffer_size(self) -> Array:
        """() int32, candidates in the buffer now."""
        return jnp.minimum(self.count, self.buffer_capacity)

    @property
    def lower_bounds(self) -> Array:
        """(D,) float32, the lowest edge of each dimension."""
        return self.boundaries[:, 0]

    @property
    def upper_bounds(self) -> Array:
        """(D,) float32, the highest edge of each dimension."""
        return self.boundaries[jnp.arange(self.descriptor_dim), jnp.asarray(self.dims)]

    @property
    def filled(self) -> Array:
        """(C,) bool, True where a cell holds an elite."""
        return self.cells.filled

    @property
    def num_filled(self) -> Array:
        """() int32, number of filled cells."""
        return self.cells.num_filled

    @property
    def is_empty(self) -> Array:
        """() bool, True when no cell is filled (then `sample` returns NaN genotypes)."""
        return self.cells.is_empty

    def cell_index(self, descriptors: Descriptor) -> Array:
        """(n,) int32 cell of each descriptor (n, D) under the current edges.

        Along dimension i the bin is the number of inner edges (1 .. dims[i] - 1) at or
        below `d_i + epsilon`: a descriptor on an edge goes to the cell above it, one
        outside the bounds to the edge cell. Non-finite rows get an arbitrary cell;
        `add` rejects them first.
        """
        points = jnp.asarray(descriptors, jnp.float32) + self.epsilon
        widest = self.boundaries.shape[1] - 1
        inner = self.boundaries[:, 1:widest]  # (D, max(dims) - 1)
        # Row i has dims[i] - 1 inner edges; the static mask drops the others (its upper bound).
        real = jnp.asarray(np.arange(1, widest)[None, :] < np.asarray(self.dims)[:, None])
        bins = jnp.sum(real & (inner[None] <= points[:, :, None]), axis=-1, dtype=jnp.int32)
        return jnp.ravel_multi_index(
            tuple(bins[:, i] for i in range(self.descriptor_dim)), self.dims, mode="clip"
        ).astype(jnp.int32)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[SlidingBoundariesArchive, AddResult]:
        """Offers a batch of n candidates, remapping wherever the count of finite candidates
        reaches a multiple of `remap_frequency` (see the module docstring for the rules).

        Args:
          genotypes: pytree whose leaves have a leading axis n and otherwise match the
            archive's genotype (`None` for an archive without genotypes).
          descriptors: (n, D) descriptors.
          fitnesses: (n,) fitnesses; NaN marks a failed evaluation.

        Returns:
          The new archive and an `AddResult`: `status` (0 not added, 1 improved, 2 new)
          and `value` (fitness minus the cell's elite at the candidate's turn, the fitness
          itself in an empty cell, -inf when rejected), as pyribs' one-at-a-time add;
          `added`, `new_cell`, `improvement` and `cell` (under the edges of that moment, -1
          when rejected) of the insertion the candidate took part in, as
          `CellRepertoire.add` gives them.
        """
        descriptors, fitnesses = check_batch(
            self.cells.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add"
        )
        n = fitnesses.shape[0]
        result = AddResult(
            added=jnp.zeros((n,), bool),
            new_cell=jnp.zeros((n,), bool),
            improvement=jnp.full((n,), -jnp.inf, jnp.float32),
            cell=jnp.full((n,), -1, jnp.int32),
            status=jnp.full((n,), NOT_ADDED, jnp.int32),
            value=jnp.full((n,), -jnp.inf, jnp.float32),
        )
        if n == 0:
            return self, result
        valid = valid_candidates(descriptors, fitnesses)
        period = self.remap_frequency
        position = self.count + jnp.cumsum(valid, dtype=jnp.int32) - 1  # among finite ones ever
        # A candidate's segment: the remaps this batch does before it; a trigger closes its segment.
        segment = jnp.where(valid, position // period - self.count // period, -1)
        trigger = valid & ((position + 1) % period == 0)

        def step(
            carry: tuple[SlidingBoundariesArchive, AddResult], s: Array
        ) -> tuple[tuple[SlidingBoundariesArchive, AddResult], None]:
            archive, result = carry
            member = segment == s
            now = member & ~trigger
            cell = jnp.where(now, archive.cell_index(descriptors), -1)
            cells, inserted = archive.cells._insert(genotypes, descriptors, fitnesses, cell)
            status, value = _in_turn(archive.cells.fitnesses, cell, fitnesses)
            result = _merge(result, inserted._replace(status=status, value=value), now)
            archive = dataclasses.replace(archive, cells=cells)._push(
                genotypes, descriptors, fitnesses, member
            )
            fires = member & trigger
            which = jnp.argmax(fires)  # the segment's trigger, its last member

            def remap() -> tuple[SlidingBoundariesArchive, AddResult]:
                remapped, last = archive._remap()
                return remapped, _merge(result, _with_status(last), jnp.arange(n) == which, broadcast=True)

            return jax.lax.cond(jnp.any(fires), remap, lambda: (archive, result)), None

        # A batch of n crosses at most (n - 1) // period + 1 multiples of `period`.
        (archive, result), _ = jax.lax.scan(
            step, (self, result), jnp.arange((n - 1) // period + 2, dtype=jnp.int32)
        )
        return archive, result

    def _push(
        self, genotypes: Genotype, descriptors: Array, fitnesses: Array, member: Array
    ) -> SlidingBoundariesArchive:
        """The archive with the `member` candidates appended to the buffer, in batch order."""
        capacity = self.buffer_capacity
        rank = jnp.cumsum(member, dtype=jnp.int32) - 1
        total = jnp.sum(member, dtype=jnp.int32)
        # Only the last `capacity` members survive; writing only them keeps the slots unique.
        keep = member & (total - rank <= capacity)
        slot = jnp.where(keep, (self.count + rank) % capacity, capacity)
        return dataclasses.replace(
            self,
            buffer_genotypes=write_rows(self.buffer_genotypes, slot, genotypes),
            buffer_descriptors=self.buffer_descriptors.at[slot].set(descriptors, mode="drop"),
            buffer_fitnesses=self.buffer_fitnesses.at[slot].set(fitnesses, mode="drop"),
            count=self.count + total,
        )

    def _remap(self) -> tuple[SlidingBoundariesArchive, AddResult]:
        """New edges from the buffer, then the former elites and the buffer re-inserted; the
        newest buffered candidate (the trigger) last and alone, for its `AddResult` (1 row)."""
        capacity, size = self.buffer_capacity, self.buffer_size
        # Slots from the oldest to the newest; when the buffer is not full the empty
        # slots come first and are rejected below.
        order = (self.count + jnp.arange(capacity, dtype=jnp.int32)) % capacity
        stored = jnp.arange(capacity) < size
        boundaries = self._percentile_edges(stored)
        cells = dataclasses.replace(
            self.cells,
            fitnesses=jnp.full_like(self.cells.fitnesses, -jnp.inf),
            centroids=_midpoints(boundaries, self.dims),
        )
        archive = dataclasses.replace(self, cells=cells, boundaries=boundaries)
        older = order[:-1]
        rows = jax.tree_util.tree_map(
            lambda elites, buffered: jnp.concatenate([elites, buffered[older]]),
            self.cells.genotypes,
            self.buffer_genotypes,
        )
        descriptors = jnp.concatenate([self.cells.descriptors, self.buffer_descriptors[older]])
        fitnesses = jnp.concatenate([self.cells.fitnesses, self.buffer_fitnesses[older]])
        offered = jnp.concatenate([self.cells.filled, stored[older]])
        cell = jnp.where(offered, archive.cell_index(descriptors), -1)
        cells, _ = cells._insert(rows, descriptors, fitnesses, cell)
        newest = order[-1:]
        last_descriptor = self.buffer_descriptors[newest]
        cells, last = cells._insert(
            jax.tree_util.tree_map(lambda b: b[newest], self.buffer_genotypes),
            last_descriptor,
            self.buffer_fitnesses[newest],
            archive.cell_index(last_descriptor),
        )
        return dataclasses.replace(archive, cells=cells), last

    def _percentile_edges(self, stored: Array) -> Array:
        """(D, max(dims) + 1) edges at the percentiles of the buffered descriptors."""
        size = self.buffer_size
        ranked = jnp.sort(jnp.where(stored[:, None], self.buffer_descriptors, jnp.inf), axis=0)
        dims = np.asarray(self.dims)
        j = np.arange(self.boundaries.shape[1])[None, :]
        # Edge j < dims[i]: the value of rank floor(j * size / dims[i]); edge dims[i]: the largest.
        rank = jnp.where(
            jnp.asarray(j < dims[:, None]), (jnp.asarray(j) * size) // jnp.asarray(dims)[:, None], size - 1
        )
        edges = jnp.take_along_axis(ranked.T, rank, axis=1)
        return jnp.where(jnp.asarray(j <= dims[:, None]), edges, jnp.inf)

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` genotypes drawn uniformly, with replacement, among the filled cells.

        An EMPTY archive gives NaN genotypes (`cells.sample_filled`); check `is_empty`.
        """
        return self.cells.sample(key, num_samples)


jax.tree_util.register_dataclass(
    SlidingBoundariesArchive,
    data_fields=[
        "cells", "boundaries", "buffer_genotypes", "buffer_descriptors", "buffer_fitnesses", "count",
    ],
    meta_fields=["dims", "remap_frequency", "epsilon"],
)


def _with_status(result: AddResult) -> AddResult:
    """`result` of ONE candidate with pyribs' status (0 not added, 1 improved, 2 new) and value
    (the improvement): alone, its insertion is its turn."""
    status = jnp.where(result.added, jnp.where(result.new_cell, NEW, IMPROVED), NOT_ADDED)
    return result._replace(status=status.astype(jnp.int32), value=result.improvement)


def _in_turn(elites: Array, cell: Array, fitnesses: Array) -> tuple[Array, Array]:
    """pyribs' (status, value) of candidates inserted one at a time in batch order into cells
    whose elites have `elites` (C,) fitnesses; `cell` -1 marks the ones not inserted.

    A candidate's elite at its turn is the best of its cell's elite and of the earlier
    candidates in its cell: an exclusive running max per cell, over the candidates grouped by
    cell (a stable sort keeps batch order within a cell).
    """
    n, num_cells = cell.shape[0], elites.shape[0]
    valid = cell >= 0
    fit = jnp.where(valid, fitnesses, -jnp.inf)
    order = jnp.argsort(jnp.where(valid, cell, num_cells), stable=True)
    grouped = jnp.where(valid, cell, num_cells)[order]
    first = jnp.concatenate([jnp.ones((1,), bool), grouped[1:] != grouped[:-1]])

    def running_max(a: tuple[Array, Array], b: tuple[Array, Array]) -> tuple[Array, Array]:
        # A segmented max: a group starting within `b` does not see `a`.
        return a[0] | b[0], jnp.where(b[0], b[1], jnp.maximum(a[1], b[1]))

    _, upto = jax.lax.associative_scan(running_max, (first, fit[order]))
    shifted = jnp.concatenate([jnp.full((1,), -jnp.inf), upto[:-1]])
    earlier = jnp.full((n,), -jnp.inf).at[order].set(jnp.where(first, -jnp.inf, shifted))
    best = jnp.maximum(earlier, jnp.where(valid, elites[jnp.clip(cell, 0)], -jnp.inf))
    status = jnp.where(best == -jnp.inf, NEW, jnp.where(fit > best, IMPROVED, NOT_ADDED))
    value = jnp.where(best == -jnp.inf, fit, fit - best)
    return (
        jnp.where(valid, status, NOT_ADDED).astype(jnp.int32),
        jnp.where(valid, value, -jnp.inf).astype(jnp.float32),
    )


def _merge(result: AddResult, update: AddResult, where: Array, broadcast: bool = False) -> AddResult:
    """`result` with the rows of `update` (every field set) where `where`; a 1-row `update`
    is broadcast."""

    def pick(old: Array | None, new: Array | None) -> Array:
        assert old is not None and new is not None
        return jnp.where(where, new[0] if broadcast else new, old)

    return AddResult(
        added=pick(result.added, update.added),
        new_cell=pick(result.new_cell, update.new_cell),
        improvement=pick(result.improvement, update.improvement),
        cell=pick(result.cell, update.cell),
        status=pick(result.status, update.status),
        value=pick(result.value, update.value),
    )


def _midpoints(boundaries: Array, dims: tuple[int, ...]) -> Array:
    """(prod(dims), D) midpoints of the cells, in row-major cell order."""
    axes = [(boundaries[i, :n] + boundaries[i, 1 : n + 1]) / 2.0 for i, n in enumerate(dims)]
    mesh = jnp.meshgrid(*axes, indexing="ij")
    return jnp.stack([m.reshape(-1) for m in mesh], axis=-1).astype(jnp.float32)


def sliding_boundaries_archive(
    genotype_example: Genotype,
    dims: Sequence[int],
    low: float | Sequence[float],
    high: float | Sequence[float],
    remap_frequency: int = 100,
    buffer_capacity: int = 1000,
    epsilon: float = 1e-6,
) -> SlidingBoundariesArchive:
    """An empty sliding-boundaries archive (Fontaine et al. 2019), edges equally spaced.

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype). Only leaf shapes and dtypes are used.
      dims: bins per descriptor dimension, e.g. `(20, 20)`; D = len(dims).
      low, high: the initial descriptor bounds, scalars or D values, `low < high`.
      remap_frequency: finite candidates between remaps (pyribs' default, 100).
      buffer_capacity: recent candidates kept for the percentiles and re-inserted at
        each remap (pyribs' default, 1000); stores that many genotypes.
      epsilon: added to descriptors before binning (pyribs' default, 1e-6).

    Returns:
      A `SlidingBoundariesArchive` of prod(dims) empty cells.
    """
    shape = tuple(int(n) for n in dims)
    if not shape or any(n <= 0 for n in shape):
        raise ValueError(f"dims must be a non-empty tuple of positive ints, got {dims}")
    lo = as_bounds(low, len(shape), "low")
    hi = as_bounds(high, len(shape), "high")
    if any(h <= a for a, h in zip(lo, hi, strict=True)):
        raise ValueError(f"need low < high in every dimension, got low={lo}, high={hi}")
    for name, value in (("remap_frequency", remap_frequency), ("buffer_capacity", buffer_capacity)):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name}: expected a positive int, got {value!r}")
    if not (isinstance(epsilon, int | float) and epsilon >= 0.0):
        raise ValueError(f"epsilon: expected a number >= 0, got {epsilon!r}")
    edges = np.full((len(shape), max(shape) + 1), np.inf, np.float32)
    for i, (n, a, h) in enumerate(zip(shape, lo, hi, strict=True)):
        edges[i, : n + 1] = np.linspace(a, h, n + 1)
    cells = cvt_repertoire(genotype_example, grid_centroids(shape, lo, hi))
    return SlidingBoundariesArchive(
        cells=cells,
        boundaries=jnp.asarray(edges),
        buffer_genotypes=init_storage(genotype_example, buffer_capacity),
        buffer_descriptors=jnp.zeros((buffer_capacity, len(shape)), jnp.float32),
        buffer_fitnesses=jnp.zeros((buffer_capacity,), jnp.float32),
        count=jnp.zeros((), jnp.int32),
        dims=shape,
        remap_frequency=remap_frequency,
        epsilon=float(epsilon),
    )
