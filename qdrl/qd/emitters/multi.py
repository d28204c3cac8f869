"""Several emitters sharing one batch: each emits its share, each learns from its own offspring.

As QDax's `MultiEmitter` (PGA-ME = GA + Q-PG, QD-PG = GA + Q-PG + D-PG, ME-PBT);
unlike QDax, `update` hands each sub-emitter only the slice of the batch it
produced.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult, Emitter, Evaluation, Repertoire, emitter_metrics
from qdrl.types import Array, Genotype, PRNGKey


def split_batch(batch_size: int, shares: Sequence[float]) -> tuple[int, ...]:
    """Integer sizes proportional to `shares` that sum to `batch_size` (largest remainders).

    `split_batch(100, (0.5, 0.5)) == (50, 50)`; `split_batch(10, (1, 1, 1)) == (4, 3, 3)`:
    each share gets the floor of its exact size, and the units left go to the
    largest fractional parts (the earlier share on ties).
    """
    if batch_size < 0:
        raise ValueError(f"batch_size must be >= 0, got {batch_size}")
    if not shares:
        raise ValueError("shares: expected at least one share")
    if any(s < 0 or not math.isfinite(s) for s in shares):
        raise ValueError(f"shares must be finite and >= 0, got {tuple(shares)}")
    total = float(sum(shares))
    if total <= 0:
        raise ValueError(f"shares must not all be 0, got {tuple(shares)}")
    exact = [batch_size * s / total for s in shares]
    sizes = [math.floor(e + 1e-9) for e in exact]
    left = batch_size - sum(sizes)
    by_remainder = sorted(range(len(shares)), key=lambda i: (-(exact[i] - sizes[i]), i))
    for i in by_remainder[:left]:
        sizes[i] += 1
    return tuple(sizes)


def _slice(tree: Any, start: int, stop: int, axis: int = 0) -> Any:
    return jax.tree.map(lambda x: jax.lax.slice_in_dim(x, start, stop, axis=axis), tree)


def concat_batches(parts: Sequence[Genotype]) -> Genotype:
    """Batches of genotypes (pytrees with a leading axis) joined along that axis, in order."""
    if len(parts) == 1:
        return parts[0]
    return jax.tree.map(lambda *xs: jnp.concatenate(xs, axis=0), *parts)


def tree_select(mask: Array, on_true: Any, on_false: Any) -> Any:
    """Per-row `where`: `mask` (K,) picks rows of pytrees whose leaves lead with K."""

    def pick(a: Array, b: Array) -> Array:
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, on_true, on_false)


@dataclasses.dataclass(eq=False)
class MultiEmitter:
    """Runs `emitters` side by side; batch_size is the sum of theirs, offspring in their order.

    The state is the tuple of the sub-emitters' states. `update` gives sub-emitter
    i its rows of `genotypes`, `evaluation.fitnesses`, `evaluation.descriptors` and
    of every `AddResult` field. `evaluation.extras` entries go whole to every
    sub-emitter (an actor-critic emitter wants every transition for its replay
    buffer) unless named in `extras_batch_axis`, which gives the axis of the
    offspring batch to split them along (e.g. `{"transitions": 1}` for (T, n, ...)
    transitions). `evaluation.env_steps` is passed whole.
    """

    emitters: tuple[Emitter, ...]
    extras_batch_axis: Mapping[str, int] = dataclasses.field(default_factory=dict)
    batch_size: int = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.emitters = tuple(self.emitters)
        if not self.emitters:
            raise ValueError("MultiEmitter needs at least one emitter")
        self.batch_size = sum(int(e.batch_size) for e in self.emitters)

    @property
    def slices(self) -> tuple[tuple[int, int], ...]:
        """(start, stop) rows of each sub-emitter in the concatenated batch."""
        bounds = []
        start = 0
        for emitter in self.emitters:
            bounds.append((start, start + int(emitter.batch_size)))
            start += int(emitter.batch_size)
        return tuple(bounds)

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> tuple[Any, ...]:
        """Each sub-emitter's state from the whole initial population."""
        keys = jax.random.split(key, len(self.emitters))
        return tuple(
            emitter.init(k, repertoire, evaluation, genotypes)
            for emitter, k in zip(self.emitters, keys, strict=True)
        )

    def emit(self, state: tuple[Any, ...], repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """The sub-emitters' offspring, concatenated on axis 0 in emitter order."""
        self._check_state(state)
        keys = jax.random.split(key, len(self.emitters))
        offspring = []
        for i, (emitter, sub_state, k) in enumerate(zip(self.emitters, state, keys, strict=True)):
            genotypes = emitter.emit(sub_state, repertoire, k)
            sizes = {int(leaf.shape[0]) for leaf in jax.tree.leaves(genotypes)}
            if sizes != {int(emitter.batch_size)}:
                raise ValueError(
                    f"emitter {i} ({type(emitter).__name__}) has batch_size {emitter.batch_size} "
                    f"but emitted leading sizes {sorted(sizes)}"
                )
            offspring.append(genotypes)
        return concat_batches(offspring)

    def update(
        self,
        state: tuple[Any, ...],
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> tuple[Any, ...]:
        """Each sub-emitter's update on its own slice of the batch."""
        self._check_state(state)
        n = int(evaluation.fitnesses.shape[0])
        if n != self.batch_size:
            raise ValueError(f"update: expected {self.batch_size} evaluations, got {n}")
        unknown = set(self.extras_batch_axis) - set(evaluation.extras)
        if unknown:
            raise ValueError(
                f"extras_batch_axis names extras the evaluation lacks: {sorted(unknown)}"
            )
        keys = jax.random.split(key, len(self.emitters))
        new_states = []
        for emitter, sub_state, (start, stop), k in zip(
            self.emitters, state, self.slices, keys, strict=True
        ):
            extras = {
                name: (
                    _slice(value, start, stop, self.extras_batch_axis[name])
                    if name in self.extras_batch_axis
                    else value
                )
                for name, value in evaluation.extras.items()
            }
            sub_evaluation = Evaluation(
                fitnesses=evaluation.fitnesses[start:stop],
                descriptors=evaluation.descriptors[start:stop],
                extras=extras,
                env_steps=evaluation.env_steps,
            )
            new_states.append(
                emitter.update(
                    sub_state,
                    repertoire,
                    _slice(genotypes, start, stop),
                    sub_evaluation,
                    _slice(added, start, stop),
                    k,
                )
            )
        return tuple(new_states)

    def log_metrics(self, state: tuple[Any, ...]) -> dict[str, Array]:
        """The sub-emitters' metrics (`qdrl.qd.base.ReportsMetrics`); the first to name one wins."""
        out: dict[str, Array] = {}
        for emitter, sub_state in zip(self.emitters, state, strict=True):
            for name, value in emitter_metrics(emitter, sub_state).items():
                out.setdefault(name, value)
        return out

    def _check_state(self, state: tuple[Any, ...]) -> None:
        if not isinstance(state, tuple) or len(state) != len(self.emitters):
            raise ValueError(
                f"MultiEmitter state: expected a tuple of {len(self.emitters)} sub-states, "
                f"got {type(state).__name__}"
            )
