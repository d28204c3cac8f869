"""Repeated evaluation: each candidate scored several times, its fitness and descriptor the means.

The naive answer to a noisy task (MAP-Elites-sampling, the baseline of Flageat & Cully 2023,
"Uncertain Quality-Diversity: evaluation methodology and new methods for Quality-Diversity in
uncertain domains", IEEE TEVC; QDax's `multi_sample_scoring_function` and `sampling`): a
candidate's N evaluations draw independent keys, and the repertoire sees their averages. With
a plain repertoire it is ME-Sampling; ME-LS (`qdrl.qd.repertoires.mels`) reads the samples
themselves from `extras["samples"]`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from qdrl.qd.base import SAMPLES, Evaluation, ScoringFn
from qdrl.types import Genotype, PRNGKey

__all__ = ["sampled_scoring"]


def sampled_scoring(scoring_fn: ScoringFn, num_samples: int) -> ScoringFn:
    """`scoring_fn` evaluating each of the n candidates `num_samples` (N) times, sample j with
    the j-th of N keys split from the evaluation's key (one vmapped call).

    The evaluation's fitness and descriptor are the means over the samples (QDax `sampling`'s
    default extractors), its env steps their sum, and `extras["samples"]` holds the samples,
    batch-major: {"fitnesses": (n, N), "descriptors": (n, N, D)}; the other extras are those
    of the first sample. A failed sample (NaN) makes the mean NaN, so the candidate is rejected.
    The QD loop counts n x N evaluations for the batch (`qdrl.qd.base.evaluations_spent`).
    N = 1 returns `scoring_fn` itself.
    """
    if not isinstance(num_samples, int) or num_samples < 1:
        raise ValueError(f"sampling.num_samples: expected a positive integer, got {num_samples!r}")
    if num_samples == 1:
        return scoring_fn

    def scoring(genotypes: Genotype, key: PRNGKey) -> Evaluation:
        keys = jax.random.split(key, num_samples)
        ev = jax.vmap(scoring_fn, in_axes=(None, 0))(genotypes, keys)  # every leaf (N, ...)
        fitnesses = jnp.swapaxes(jnp.asarray(ev.fitnesses, jnp.float32), 0, 1)  # (n, N)
        descriptors = jnp.swapaxes(jnp.asarray(ev.descriptors, jnp.float32), 0, 1)  # (n, N, D)
        extras = {name: jax.tree.map(lambda x: x[0], value) for name, value in ev.extras.items()}
        extras[SAMPLES] = {"fitnesses": fitnesses, "descriptors": descriptors}
        return Evaluation(
            fitnesses=jnp.mean(fitnesses, axis=1),
            descriptors=jnp.mean(descriptors, axis=1),
            extras=extras,
            env_steps=jnp.sum(jnp.asarray(ev.env_steps, jnp.int32)),
        )

    return scoring
