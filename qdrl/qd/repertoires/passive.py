"""Passive archives: repertoires that only MEASURE an algorithm, storing no genotype.

Every algorithm of qdrl, RL or QD, feeds the descriptors and fitnesses of the
policies it evaluates to a passive archive, so that QD metrics (QD score,
coverage, max fitness; `qdrl.qd.metrics.qd_metrics`) are computed the same way for
all of them (QDax paper, comparison of SMERL with MAP-Elites and PGA-ME). A passive
archive is a `CellRepertoire` whose genotypes are `None`: it is never sampled by
emitters (sampling it would return `None`) and never drives the search. Like every
repertoire it rejects evaluations whose fitness or descriptor is not finite (NaN,
+inf, -inf), so one diverged rollout cannot make the metrics infinite.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, TypeVar

import numpy as np

from qdrl.qd.metrics import qd_metrics, range_qd_score
from qdrl.qd.repertoires.cells import CellRepertoire, cvt_repertoire, grid_repertoire
from qdrl.qd.repertoires.unstructured import UnstructuredRepertoire
from qdrl.types import Array, Descriptor, Fitness

__all__ = ["feed", "observe", "passive_archive"]

_Archive = TypeVar("_Archive", CellRepertoire, UnstructuredRepertoire)


def passive_archive(
    kind: Literal["grid", "cvt"],
    *,
    grid_shape: Sequence[int] | None = None,
    low: float | Sequence[float] | None = None,
    high: float | Sequence[float] | None = None,
    centroids: Array | np.ndarray | None = None,
) -> CellRepertoire:
    """An empty measurement-only archive (genotype `None`): a grid or a CVT archive.

    Args:
      kind: "grid" (needs `grid_shape`, `low`, `high`) or "cvt" (needs `centroids`).
      grid_shape, low, high: as in `grid_repertoire`.
      centroids: (C, D), as in `cvt_repertoire`.
    """
    if kind == "grid":
        if grid_shape is None or low is None or high is None:
            raise ValueError("passive_archive(kind='grid') needs grid_shape, low and high")
        return grid_repertoire(None, grid_shape, low, high)
    if kind == "cvt":
        if centroids is None:
            raise ValueError("passive_archive(kind='cvt') needs centroids")
        return cvt_repertoire(None, centroids)
    raise ValueError(f"kind must be 'grid' or 'cvt', got {kind!r}")


def observe(archive: _Archive, descriptors: Descriptor, fitnesses: Fitness) -> _Archive:
    """The archive after offering it n evaluations (descriptors (n, D), fitnesses (n,)); jittable.

    Same rules as `add`: a fitness or descriptor that is not finite (NaN, +-inf) is
    rejected, subnormal fitnesses count as 0, best per cell, strictly better
    replaces. The per-candidate `AddResult` is dropped. The archive must store no
    genotype.
    """
    if archive.genotypes is not None:
        raise ValueError("observe is for passive archives (genotypes None); use add instead")
    new, _ = archive.add(None, descriptors, fitnesses)
    return new


def feed(
    archive: CellRepertoire, descriptors: Descriptor, returns: Fitness, qd_offset: float,
    fitness_range: tuple[float, float] | None = None,
) -> tuple[CellRepertoire, dict[str, Array]]:
    """The passive archive after offering it evaluated episodes, and its QD metrics; jittable.

    `descriptors` (..., D) and `returns` (...) with the same leading axes (episodes, or
    members x episodes); every RL, PBT and skill-discovery run measures itself so. With
    `fitness_range`, the metrics add `range_qd_score` (`qdrl.qd.metrics.range_qd_score`).
    """
    archive = observe(
        archive, descriptors.reshape((-1, descriptors.shape[-1])), returns.reshape((-1,))
    )
    metrics = qd_metrics(archive, qd_offset)
    if fitness_range is not None:
        metrics["range_qd_score"] = range_qd_score(archive, fitness_range)
    return archive, metrics
