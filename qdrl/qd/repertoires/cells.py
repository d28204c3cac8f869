"""Cell repertoires: one elite per cell, cells from a regular grid or from CVT centroids.

One implementation serves both containers of the QDax table:

- the MAP-Elites grid (Mouret & Clune 2015, "Illuminating search spaces by mapping
  elites"): the descriptor box `[low, high]` is cut into `grid_shape` equal bins and
  a descriptor's cell is found by DIRECT indexing (per-dimension `floor`, then
  `ravel_multi_index`), never by a nearest-centroid search;
- the CVT archive (Vassiliades et al. 2018, "Using centroidal Voronoi tessellations
  to scale up the multidimensional archive of phenotypic elites"): a descriptor's
  cell is its nearest centroid (see `qdrl.qd.repertoires.cvt.cvt_centroids`).

Only the indexing differs; insertion (`CellRepertoire.add`) and sampling are shared.
A repertoire is a frozen dataclass registered as a pytree: genotypes, fitnesses,
descriptors and centroids are leaves; the grid shape and bounds are static
metadata, so a repertoire goes through `jax.jit` and `jax.lax.scan` and one
compilation serves every `add` of a run.

Typical use::

    repertoire = grid_repertoire(example_params, grid_shape=(50, 50), low=0.0, high=1.0)
    repertoire, result = repertoire.add(genotypes, descriptors, fitnesses)
    parents = repertoire.sample(key, 128)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.base import AddResult
from qdrl.qd.repertoires.lookup import (
    Lookup,
    build_lookup,
    grid_bins,
    nearest,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = [
    "CellRepertoire",
    "Occupancy",
    "Slots",
    "as_bounds",
    "check_batch",
    "cvt_repertoire",
    "flush_subnormals",
    "grid_centroids",
    "grid_repertoire",
    "init_storage",
    "nearest_centroid",
    "sample_filled_indices",
    "valid_candidates",
    "write_rows",
]


def _shape_dtype(leaf: Any) -> tuple[tuple[int, ...], np.dtype]:
    # Arrays and `jax.ShapeDtypeStruct` expose shape and dtype; Python scalars go
    # through jnp so they take JAX's default (32-bit) dtypes.
    if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
        return tuple(leaf.shape), np.dtype(leaf.dtype)
    arr = jnp.asarray(leaf)
    return tuple(arr.shape), np.dtype(arr.dtype)


def init_storage(genotype_example: Genotype, num_cells: int) -> Genotype:
    """Zeroed genotype storage: every leaf of `genotype_example` gets a leading `num_cells` axis.

    `genotype_example` is one genotype without batch axis (arrays, scalars or
    `jax.ShapeDtypeStruct` leaves); `None` stores no genotype (passive archives).
    """

    def zeros(leaf: Any) -> Array:
        shape, dtype = _shape_dtype(leaf)
        return jnp.zeros((num_cells, *shape), dtype)

    return jax.tree_util.tree_map(zeros, genotype_example)


def as_bounds(value: float | Sequence[float], dim: int, name: str) -> tuple[float, ...]:
    """`value` as a tuple of `dim` Python floats (a scalar is broadcast), for static metadata."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((dim,), float(arr))
    if arr.shape != (dim,):
        raise ValueError(f"{name} must be a scalar or have {dim} entries, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


def grid_centroids(
    grid_shape: Sequence[int], low: Sequence[float], high: Sequence[float]
) -> np.ndarray:
    """Centres of the cells of a regular grid, (prod(grid_shape), D), in row-major cell order."""
    axes = [
        lo + (np.arange(n) + 0.5) * (hi - lo) / n
        for n, lo, hi in zip(grid_shape, low, high, strict=True)
    ]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.reshape(-1) for m in mesh], axis=-1).astype(np.float32)


def _filled_indices(key: PRNGKey, filled: Array, num_samples: int) -> tuple[Array, Array]:
    """(indices, number of filled cells): see `sample_filled_indices`."""
    num_cells = filled.shape[0]
    cell = jnp.arange(num_cells, dtype=jnp.int32)
    counts = jnp.cumsum(filled.astype(jnp.int32))
    total = counts[-1]
    # The filled cells in order: filled cell c goes to slot counts[c] - 1; empty cells
    # go to distinct out-of-range slots, dropped (so every index is unique). The scatter
    # writes into the cell indices themselves: slots past the filled count keep stale
    # values that no rank reaches, and no buffer of zeros is built (one program fewer).
    slot = jnp.where(filled, counts - 1, num_cells + cell)
    compact = cell.at[slot].set(cell, mode="drop", unique_indices=True)
    bits = jax.random.bits(key, (num_samples,), jnp.uint32)
    ranks = bits % jnp.maximum(total, 1).astype(jnp.uint32)
    return jnp.where(total > 0, compact[ranks.astype(jnp.int32)], 0), total


def sample_filled_indices(key: PRNGKey, filled: Array, num_samples: int) -> Array:
    """`num_samples` cell indices drawn uniformly, with replacement, among the filled cells.

    A rank in `[0, num_filled)` (32 random bits modulo num_filled: the ranks'
    probabilities differ by less than num_filled / 2^32 relative, 2.4e-6 for 10^4
    filled cells) picks an entry of the list of filled cells, built by one scatter
    of the cells to their rank among the filled ones (a cumulative count). No
    search: a `jnp.searchsorted` is a `while` loop whose log2(C) steps each launch
    kernels on a GPU. When no cell is filled, every index is 0 (callers check
    `num_filled`/`is_empty`, or use `sample_filled`; jitted code cannot raise).
    """
    return _filled_indices(key, filled, num_samples)[0]


def sample_filled(key: PRNGKey, genotypes: Genotype, filled: Array, num_samples: int) -> Genotype:
    """`num_samples` rows of `genotypes` drawn uniformly, with replacement, among the filled ones.

    An EMPTY store gives NaN in every floating-point leaf (0 in integer leaves), not
    the zeros of an empty row: offspring built from them evaluate to NaN and are
    rejected, so a run whose repertoire is empty stays visibly empty (coverage 0)
    instead of searching from zero genotypes. Outside jit, `MapElites.ask` raises
    on an empty repertoire before sampling it.
    """
    idx, total = _filled_indices(key, filled, num_samples)

    def take(x: Array) -> Array:
        rows = x[idx]
        if jnp.issubdtype(rows.dtype, jnp.floating):
            rows = jnp.where(total > 0, rows, jnp.asarray(jnp.nan, rows.dtype))
        return rows

    return jax.tree_util.tree_map(take, genotypes)


def nearest_centroid(points: Array, centroids: Array) -> Array:
    """(n,) int32 index of the nearest centroid (squared Euclidean) of each point (n, D).

    By brute force, in the form that suits the backend (`lookup.nearest`).
    """
    return nearest(points, centroids, None)


def flush_subnormals(fitnesses: Array) -> Array:
    """`fitnesses` with subnormal values (|f| < 1.18e-38) and -0.0 replaced by +0.0.

    XLA on a CPU flushes subnormals to zero in arithmetic and comparisons, a GPU may
    not: without this, 4e-41 > 0 would hold on one backend and not on the other, and
    "keep the best" would pick differently. Flushing first gives every backend the
    same rule, and the stored fitness is the flushed one.
    """
    tiny = jnp.finfo(jnp.float32).tiny
    return jnp.where(jnp.abs(fitnesses) < tiny, jnp.zeros_like(fitnesses), fitnesses)


def check_batch(
    storage: Genotype,
    descriptor_dim: int,
    genotypes: Genotype,
    descriptors: Descriptor,
    fitnesses: Fitness,
    where: str,
) -> tuple[Array, Array]:
    """Checks a candidate batch against a repertoire's storage; returns float32 (descriptors, fitnesses).

    The returned fitnesses have their subnormals flushed to 0 (`flush_subnormals`).
    Shapes are static, so the checks run at trace time and cost nothing under jit.
    """
    fitnesses = jnp.asarray(fitnesses, jnp.float32)
    descriptors = jnp.asarray(descriptors, jnp.float32)
    if fitnesses.ndim != 1:
        raise ValueError(f"{where}: fitnesses must have shape (n,), got {fitnesses.shape}")
    n = fitnesses.shape[0]
    if descriptors.shape != (n, descriptor_dim):
        raise ValueError(
            f"{where}: descriptors must have shape (n, D) = ({n}, {descriptor_dim}), "
            f"got {descriptors.shape}"
        )
    # Any: mypy cannot resolve jaxlib's PyTreeDef type and rejects comparing it.
    store_def: Any = jax.tree_util.tree_structure(storage)
    cand_def: Any = jax.tree_util.tree_structure(genotypes)
    if store_def != cand_def:
        raise ValueError(
            f"{where}: genotypes structure does not match the repertoire's.\n"
            f"  expected: {store_def}\n  got:      {cand_def}"
        )
    named = jax.tree_util.tree_flatten_with_path(genotypes)[0]
    for (path, leaf), store in zip(named, jax.tree_util.tree_leaves(storage), strict=True):
        shape, _ = _shape_dtype(leaf)
        want = (n, *store.shape[1:])
        if shape != want:
            name = jax.tree_util.keystr(path) or "<root>"
            raise ValueError(
                f"{where}: genotypes leaf {name} must have shape {want} (a leading batch "
                f"axis of n={n}, then the genotype's shape), got {shape}"
            )
    return descriptors, flush_subnormals(fitnesses)


def valid_candidates(descriptors: Array, fitnesses: Array) -> Array:
    """(n,) bool: candidates with a finite fitness and a finite descriptor.

    NaN marks a failed evaluation; +-inf fitnesses and descriptors are rejected too:
    a stored +inf would make the QD score infinite for the rest of the run and its
    cell could never be improved, and a non-finite descriptor has no place in
    descriptor space (a CVT archive without bounds has nothing to clip it to).
    """
    return jnp.isfinite(fitnesses) & jnp.all(jnp.isfinite(descriptors), axis=-1)


def write_rows(storage: Genotype, target: Array, rows: Genotype) -> Genotype:
    """Scatters `rows` (leading axis n) into `storage` at `target`; out-of-range targets are dropped."""
    return jax.tree_util.tree_map(
        lambda s, r: s.at[target].set(r.astype(s.dtype), mode="drop"), storage, rows
    )


class Occupancy:
    """The views every container of elites shares: `fitnesses` (C,) is -inf where a cell or
    slot is empty. Mixed into the repertoires' frozen dataclasses."""

    fitnesses: Array

    @property
    def filled(self) -> Array:
        """(C,) bool, True where a cell or slot holds an elite."""
        return self.fitnesses > -jnp.inf

    @property
    def num_filled(self) -> Array:
        """() int32, number of filled cells or slots."""
        return jnp.sum(self.filled, dtype=jnp.int32)

    @property
    def is_empty(self) -> Array:
        """() bool, True when nothing is stored (then `sample` returns NaN genotypes)."""
        return self.num_filled == 0


class Slots(Occupancy):
    """`Occupancy` of a container of C slots without cells (unstructured, proximity, DNS), and
    uniform sampling among the stored genotypes."""

    genotypes: Genotype
    descriptors: Array

    @property
    def capacity(self) -> int:
        """Number of slots C (static)."""
        return int(self.fitnesses.shape[0])

    @property
    def num_cells(self) -> int:
        """Number of slots C; coverage is `num_filled / num_cells` as for cell repertoires."""
        return self.capacity

    @property
    def descriptor_dim(self) -> int:
        """Descriptor dimension D (static)."""
        return int(self.descriptors.shape[-1])

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` genotypes drawn uniformly, with replacement, among the stored ones.

        Sampling an EMPTY container does not fail: it returns NaN in every
        floating-point leaf (`sample_filled`). Check `is_empty` / `num_filled` first.
        """
        return sample_filled(key, self.genotypes, self.filled, num_samples)


@dataclasses.dataclass(frozen=True, eq=False)
class CellRepertoire(Occupancy):
    """One elite per cell; cells from a regular grid (direct indexing) or from CVT centroids.

    Attributes:
      genotypes: pytree of the elites' genotypes, every leaf (C, ...); zeros in empty
        cells; `None` when the repertoire stores no genotype (passive archive).
      fitnesses: (C,) float32, the elites' fitnesses, -inf where a cell is empty.
      descriptors: (C, D) float32, the elites' own descriptors (zeros where empty).
      centroids: (C, D) float32 cell centres: the grid's bin centres, or the CVT
        centroids (which also define the cells).
      grid_shape: bins per descriptor dimension for a grid; None for a CVT archive.
      low, high: the grid's descriptor bounds (D floats each); None for a CVT archive.
      lookup_table, lookup_hull, lookup_grid: for a low-dimensional CVT archive built
        with bounds, the lookup grid (candidate centroids per lookup cell, those of
        points outside the box; its shape and box) that makes the exact
        nearest-centroid search cheap (`lookup.py`); else None.
      thresholds, learning_rate, threshold_min: CMA-MAE's archive (see
        `with_learning_rate`): (C,) float32 acceptance thresholds kept apart from
        the elites, the archive learning rate alpha and the thresholds' start
        value; None / None / -inf for a plain elitist repertoire.
    """

    genotypes: Genotype
    fitnesses: Array
    descriptors: Array
    centroids: Array
    grid_shape: tuple[int, ...] | None = None
    low: tuple[float, ...] | None = None
    high: tuple[float, ...] | None = None
    lookup_table: Array | None = None
    lookup_hull: Array | None = None
    lookup_grid: tuple[tuple[int, ...], tuple[float, ...], tuple[float, ...]] | None = None
    thresholds: Array | None = None
    learning_rate: float | None = None
    threshold_min: float = -math.inf

    @property
    def lookup(self) -> Lookup | None:
        """The CVT lookup grid (candidates per lookup cell), when there is one."""
        if self.lookup_table is None or self.lookup_hull is None or self.lookup_grid is None:
            return None
        return Lookup(self.lookup_table, self.lookup_hull, *self.lookup_grid)

    @property
    def num_cells(self) -> int:
        """Number of cells C (static)."""
        return int(self.fitnesses.shape[0])

    @property
    def descriptor_dim(self) -> int:
        """Descriptor dimension D (static)."""
        return int(self.centroids.shape[-1])

    @property
    def is_grid(self) -> bool:
        """True for a regular grid (direct indexing), False for a CVT archive."""
        return self.grid_shape is not None

    def cell_index(self, descriptors: Descriptor) -> Array:
        """(n,) int32 cell of each descriptor (n, D); out-of-bounds descriptors go to the edge cells.

        Grid: bin `floor((d - low) / (high - low) * grid_shape)` per dimension, clipped
        to `[0, grid_shape - 1]`, then raveled in row-major order. CVT: the nearest
        centroid (any point of space, inside the box or not, has one; see
        `lookup.nearest` for how it is searched). Rows holding NaN or +-inf get an
        arbitrary cell; `add` rejects them before indexing matters.
        """
        descriptors = jnp.asarray(descriptors, jnp.float32)
        if self.grid_shape is not None:
            assert self.low is not None and self.high is not None
            return grid_bins(descriptors, self.grid_shape, self.low, self.high)
        return nearest(descriptors, self.centroids, self.lookup)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[CellRepertoire, AddResult]:
        """Offers a batch of n candidates; each cell keeps the best elite it was ever offered.

        Rules (jittable, fixed shapes):
        - a candidate whose fitness or descriptor is not finite (NaN, +inf, -inf) is
          rejected (cell -1, never stored);
        - subnormal fitnesses are flushed to 0 before any comparison, so that every
          backend compares alike (`flush_subnormals`); the stored fitness is the
          flushed one;
        - finite descriptors outside the grid's bounds are CLIPPED to the edge cells
          (CVT: the nearest centroid, which is an edge cell for far-away points); the
          stored descriptor is the candidate's own, unclipped one;
        - among the candidates of one batch falling in the same cell, the fittest is
          kept, ties broken by the lowest batch index;
        - it replaces the cell's elite only if STRICTLY fitter (an equal or worse
          candidate never replaces an elite).

        Args:
          genotypes: pytree whose leaves have a leading axis n and otherwise match
            the repertoire's genotype (`None` for a repertoire without genotypes).
          descriptors: (n, D) descriptors.
          fitnesses: (n,) fitnesses; NaN marks a failed evaluation.

        Returns:
          The new repertoire and an `AddResult`: `added` (now the elite of its cell),
          `new_cell` (added to an empty cell), `improvement` (fitness minus the
          previous elite's, the fitness itself for an empty cell, -inf when
          rejected; "previous" means before this batch), `cell` (-1 when rejected).
        """
        descriptors, fitnesses = check_batch(
            self.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add"
        )
        valid = valid_candidates(descriptors, fitnesses)
        cell = jnp.where(valid, self.cell_index(descriptors), -1)
        return self._insert(genotypes, descriptors, fitnesses, cell)

    def _insert(
        self, genotypes: Genotype, descriptors: Array, fitnesses: Array, cell: Array
    ) -> tuple[CellRepertoire, AddResult]:
        """Best-per-cell insertion of candidates whose cells (-1: rejected) are known."""
        n, num_cells = fitnesses.shape[0], self.num_cells
        valid = cell >= 0
        # Rejected candidates go to an extra segment `num_cells` that is then dropped.
        segment = jnp.where(valid, cell, num_cells)
        fit = jnp.where(valid, fitnesses, -jnp.inf)
        safe_cell = jnp.clip(cell, 0)  # rejected rows (-1) read cell 0, then are masked
        old_fit = jnp.where(valid, self.fitnesses[safe_cell], -jnp.inf)
        old_filled = old_fit > -jnp.inf
        # Each cell's new fitness: the max of its elite's and its candidates' (rejected ones,
        # in the out-of-range segment num_cells, are dropped), scattered into the stored
        # fitnesses themselves rather than into a fresh buffer of segments.
        new_fit = self.fitnesses.at[segment].max(fit, mode="drop")
        index = jnp.arange(n, dtype=jnp.int32)
        # A candidate that beats its cell's elite and equals the cell's new fitness is a best
        # of its cell; of equals, the lowest index wins.
        is_best = valid & (fit > old_fit) & (fit == new_fit[safe_cell])
        winner = jax.ops.segment_min(
            jnp.where(is_best, index, n), segment, num_segments=num_cells + 1
        )
        added = is_best & (winner[segment] == index)
        # At most one writer per cell, so the scatter is deterministic; losers are dropped.
        target = jnp.where(added, cell, num_cells)
        new = dataclasses.replace(
            self,
            genotypes=write_rows(self.genotypes, target, genotypes),
            fitnesses=new_fit,
            descriptors=self.descriptors.at[target].set(descriptors, mode="drop"),
        )
        result = AddResult(
            added=added,
            new_cell=added & ~old_filled,
            improvement=jnp.where(
                valid, jnp.where(old_filled, fit - old_fit, fit), -jnp.inf
            ).astype(jnp.float32),
            cell=cell.astype(jnp.int32),
        )
        if self.thresholds is not None:
            return self._update_thresholds(new, result, fit, cell)
        return new, result

    def with_learning_rate(
        self, learning_rate: float, threshold_min: float = -math.inf
    ) -> CellRepertoire:
        """This (empty) repertoire as CMA-MAE's archive: thresholds apart from elites.

        Fontaine & Nikolaidis 2023, "Covariance Matrix Adaptation MAP-Annealing";
        pyribs' archives with `learning_rate` and `threshold_min`. Every cell gets a
        threshold t = `threshold_min`. A candidate is accepted when its fitness f
        beats its cell's threshold (as it was before the batch); its `AddResult`
        improvement is f - t (f itself in a cell whose threshold is still -inf).
        The k candidates of a batch that beat the threshold of one cell move it to
        (1 - alpha)^k t + (1 - (1 - alpha)^k) mean(f) (Fontaine & Nikolaidis'
        batch rule, t <- (1 - alpha) t + alpha f for one). The elites themselves
        stay elitist: each cell keeps the best candidate it was ever offered, so
        the metrics read the best solutions as before.

        With `threshold_min` = -inf the threshold of a cell is the best fitness it
        received (alpha must then be 1): this is CMA-ME's archive, and runs on it
        equal runs on the plain repertoire bit for bit.
        """
        alpha = learning_rate
        if not (isinstance(alpha, int | float) and 0.0 <= alpha <= 1.0):
            raise ValueError(f"repertoire.learning_rate: expected a number in [0, 1], got {alpha!r}")
        if not (isinstance(threshold_min, int | float) and threshold_min < math.inf):
            raise ValueError(
                f"repertoire.threshold_min: expected a finite number or -inf, got {threshold_min!r}"
            )
        if threshold_min == -math.inf and alpha != 1.0:
            raise ValueError(
                "repertoire.threshold_min: expected a finite number when "
                f"repertoire.learning_rate < 1, got {threshold_min!r}"
            )
        return dataclasses.replace(
            self,
            thresholds=jnp.full((self.num_cells,), threshold_min, jnp.float32),
            learning_rate=float(alpha),
            threshold_min=float(threshold_min),
        )

    def _update_thresholds(
        self, new: CellRepertoire, result: AddResult, fit: Array, cell: Array
    ) -> tuple[CellRepertoire, AddResult]:
        """CMA-MAE's thresholds after a batch; improvement measured against them."""
        assert self.thresholds is not None and self.learning_rate is not None
        num_cells = self.num_cells
        valid = cell >= 0
        before = jnp.where(valid, self.thresholds[jnp.clip(cell, 0)], -jnp.inf)
        beats = valid & (fit > before)
        segment = jnp.where(beats, cell, num_cells)
        if self.threshold_min == -math.inf:
            best = jax.ops.segment_max(
                jnp.where(beats, fit, -jnp.inf), segment, num_segments=num_cells + 1
            )
            thresholds = jnp.maximum(self.thresholds, best[:num_cells])
        else:
            count = jax.ops.segment_sum(
                beats.astype(jnp.float32), segment, num_segments=num_cells + 1
            )[:num_cells]
            total = jax.ops.segment_sum(
                jnp.where(beats, fit, 0.0), segment, num_segments=num_cells + 1
            )[:num_cells]
            keep = (1.0 - self.learning_rate) ** count
            moved = keep * self.thresholds + (1.0 - keep) * total / jnp.maximum(count, 1.0)
            thresholds = jnp.where(count > 0, moved, self.thresholds)
        base = jnp.where(before == -jnp.inf, 0.0, before)
        improvement = jnp.where(valid, fit - base, -jnp.inf).astype(jnp.float32)
        return (
            dataclasses.replace(new, thresholds=thresholds),
            result._replace(improvement=improvement),
        )

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` genotypes drawn uniformly, with replacement, among the filled cells.

        Sampling an EMPTY repertoire does not fail (jitted code cannot raise): it
        returns NaN in every floating-point leaf (`sample_filled`), whose offspring
        are rejected when evaluated. Check `is_empty` / `num_filled` first.
        """
        return sample_filled(key, self.genotypes, self.filled, num_samples)


jax.tree_util.register_dataclass(
    CellRepertoire,
    data_fields=[
        "genotypes", "fitnesses", "descriptors", "centroids", "lookup_table", "lookup_hull", "thresholds",
    ],
    meta_fields=["grid_shape", "low", "high", "lookup_grid", "learning_rate", "threshold_min"],
)


def _empty(genotype_example: Genotype, centroids: np.ndarray, **meta: Any) -> CellRepertoire:
    num_cells, dim = centroids.shape
    return CellRepertoire(
        genotypes=init_storage(genotype_example, num_cells),
        fitnesses=jnp.full((num_cells,), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((num_cells, dim), jnp.float32),
        centroids=jnp.asarray(centroids, jnp.float32),
        **meta,
    )


def grid_repertoire(
    genotype_example: Genotype,
    grid_shape: Sequence[int],
    low: float | Sequence[float],
    high: float | Sequence[float],
) -> CellRepertoire:
    """An empty MAP-Elites grid (Mouret & Clune 2015) with direct cell indexing.

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype). Only leaf shapes and dtypes are used.
      grid_shape: bins per descriptor dimension, e.g. `(50, 50)`; D = len(grid_shape).
      low, high: descriptor bounds, scalars (same for every dimension) or D values,
        with `low < high`. Descriptors outside are clipped to the edge cells.

    Returns:
      A `CellRepertoire` of prod(grid_shape) empty cells.
    """
    shape = tuple(int(n) for n in grid_shape)
    if not shape or any(n <= 0 for n in shape):
        raise ValueError(f"grid_shape must be a non-empty tuple of positive ints, got {grid_shape}")
    lo = as_bounds(low, len(shape), "low")
    hi = as_bounds(high, len(shape), "high")
    if any(h <= a for a, h in zip(lo, hi, strict=True)):
        raise ValueError(f"need low < high in every dimension, got low={lo}, high={hi}")
    return _empty(
        genotype_example, grid_centroids(shape, lo, hi), grid_shape=shape, low=lo, high=hi
    )


def cvt_repertoire(
    genotype_example: Genotype,
    centroids: Array | np.ndarray,
    low: float | Sequence[float] | None = None,
    high: float | Sequence[float] | None = None,
) -> CellRepertoire:
    """An empty CVT archive (Vassiliades et al. 2018): cell = nearest centroid.

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype).
      centroids: (C, D) centroids, e.g. from `qdrl.qd.repertoires.cvt.cvt_centroids`.
      low, high: the descriptor box. When given (and D <= 3), an exact lookup grid
        replaces the brute-force nearest-centroid search inside the box on the CPU
        (see `lookup.py`); the cells are the same either way.

    Returns:
      A `CellRepertoire` of C empty cells.
    """
    c = np.asarray(centroids, dtype=np.float32)
    if c.ndim != 2 or c.shape[0] == 0 or c.shape[1] == 0:
        raise ValueError(f"centroids must have shape (C, D) with C, D > 0, got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("centroids must be finite")
    if (low is None) != (high is None):
        raise ValueError("give both low and high, or neither")
    meta: dict[str, Any] = {}
    if low is not None and high is not None:
        lo = as_bounds(low, c.shape[1], "low")
        hi = as_bounds(high, c.shape[1], "high")
        if any(h <= a for a, h in zip(lo, hi, strict=True)):
            raise ValueError(f"need low < high in every dimension, got low={lo}, high={hi}")
        lookup = build_lookup(c, lo, hi)
        if lookup is not None:
            meta = {
                "lookup_table": lookup.table,
                "lookup_hull": lookup.hull,
                "lookup_grid": (lookup.shape, lookup.low, lookup.high),
            }
    return _empty(genotype_example, c, **meta)
