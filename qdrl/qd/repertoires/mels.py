"""MAP-Elites Low-Spread's repertoire: each cell keeps its spread beside its elite.

ME-LS (GECCO 2023, doi:10.1145/3583131.3590433, which QDax's `MELSRepertoire` cites as Mace
2023). Every candidate is evaluated N times
(`qdrl.qd.sampling.sampled_scoring`, whose `extras["samples"]` this repertoire reads). As
QDax defines them:

- the candidate's cell is the most frequent cell of its N descriptors (the mode; a tie goes
  to the lowest cell index, as QDax's `jnp.unique` then `argmax`), and the descriptor stored
  is that cell's centroid;
- its fitness is the mean of its N fitnesses;
- its spread is the mean Euclidean distance between its descriptors over the N (N - 1) / 2
  pairs of samples (0 when N = 1);
- it replaces its cell's elite when its fitness is strictly higher AND its spread is no
  higher (an empty cell has fitness -inf and spread +inf, so any candidate fills it).

QDax leaves the choice among several candidates of one batch that beat one cell to the
scatter (arbitrary); here the fittest of them wins, then the lowest spread, then the lowest
batch index, so a run is the same on every backend.

The repertoire is a `CellRepertoire` whose `add` (the plain best-per-cell insertion of
fitnesses and descriptors) is untouched: it is what `qdrl.qd.reevaluate` rebuilds the
corrected repertoire with and what `qdrl.load_run` restores an export into. The QD loop
offers each batch through `add_evaluation` (`qdrl.qd.base.add_evaluation`), the rule above.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from qdrl.qd.base import SAMPLES, AddResult, Evaluation
from qdrl.qd.repertoires.cells import CellRepertoire, check_batch, flush_subnormals, write_rows
from qdrl.types import Array, Genotype

__all__ = ["MELSRepertoire", "evaluation_samples", "mean_spread", "mels_repertoire", "sample_cells", "spread"]

# CellRepertoire's static metadata; its other fields are leaves (`cells.py` registers them so).
CELL_META = ("grid_shape", "low", "high", "lookup_grid", "learning_rate", "threshold_min")


def register_cells_subclass(cls: type[Any]) -> None:
    """Registers a dataclass subclass of `CellRepertoire` as a pytree: CellRepertoire's static
    metadata stays static, every other field (the subclass's own included) is a leaf."""
    fields = [f.name for f in dataclasses.fields(cls)]
    jax.tree_util.register_dataclass(
        cls, data_fields=[f for f in fields if f not in CELL_META], meta_fields=list(CELL_META)
    )


def evaluation_samples(evaluation: Evaluation) -> tuple[Array, Array]:
    """(n, N) fitnesses and (n, N, D) descriptors of a batch's samples: `extras["samples"]`
    of a sampled evaluation, else its own values as one sample each (N = 1)."""
    samples = evaluation.extras.get(SAMPLES)
    fitnesses = jnp.asarray(evaluation.fitnesses, jnp.float32)
    descriptors = jnp.asarray(evaluation.descriptors, jnp.float32)
    if samples is None:
        return fitnesses[:, None], descriptors[:, None, :]
    fit_s = jnp.asarray(samples["fitnesses"], jnp.float32)
    desc_s = jnp.asarray(samples["descriptors"], jnp.float32)
    n, dim = descriptors.shape
    if fit_s.ndim != 2 or fit_s.shape[0] != n or desc_s.shape != (n, fit_s.shape[1], dim):
        raise ValueError(
            f"extras['samples']: expected fitnesses (n, N) and descriptors (n, N, D) with n={n}, D={dim}, "
            f"got {fit_s.shape} and {desc_s.shape}"
        )
    return fit_s, desc_s


def spread(descriptors: Array) -> Array:
    """(n,) mean Euclidean distance between the N descriptors of each candidate, (n, N, D),
    over its N (N - 1) / 2 pairs (QDax `_dispersion`); 0 when N = 1."""
    num = descriptors.shape[1]
    if num == 1:
        return jnp.zeros(descriptors.shape[:1], jnp.float32)
    diff = descriptors[:, :, None, :] - descriptors[:, None, :, :]
    # sqrt of a sum that is 0 on the diagonal: where-guarded so a gradient would stay finite
    sq = jnp.sum(jnp.square(diff), axis=-1)
    dist = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)
    return jnp.sum(dist, axis=(1, 2)) / (num * (num - 1))


def sample_cells(cells: Array, num_cells: int) -> Array:
    """(n,) the most frequent of each row of cells (n, N); of equally frequent ones, the lowest."""
    counts = jnp.sum(cells[:, :, None] == cells[:, None, :], axis=-1)  # (n, N) each sample's cell's count
    most = jnp.max(counts, axis=1, keepdims=True)
    return jnp.min(jnp.where(counts == most, cells, num_cells), axis=1).astype(jnp.int32)


def mean_spread(repertoire: MELSRepertoire) -> Array:
    """() float32 mean spread of the elites (NaN when the repertoire is empty)."""
    filled = repertoire.filled
    count = jnp.sum(filled)
    total = jnp.sum(jnp.where(filled, repertoire.spreads, 0.0))
    return jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan).astype(jnp.float32)


@dataclasses.dataclass(frozen=True, eq=False)
class MELSRepertoire(CellRepertoire):
    """A `CellRepertoire` whose elites entered by ME-LS' rule; `spreads` (C,) float32 is each
    elite's spread, +inf where a cell is empty."""

    spreads: Array = dataclasses.field(default_factory=lambda: jnp.zeros((0,), jnp.float32))

    def add_evaluation(self, genotypes: Genotype, evaluation: Evaluation) -> tuple[MELSRepertoire, AddResult]:
        """Offers a sampled batch by ME-LS' rule (module docstring); a candidate with a non-finite
        sample (fitness or descriptor) is rejected (cell -1)."""
        check_batch(
            self.genotypes, self.descriptor_dim, genotypes, evaluation.descriptors, evaluation.fitnesses,
            "add_evaluation",
        )
        fit_s, desc_s = evaluation_samples(evaluation)
        n, num, dim = desc_s.shape
        valid = jnp.all(jnp.isfinite(fit_s), axis=1) & jnp.all(jnp.isfinite(desc_s), axis=(1, 2))
        cells = self.cell_index(desc_s.reshape(n * num, dim)).reshape(n, num)
        cell = jnp.where(valid, sample_cells(cells, self.num_cells), -1)
        fitness = flush_subnormals(jnp.mean(fit_s, axis=1))
        return self._insert_low_spread(genotypes, fitness, spread(desc_s), cell)

    def _insert_low_spread(
        self, genotypes: Genotype, fit: Array, spreads: Array, cell: Array
    ) -> tuple[MELSRepertoire, AddResult]:
        n, num_cells = fit.shape[0], self.num_cells
        valid = cell >= 0
        safe = jnp.clip(cell, 0)
        old_fit = jnp.where(valid, self.fitnesses[safe], -jnp.inf)
        beats = valid & (fit > old_fit) & (spreads <= self.spreads[safe])
        segment = jnp.where(beats, cell, num_cells)

        def among(mask: Array, values: Array, fill: float, reduce: Any) -> Array:
            """`mask` narrowed to the candidates whose `values` equal their cell's `reduce`."""
            best = reduce(jnp.where(mask, values, fill), segment, num_segments=num_cells + 1)
            return mask & (values == best[segment])

        best = among(among(beats, fit, -jnp.inf, jax.ops.segment_max), spreads, jnp.inf, jax.ops.segment_min)
        index = jnp.arange(n, dtype=jnp.int32)
        first = jax.ops.segment_min(jnp.where(best, index, n), segment, num_segments=num_cells + 1)
        added = best & (first[segment] == index)
        target = jnp.where(added, cell, num_cells)  # one writer per cell at most
        new = dataclasses.replace(
            self,
            genotypes=write_rows(self.genotypes, target, genotypes),
            fitnesses=self.fitnesses.at[target].set(fit, mode="drop"),
            descriptors=self.descriptors.at[target].set(self.centroids[safe], mode="drop"),
            spreads=self.spreads.at[target].set(spreads, mode="drop"),
        )
        old_filled = old_fit > -jnp.inf
        return new, AddResult(
            added=added,
            new_cell=added & ~old_filled,
            improvement=jnp.where(valid, jnp.where(old_filled, fit - old_fit, fit), -jnp.inf).astype(jnp.float32),
            cell=cell.astype(jnp.int32),
        )

    def log_metrics(self) -> dict[str, Array]:
        """The mean spread of the elites, logged beside the QD metrics."""
        return {"mean_spread": mean_spread(self)}


register_cells_subclass(MELSRepertoire)


def mels_repertoire(cells: CellRepertoire) -> MELSRepertoire:
    """An empty ME-LS repertoire on the cells (grid or CVT) of the empty `cells`."""
    if not isinstance(cells, CellRepertoire) or cells.thresholds is not None:
        raise ValueError(
            "repertoire.kind: ME-LS keeps its elites on a grid or CVT repertoire without CMA-MAE's thresholds, "
            f"got {type(cells).__name__}"
        )
    fields = {f.name: getattr(cells, f.name) for f in dataclasses.fields(CellRepertoire)}
    return MELSRepertoire(**fields, spreads=jnp.full((cells.num_cells,), jnp.inf, jnp.float32))
