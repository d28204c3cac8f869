"""The categorical archive: each descriptor dimension takes one of a finite list of categories.

As pyribs' `CategoricalArchive` (0.12): a MAP-Elites grid with one bin per category of
each dimension, e.g. `[["A", "B", "C"], ["one", "two"]]` gives 3 x 2 cells. Inside jitted
code a descriptor is the tuple of its category INDICES, stored as float32 like every
other descriptor (`[2.0, 0.0]` is ("C", "one")); the names are static metadata, for
plots and tables (`decode`, `encode`).

Insertion is the grid's (`CellRepertoire._insert`: one elite per cell, replaced only by a
strictly fitter candidate, the fittest of a batch per cell, ties to the lowest batch
index), with one extra rejection: a descriptor that is not a valid category index in
every dimension (not an integer, negative, or >= the number of categories; pyribs raises
on an unknown category) is REJECTED, cell -1, never stored, where a grid would clip it
to an edge cell. CMA-MAE's thresholds come with `with_learning_rate`, as pyribs'
`learning_rate` and `threshold_min`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from qdrl.qd.base import AddResult
from qdrl.qd.repertoires.cells import CellRepertoire, check_batch, grid_repertoire, valid_candidates
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = ["CategoricalArchive", "categorical_archive"]


@dataclasses.dataclass(frozen=True, eq=False)
class CategoricalArchive:
    """One elite per combination of categories.

    Attributes:
      grid: the cells, a MAP-Elites grid of `dims` bins over [-0.5, n - 0.5] per dimension,
        so that the centre of bin k is category index k (heatmaps and exports read it as
        any grid).
      categories: the category names of each dimension (static).
    """

    grid: CellRepertoire
    categories: tuple[tuple[str, ...], ...]

    @property
    def genotypes(self) -> Genotype:
        """The elites' genotypes, leaves (C, ...)."""
        return self.grid.genotypes

    @property
    def fitnesses(self) -> Array:
        """(C,) float32, -inf where empty."""
        return self.grid.fitnesses

    @property
    def descriptors(self) -> Array:
        """(C, D) float32 category indices of the elites."""
        return self.grid.descriptors

    @property
    def centroids(self) -> Array:
        """(C, D) float32: each cell's category indices."""
        return self.grid.centroids

    @property
    def grid_shape(self) -> tuple[int, ...] | None:
        """Categories per dimension, as a grid's shape (static)."""
        return self.grid.grid_shape

    @property
    def low(self) -> tuple[float, ...] | None:
        """-0.5 in every dimension: the grid's lower bounds."""
        return self.grid.low

    @property
    def high(self) -> tuple[float, ...] | None:
        """n - 0.5 per dimension of n categories: the grid's upper bounds."""
        return self.grid.high

    @property
    def dims(self) -> tuple[int, ...]:
        """Categories per dimension (static)."""
        return tuple(len(names) for names in self.categories)

    @property
    def thresholds(self) -> Array | None:
        """(C,) CMA-MAE thresholds, when the archive has them (`with_learning_rate`)."""
        return self.grid.thresholds

    @property
    def threshold_min(self) -> float:
        """CMA-MAE's initial threshold (-inf without thresholds)."""
        return self.grid.threshold_min

    @property
    def num_cells(self) -> int:
        """Number of cells C = prod(dims) (static)."""
        return self.grid.num_cells

    @property
    def descriptor_dim(self) -> int:
        """Descriptor dimension D (static)."""
        return len(self.categories)

    @property
    def filled(self) -> Array:
        """(C,) bool, True where a cell holds an elite."""
        return self.grid.filled

    @property
    def num_filled(self) -> Array:
        """() int32, number of filled cells."""
        return self.grid.num_filled

    @property
    def is_empty(self) -> Array:
        """() bool, True when no cell is filled (then `sample` returns NaN genotypes)."""
        return self.grid.is_empty

    def cell_index(self, descriptors: Descriptor) -> Array:
        """(n,) int32 row-major cell of each descriptor (n, D) of category indices; -1 where a
        row is not a valid index in every dimension (an integer in [0, n_i), so NaN and
        +-inf too)."""
        points = jnp.asarray(descriptors, jnp.float32)
        counts = jnp.asarray(self.dims, jnp.float32)
        ok = jnp.all((points == jnp.floor(points)) & (points >= 0.0) & (points < counts), axis=-1)
        index = jnp.where(ok[:, None], points, 0.0).astype(jnp.int32)
        cell = jnp.ravel_multi_index(
            tuple(index[:, i] for i in range(self.descriptor_dim)), self.dims, mode="clip"
        )
        return jnp.where(ok, cell, -1).astype(jnp.int32)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[CategoricalArchive, AddResult]:
        """Offers a batch of n candidates; the grid's rules (`CellRepertoire.add`), except that
        a descriptor that is not a valid category index is rejected (cell -1), not clipped.

        Args:
          genotypes: pytree whose leaves have a leading axis n and otherwise match the
            archive's genotype (`None` for an archive without genotypes).
          descriptors: (n, D) category indices as floats.
          fitnesses: (n,) fitnesses; NaN marks a failed evaluation.

        Returns:
          The new archive and the grid's `AddResult`.
        """
        descriptors, fitnesses = check_batch(
            self.grid.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add"
        )
        cell = jnp.where(valid_candidates(descriptors, fitnesses), self.cell_index(descriptors), -1)
        grid, result = self.grid._insert(genotypes, descriptors, fitnesses, cell)
        return dataclasses.replace(self, grid=grid), result

    def with_learning_rate(
        self, learning_rate: float, threshold_min: float = -math.inf
    ) -> CategoricalArchive:
        """This (empty) archive as CMA-MAE's: see `CellRepertoire.with_learning_rate`."""
        return dataclasses.replace(self, grid=self.grid.with_learning_rate(learning_rate, threshold_min))

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` genotypes drawn uniformly, with replacement, among the filled cells.

        An EMPTY archive gives NaN genotypes (`cells.sample_filled`); check `is_empty`.
        """
        return self.grid.sample(key, num_samples)

    def encode(self, names: Sequence[Sequence[str]]) -> np.ndarray:
        """(n, D) float32 descriptors of n rows of category names; KeyError names an unknown one."""
        lookup = [{name: k for k, name in enumerate(dim)} for dim in self.categories]
        rows = [list(row) for row in names]
        for row in rows:
            if len(row) != self.descriptor_dim:
                raise ValueError(f"encode: expected {self.descriptor_dim} names per row, got {row}")
        out = np.zeros((len(rows), self.descriptor_dim), np.float32)
        for r, row in enumerate(rows):
            for i, name in enumerate(row):
                if name not in lookup[i]:
                    raise KeyError(
                        f"encode: {name!r} is not a category of dimension {i}; expected one of "
                        f"{list(self.categories[i])}"
                    )
                out[r, i] = lookup[i][name]
        return out

    def decode(self, descriptors: ArrayLike) -> list[tuple[str, ...] | None]:
        """The category names of each descriptor row (n, D) (host side); None for a row that
        is not a valid index (the rows `add` rejects)."""
        points = np.asarray(descriptors, np.float64)
        cells = np.asarray(self.cell_index(jnp.asarray(points, jnp.float32)))
        return [
            None if c < 0 else tuple(self.categories[i][int(v)] for i, v in enumerate(row))
            for row, c in zip(points, cells, strict=True)
        ]


jax.tree_util.register_dataclass(CategoricalArchive, data_fields=["grid"], meta_fields=["categories"])


def categorical_archive(
    genotype_example: Genotype, categories: Sequence[Sequence[str]]
) -> CategoricalArchive:
    """An empty categorical archive (pyribs' `CategoricalArchive`).

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype). Only leaf shapes and dtypes are used.
      categories: the names of the categories of each descriptor dimension, e.g.
        `[["A", "B", "C"], ["one", "two"]]`; D = len(categories), names unique within
        a dimension.

    Returns:
      A `CategoricalArchive` of prod(len(c) for c in categories) empty cells.
    """
    if isinstance(categories, str) or not categories:
        raise ValueError(f"categories: expected a non-empty list of lists of names, got {categories!r}")
    names: list[tuple[str, ...]] = []
    for i, dim in enumerate(categories):
        if isinstance(dim, str) or not dim:
            raise ValueError(f"categories[{i}]: expected a non-empty list of names, got {dim!r}")
        row = tuple(str(name) for name in dim)
        if len(set(row)) != len(row):
            raise ValueError(f"categories[{i}]: names must be unique, got {list(row)}")
        names.append(row)
    dims = tuple(len(row) for row in names)
    grid = grid_repertoire(
        genotype_example, dims, low=[-0.5] * len(dims), high=[n - 0.5 for n in dims]
    )
    return CategoricalArchive(grid=grid, categories=tuple(names))
