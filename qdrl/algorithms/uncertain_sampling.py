"""The Uncertain-QD methods that re-evaluate: Archive-, Adaptive- and Parallel-Adaptive-Sampling.

Each is MAP-Elites (`qd_recipe`) with the registry's GA emitters, whose cells keep their
elites' samples (`qdrl.qd.repertoires.accumulating`) and whose emitter lays its offspring
into the batch the repertoire plans (`qdrl.qd.emitters.resampling`): part of each
iteration's `emitter.batch_size` evaluations re-evaluate stored solutions, so a run spends
exactly as many evaluations as MAP-Elites with the same batch. The `[resampling]` section:

    [resampling]
    reevaluations = 256   # at most this many rows of each batch re-evaluate stored solutions
    max_samples = 0       # cap on samples (0: none); see AccumulatingRepertoire
    statistic = "median"  # parallel_adaptive_sampling: the elites' count statistic setting m
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, Literal

from qdrl.algorithms.base import BuildContext, ExperimentConfig, Recipe
from qdrl.algorithms.qd import parse_repertoire, qd_recipe, registry_source
from qdrl.config import ConfigError, NonNegativeInt, PositiveInt, build, check_table
from qdrl.qd.emitters.qd_rl import QDRLParts
from qdrl.qd.emitters.registry import GA_KINDS, EmitterFamily, parse_emitters
from qdrl.qd.emitters.resampling import ResamplingEmitter
from qdrl.qd.repertoires.accumulating import AccumulatingRepertoire, Method, accumulating_repertoire
from qdrl.tasks import Task

__all__ = [
    "ADAPTIVE_SAMPLING",
    "ARCHIVE_SAMPLING",
    "PARALLEL_ADAPTIVE_SAMPLING",
    "ResamplingConfig",
    "Sampled",
    "sampling_recipe",
]


@dataclasses.dataclass(frozen=True)
class ResamplingConfig:
    """The `[resampling]` section: how much of each batch re-evaluates stored solutions."""

    # at most this many rows of each iteration's batch re-evaluate stored solutions (the least-sampled
    # elites; Adaptive-Sampling: challenged elites, then challengers); the other rows are offspring
    reevaluations: PositiveInt = 256
    # 0: no cap; else archive_sampling and parallel_adaptive_sampling stop re-evaluating an elite
    # with this many samples, parallel_adaptive_sampling samples an offspring at most this many
    # times, and an adaptive_sampling challenger wins with this many
    max_samples: NonNegativeInt = 0
    # parallel_adaptive_sampling: each offspring takes m rows, m this statistic of the elites'
    # sample counts (Flageat & Cully's `use_evals`; median in their runs)
    statistic: Literal["median", "max", "min", "mean"] = "median"


@dataclasses.dataclass(frozen=True)
class Sampled:
    """A sampling method's emitter config: the GA's `[emitter]` and `[resampling]`."""

    emitter: Any
    resampling: ResamplingConfig

    @property
    def offspring(self) -> int:
        """Rows evaluated per iteration (re-evaluations included): the GA's batch."""
        return int(self.emitter.offspring)


_FAMILY = EmitterFamily({"kind": "isoline"}, GA_KINDS, pool=False)


def _parse(spec: Mapping[str, Any], exp: ExperimentConfig, defaults: Mapping[str, Any], method: str) -> Sampled:
    del exp
    rep = parse_repertoire(spec, "grid", {})
    if rep.kind not in ("grid", "cvt"):
        raise ConfigError(f"repertoire.kind: {method} keeps its samples in grid or cvt cells; got {rep.kind!r}")
    if rep.annealed:
        raise ConfigError(
            f"repertoire.learning_rate: {method} keeps no CMA-MAE thresholds; expected learning_rate 1 and "
            "threshold_min -inf"
        )
    emitter = parse_emitters(spec, _FAMILY)
    resampling: ResamplingConfig = build(
        ResamplingConfig, {**defaults, **check_table(spec.get("resampling", {}), "resampling")}, "resampling"
    )
    if resampling.reevaluations >= emitter.offspring:
        raise ConfigError(
            f"resampling.reevaluations: expected below emitter.batch_size={emitter.offspring} (the other "
            f"rows are offspring), got {resampling.reevaluations}"
        )
    return Sampled(emitter, resampling)


def _build(config: Sampled, task: Task, ctx: BuildContext) -> QDRLParts:
    parts = registry_source(_FAMILY).build(config.emitter, task, ctx)
    return parts._replace(emitter=ResamplingEmitter(parts.emitter))


def _cells_as(method: Method) -> Any:
    def cells_as(cells: Any, config: Sampled) -> AccumulatingRepertoire:
        r = config.resampling
        return accumulating_repertoire(cells, method, r.reevaluations, r.max_samples, r.statistic)

    return cells_as


def sampling_recipe(method: Method, description: str, resampling: Mapping[str, Any] | None = None) -> Recipe:
    """The recipe of `method` (see `qdrl.qd.repertoires.accumulating`): MAP-Elites with the GA
    emitters on accumulating grid (default) or CVT cells; `resampling`: defaults of `[resampling]`."""
    defaults = dict(resampling or {})
    source = dataclasses.replace(
        registry_source(_FAMILY),
        parse=lambda spec, exp: _parse(spec, exp, defaults, method),
        tables=lambda c: {"emitter": c.emitter, "resampling": c.resampling},
        config_of=lambda s: Sampled(s["emitter"], s["resampling"]),
        build=_build,
        uses_cma_es=lambda c: False,
    )
    return qd_recipe(source, description=description, cells_as=_cells_as(method))


ARCHIVE_SAMPLING = sampling_recipe(
    "archive_sampling", "Archive-Sampling (Flageat & Cully 2023): elites re-evaluated, kept at their means",
)
ADAPTIVE_SAMPLING = sampling_recipe(
    "adaptive_sampling", "Adaptive-Sampling (Justesen et al. 2019): challengers sampled until decided",
)
PARALLEL_ADAPTIVE_SAMPLING = sampling_recipe(
    "parallel_adaptive_sampling",
    "Parallel-Adaptive-Sampling (Flageat & Cully 2023): Archive-Sampling, offspring sampled m times",
)
