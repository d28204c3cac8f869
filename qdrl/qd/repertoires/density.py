"""The archive of Density Descent Search: a reservoir of descriptors and a Gaussian KDE over it.

Lee et al. 2024, "Density Descent for Diversity Optimization" (GECCO 2024,
doi:10.1145/3638529.3654001); pyribs' `DensityArchive` with `density_method="kde"`. DDS
ranks offspring by the density of their descriptors among those seen so far, lowest
first, and so descends the density: it spreads the search over descriptor space.

The archive keeps no solution, only a buffer of at most K descriptors, a uniform sample
of every valid descriptor ever offered (reservoir sampling), and estimates densities
with a Gaussian kernel of bandwidth h over that buffer (`kde_density`). A run keeps a
separate result archive (a grid or CVT repertoire) for its solutions and metrics;
emitters sample that one.

Reservoir rule: the first K valid descriptors fill the buffer in order; the t-th
(0-indexed, t >= K) replaces a uniformly drawn row with probability K / (t + 1), else
it is dropped (Algorithm R). pyribs draws skip lengths instead (Li 1994, Algorithm L),
fewer random numbers for a sequential loop; both keep a uniform sample of the stream.
Here each candidate draws one integer in [0, t] (its row if < K) and the batch is
resolved at once, the latest writer of a row winning as in a sequential pass: no loop
over the batch. pyribs' loop indexes the batch from its start at every replacement, so
it stores the first items of a batch more often (some twice); this archive keeps the
textbook uniform sample.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.neighbours import squared_distances
from qdrl.qd.repertoires.cells import check_batch, valid_candidates
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = ["DensityArchive", "density_archive", "kde_density"]


def kde_density(
    points: Array, buffer: Array, count: Array | int, bandwidth: Array | float
) -> Array:
    """(n,) Gaussian kernel density at points (n, D) of the first `count` rows of `buffer` (K, D).

    pyribs' KDE: sum_j phi(|x - b_j| / h) / (count * h), phi the standard normal
    density, whatever D (pyribs divides by h, not h^D: the values rank alike). 0 when
    `count` is 0. Distances are summed over dimensions of (x - b) (`squared_distances`), no
    |x|^2 - 2 x.b + |b|^2 expansion, which would cancel for points far from the origin and a
    small h (beyond 16 dimensions, the expansion about the points' mean).
    """
    points = jnp.asarray(points, jnp.float32)
    buffer = jnp.asarray(buffer, jnp.float32)
    count = jnp.asarray(count, jnp.int32)
    h = jnp.asarray(bandwidth, jnp.float32)
    if points.ndim != 2 or buffer.ndim != 2 or points.shape[1] != buffer.shape[1]:
        raise ValueError(
            f"kde_density: expected points (n, D) and buffer (K, D), got {points.shape} "
            f"and {buffer.shape}"
        )
    sq = squared_distances(points, buffer)
    used = jnp.arange(buffer.shape[0]) < count
    total = jnp.sum(jnp.where(used, jnp.exp(-0.5 * sq / (h * h)), 0.0), axis=1)
    norm = math.sqrt(2.0 * math.pi) * jnp.maximum(count, 1).astype(jnp.float32) * h
    return jnp.where(count > 0, total / norm, 0.0)


@dataclasses.dataclass(frozen=True, eq=False)
class DensityArchive:
    """A reservoir of at most K descriptors and the Gaussian KDE over it; stores no genotype.

    Attributes:
      buffer: (K, D) float32 descriptors; the first `min(seen, K)` rows are in use.
      seen: () int32 number of valid descriptors ever offered (the stream's length).
      bandwidth: () float32 kernel bandwidth h; a leaf, so runs can sweep it under vmap.
      key: the reservoir's key, split at every `add`.

    The cell-repertoire views read the buffer: `descriptors` is the buffer, `num_cells`
    K, `filled` its rows in use. `fitnesses` holds no fitness (0 in the rows in use,
    -inf in the others, so `filled` reads the same): QD metrics of this archive are
    meaningless, read them from the run's result archive.
    """

    buffer: Array
    seen: Array
    bandwidth: Array
    key: PRNGKey

    @property
    def genotypes(self) -> None:
        """None: the archive stores no solution."""
        return None

    @property
    def num_cells(self) -> int:
        """Buffer size K (static)."""
        return int(self.buffer.shape[0])

    @property
    def descriptor_dim(self) -> int:
        """Descriptor dimension D (static)."""
        return int(self.buffer.shape[1])

    @property
    def count(self) -> Array:
        """() int32 rows of the buffer in use, min(seen, K)."""
        return jnp.minimum(self.seen, self.num_cells)

    @property
    def descriptors(self) -> Array:
        """(K, D) the buffer (rows past `count` are zeros or stale)."""
        return self.buffer

    @property
    def filled(self) -> Array:
        """(K,) bool, the rows of the buffer in use."""
        return jnp.arange(self.num_cells) < self.count

    @property
    def fitnesses(self) -> Array:
        """(K,) float32: 0 where `filled`, -inf elsewhere; no fitness is stored."""
        return jnp.where(self.filled, 0.0, -jnp.inf).astype(jnp.float32)

    @property
    def num_filled(self) -> Array:
        """() int32 rows of the buffer in use."""
        return self.count

    @property
    def is_empty(self) -> Array:
        """() bool, True before any valid descriptor was offered (every density is then 0)."""
        return self.seen == 0

    def density(self, descriptors: Descriptor) -> Array:
        """(n,) KDE density at descriptors (n, D) of the current buffer (`kde_density`)."""
        return kde_density(descriptors, self.buffer, self.count, self.bandwidth)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[DensityArchive, AddResult]:
        """Judges n candidates by their density, then offers their descriptors to the reservoir.

        `genotypes` is ignored (any pytree, or None). A candidate whose fitness or
        descriptor is not finite is rejected: a failed evaluation, kept out of the
        buffer (pyribs raises on such descriptors and ignores objectives).

        Returns:
          The new archive and an `AddResult`:
          - `status` 2 for every valid candidate, as pyribs (the archive rejects
            nothing), 0 for a rejected one;
          - `info["density"]` the KDE at the candidate of the buffer BEFORE the batch,
            as pyribs, +inf for a rejected one (so rankers put it last);
          - `value` and `improvement` -density (-inf when rejected): pyribs returns no
            value, this one makes value rankers ("imp", "2imp") order as DDS does,
            lowest density first;
          - `added`: the descriptor is in the buffer after the batch; `new_cell`: it
            went to a free row; `cell`: that row, -1 when it is not in the buffer.
        """
        descriptors, fitnesses = check_batch(
            None, self.descriptor_dim, None, descriptors, fitnesses, "add"
        )
        n, size = fitnesses.shape[0], self.num_cells
        valid = valid_candidates(descriptors, fitnesses)
        density = self.density(descriptors)
        # Stream position of each valid candidate; Algorithm R draws one integer in [0, t].
        position = self.seen + jnp.cumsum(valid, dtype=jnp.int32) - 1
        key, draw_key = jax.random.split(self.key)
        draw = jax.random.randint(draw_key, (n,), 0, jnp.maximum(position, 0) + 1, jnp.int32)
        row = jnp.where(position < size, position, draw)
        row = jnp.where(valid & (row < size), row, size)
        # The latest candidate of the batch writing a row wins, as in a sequential pass.
        index = jnp.arange(n, dtype=jnp.int32)
        last = jax.ops.segment_max(index, row, num_segments=size + 1)
        kept = (row < size) & (last[row] == index)
        target = jnp.where(kept, row, size)
        new = dataclasses.replace(
            self,
            buffer=self.buffer.at[target].set(descriptors, mode="drop"),
            seen=self.seen + jnp.sum(valid, dtype=jnp.int32),
            key=key,
        )
        # 0 - d rather than -d: an empty buffer's value is +0, not -0
        value = jnp.where(valid, 0.0 - density, -jnp.inf).astype(jnp.float32)
        return new, AddResult(
            added=kept,
            new_cell=kept & (position < size),
            improvement=value,
            cell=jnp.where(kept, row, -1).astype(jnp.int32),
            status=jnp.where(valid, 2, 0).astype(jnp.int32),
            value=value,
            info={"density": jnp.where(valid, density, jnp.inf).astype(jnp.float32)},
        )

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """Not available: the archive stores no solution; sample the run's result archive."""
        raise NotImplementedError(
            "DensityArchive stores no genotypes (Density Descent Search keeps only "
            "descriptors); sample parents from the run's result archive instead"
        )


jax.tree_util.register_dataclass(
    DensityArchive, data_fields=["buffer", "seen", "bandwidth", "key"], meta_fields=[]
)


def density_archive(
    descriptor_dim: int, buffer_size: int, bandwidth: float, *, key: PRNGKey
) -> DensityArchive:
    """An empty DDS archive (Lee et al. 2024): a reservoir of `buffer_size` descriptors and a KDE.

    Args:
      descriptor_dim: descriptor dimension D (>= 1).
      buffer_size: reservoir size K (>= 1); pyribs' DDS config uses 10000.
      bandwidth: the Gaussian kernel's bandwidth h (> 0), in descriptor units; pyribs'
        DDS sphere config uses 25.6 for descriptors in [-51.2, 51.2]^2.
      key: the reservoir's key.
    """
    if not _is_int(descriptor_dim) or descriptor_dim < 1:
        raise ValueError(f"descriptor_dim: expected an int >= 1, got {descriptor_dim!r}")
    if not _is_int(buffer_size) or buffer_size < 1:
        raise ValueError(f"buffer_size: expected an int >= 1, got {buffer_size!r}")
    if not (isinstance(bandwidth, numbers.Real) and 0.0 < bandwidth < math.inf):
        raise ValueError(f"bandwidth: expected a finite number > 0, got {bandwidth!r}")
    return DensityArchive(
        buffer=jnp.zeros((int(buffer_size), int(descriptor_dim)), jnp.float32),
        seen=jnp.zeros((), jnp.int32),
        bandwidth=jnp.asarray(bandwidth, jnp.float32),
        key=key,
    )


def _is_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)
