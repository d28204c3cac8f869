"""An emitter whose batch also re-evaluates what the repertoire asks for (Uncertain-QD sampling).

Archive-Sampling, Adaptive-Sampling and Parallel-Adaptive-Sampling (see
`qdrl.qd.repertoires.accumulating`) spend part of each iteration's evaluations on
solutions already stored. The repertoire plans the batch (`AccumulatingRepertoire.plan`);
this wrapper hands it the inner emitter's offspring and returns the rows it builds, so
the loop evaluates exactly `batch_size` rows per iteration, re-evaluations included, and
stays the one MAP-Elites loop.
"""

from __future__ import annotations

from typing import Any

from qdrl.qd.base import AddResult, Emitter, Evaluation, Repertoire
from qdrl.types import Genotype, PRNGKey

__all__ = ["ResamplingEmitter"]


class ResamplingEmitter:
    """`inner`'s offspring laid into the rows its repertoire plans (`repertoire.batch`).

    The inner emitter sees the whole evaluated batch in `update`, re-evaluations included
    (its `added` is False on them); use a stateless emitter (the GA) or one that reads only
    `added`. `batch_size`, the rows evaluated per iteration, is the inner emitter's.
    """

    def __init__(self, inner: Emitter) -> None:
        self.inner = inner
        self.batch_size = inner.batch_size

    def init(self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype) -> Any:
        return self.inner.init(key, repertoire, evaluation, genotypes)

    def emit(self, state: Any, repertoire: Any, key: PRNGKey) -> Genotype:
        """The planned re-evaluations, then the inner emitter's offspring (`repertoire.batch`)."""
        return repertoire.batch(self.inner.emit(state, repertoire, key))

    def update(
        self, state: Any, repertoire: Repertoire, genotypes: Genotype, evaluation: Evaluation, added: AddResult,
        key: PRNGKey,
    ) -> Any:
        return self.inner.update(state, repertoire, genotypes, evaluation, added, key)
