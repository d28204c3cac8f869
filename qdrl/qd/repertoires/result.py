"""A search archive beside a passive result archive, as pyribs' examples pair them.

Novelty search's proximity archive, Dominated Novelty Search's population, Density Descent's
density archive and Discount Model Search's discount archive decide what the search keeps or
how it ranks offspring, but none has cells a QD score can be read from (the density and
discount archives keep no solutions at all). pyribs' examples add every evaluated solution to a
second, passive `GridArchive` (the "result archive", 100x100 cells on the sphere) and report
its QD score, coverage and best objective; qdrl does the same, so that every figure of these
runs reads as MAP-Elites' does.

`ResultArchived` is that pair. It is a repertoire to the QD loop (`qdrl.qd.base`): `add`
offers each batch to both and returns the SEARCH archive's `AddResult` (its status, value and
ranker fields, which `qdrl.qd.emitters.rankers.outcome` passes on); `genotypes`, `fitnesses`
and `descriptors` are the RESULT archive's, so metrics, plots and exports read the result
archive; `sample` draws parents from the search archive when it stores solutions
(`parents = "search"`), else from the result archive (pyribs'
`pass_result_archive_to_emitters`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult, Evaluation, add_evaluation
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = [
    "Parents",
    "ResultArchived",
    "result_archive",
    "search_archive_metrics",
    "with_result_archive",
]

Parents = Literal["search", "result"]


@dataclasses.dataclass(frozen=True, eq=False)
class ResultArchived:
    """A search archive (`search`) and the result archive (`result`, a cell repertoire) it feeds.

    `parents` (static) says which of the two `sample` draws from.
    """

    search: Any
    result: Any
    parents: Parents = "search"

    @property
    def genotypes(self) -> Genotype:
        return self.result.genotypes

    @property
    def fitnesses(self) -> Array:
        return self.result.fitnesses

    @property
    def descriptors(self) -> Array:
        return self.result.descriptors

    @property
    def num_cells(self) -> int:
        return int(self.result.num_cells)

    @property
    def filled(self) -> Array:
        return self.result.filled

    @property
    def num_filled(self) -> Array:
        return self.result.num_filled

    @property
    def is_empty(self) -> Array:
        """Whether the archive that parents come from holds nothing."""
        return self._parents.is_empty

    @property
    def low(self) -> Any:
        """The result archive's descriptor bounds (the random-direction rankers read them)."""
        return getattr(self.result, "low", None)

    @property
    def high(self) -> Any:
        return getattr(self.result, "high", None)

    @property
    def _parents(self) -> Any:
        return self.search if self.parents == "search" else self.result

    def cell_index(self, descriptors: Descriptor) -> Array:
        """The result archive's cells of `descriptors`."""
        return self.result.cell_index(descriptors)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[ResultArchived, AddResult]:
        """Offers the batch to both archives; returns the search archive's verdict on it."""
        search, added = self.search.add(genotypes, descriptors, fitnesses)
        result, _ = self.result.add(genotypes, descriptors, fitnesses)
        return dataclasses.replace(self, search=search, result=result), added

    def add_evaluation(self, genotypes: Genotype, evaluation: Evaluation) -> tuple[ResultArchived, AddResult]:
        """`add`, the search archive reading the whole evaluation when it asks for it
        (`qdrl.qd.base.add_evaluation`: AURORA encodes the evaluation's observations)."""
        search, added = add_evaluation(self.search, genotypes, evaluation)
        result, _ = self.result.add(genotypes, evaluation.descriptors, evaluation.fitnesses)
        return dataclasses.replace(self, search=search, result=result), added

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` parents drawn from the archive `parents` names; from the result archive
        while a search archive that should give them is still empty."""
        if self.parents == "result":
            return self.result.sample(key, num_samples)
        return jax.lax.cond(
            jnp.asarray(self.search.is_empty),
            lambda: self.result.sample(key, num_samples),
            lambda: self.search.sample(key, num_samples),
        )


jax.tree_util.register_dataclass(ResultArchived, data_fields=["search", "result"], meta_fields=["parents"])


def with_result_archive(search: Any, result: Any, parents: Parents | None = None) -> ResultArchived:
    """`search` beside the passive `result` archive; `parents` defaults to the search archive
    when it stores genotypes (`search.genotypes` is not None), else the result archive."""
    if parents is None:
        parents = "search" if getattr(search, "genotypes", None) is not None else "result"
    if parents not in ("search", "result"):
        raise ValueError(f"parents: expected 'search' or 'result', got {parents!r}")
    if parents == "result" and getattr(result, "genotypes", None) is None:
        raise ValueError("parents: the result archive stores no genotypes to draw parents from")
    return ResultArchived(search, result, parents)


def result_archive(repertoire: Any) -> Any:
    """The archive a run's figures read: the result archive of a `ResultArchived`, else itself."""
    return repertoire.result if isinstance(repertoire, ResultArchived) else repertoire


def search_archive_metrics(search: Any) -> dict[str, Array]:
    """`search_size` (solutions a proximity archive or DNS population holds, descriptors in a
    density buffer, cells a discount archive's record has reached), and where the archive has
    them its current `novelty_threshold` and its discount model's last `discount_loss`, or what
    an archive reports of itself (`own_metrics`: AURORA's elites, threshold and autoencoder
    loss); jittable."""
    out = {"search_size": jnp.asarray(search.num_filled, jnp.int32)}
    if hasattr(search, "novelty_threshold"):
        out["novelty_threshold"] = jnp.asarray(search.novelty_threshold, jnp.float32)
    if hasattr(search, "own_metrics"):  # an archive that says what it reports (AURORA)
        out.update(search.own_metrics())
    elif hasattr(search, "loss"):
        out["discount_loss"] = jnp.asarray(search.loss, jnp.float32)
    return out
