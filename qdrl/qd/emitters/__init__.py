"""Emitters: what proposes offspring to the QD loop (`qdrl.qd.base.Emitter`)."""

from __future__ import annotations

from qdrl.qd.emitters.ga import (
    GAEmitter,
    MutationFn,
    VariationFn,
    gaussian_mutation,
    isoline_emitter,
    isoline_variation,
    polynomial_crossover,
    polynomial_emitter,
    polynomial_mutation,
)
from qdrl.qd.emitters.multi import MultiEmitter, concat_batches, split_batch

__all__ = [
    "GAEmitter",
    "MultiEmitter",
    "MutationFn",
    "VariationFn",
    "concat_batches",
    "gaussian_mutation",
    "isoline_emitter",
    "isoline_variation",
    "polynomial_crossover",
    "polynomial_emitter",
    "polynomial_mutation",
    "split_batch",
]
