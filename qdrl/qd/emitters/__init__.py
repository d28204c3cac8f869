"""Emitters: what proposes offspring to the QD loop (`qdrl.qd.base.Emitter`)."""

from __future__ import annotations

from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig, CMAEmitterState
from qdrl.qd.emitters.ga import (
    GAConfig,
    GAEmitter,
    MutationFn,
    VariationFn,
    ga_emitter,
    gaussian_mutation,
    isoline_emitter,
    isoline_variation,
    polynomial_crossover,
    polynomial_emitter,
    polynomial_mutation,
)
from qdrl.qd.emitters.mega import (
    CMAMegaConfig,
    CMAMegaEmitter,
    CMAMegaState,
    OMGMegaConfig,
    OMGMegaEmitter,
)
from qdrl.qd.emitters.multi import MultiEmitter, concat_batches, split_batch
from qdrl.qd.emitters.rankers import RANKERS, Outcome, outcome, rank
from qdrl.qd.emitters.registry import (
    EMITTER_KINDS,
    EmitterContext,
    build_emitter,
    build_pool,
    parse_emitter,
)
from qdrl.qd.emitters.scheduler import (
    BanditScheduler,
    BanditState,
    SchedulerConfig,
    StatelessInstances,
)

__all__ = [
    "EMITTER_KINDS",
    "RANKERS",
    "BanditScheduler",
    "BanditState",
    "CMAEmitter",
    "CMAEmitterConfig",
    "CMAEmitterState",
    "CMAMegaConfig",
    "CMAMegaEmitter",
    "CMAMegaState",
    "EmitterContext",
    "GAConfig",
    "GAEmitter",
    "MultiEmitter",
    "MutationFn",
    "OMGMegaConfig",
    "OMGMegaEmitter",
    "Outcome",
    "SchedulerConfig",
    "StatelessInstances",
    "VariationFn",
    "build_emitter",
    "build_pool",
    "concat_batches",
    "ga_emitter",
    "gaussian_mutation",
    "isoline_emitter",
    "isoline_variation",
    "outcome",
    "parse_emitter",
    "polynomial_crossover",
    "polynomial_emitter",
    "polynomial_mutation",
    "rank",
    "split_batch",
]
