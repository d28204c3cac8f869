"""Tests for qdrl.qd.emitters.multi: concatenation order, update routing, split_batch."""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.emitters import MultiEmitter, isoline_emitter, split_batch


class CounterState(NamedTuple):
    emits: jax.Array  # how many times this emitter's offspring were updated on
    tag_sum: jax.Array  # sum of the genotype tags it was given back
    fitness_sum: jax.Array
    rows: jax.Array  # how many rows it was given back
    added_sum: jax.Array
    extras_shape: jax.Array  # (T, n) of the extras["transitions"] it saw


@dataclasses.dataclass(eq=False)
class TaggedEmitter:
    """Emits rows filled with its tag; its state counts what `update` hands it."""

    batch_size: int
    tag: float

    def init(self, key, repertoire, evaluation, genotypes) -> CounterState:
        zero = jnp.zeros((), jnp.float32)
        return CounterState(zero, zero, zero, zero, zero, jnp.zeros((2,), jnp.int32))

    def emit(self, state, repertoire, key) -> dict[str, jax.Array]:
        return {
            "x": jnp.full((self.batch_size, 2), self.tag),
            "y": jnp.full((self.batch_size,), self.tag) + state.emits,
        }

    def update(self, state, repertoire, genotypes, evaluation, added, key) -> CounterState:
        transitions = evaluation.extras["transitions"]
        return CounterState(
            emits=state.emits + 1,
            tag_sum=state.tag_sum + jnp.sum(genotypes["x"][:, 0]),
            fitness_sum=state.fitness_sum + jnp.sum(evaluation.fitnesses),
            rows=state.rows + genotypes["x"].shape[0] + 0 * evaluation.descriptors.shape[0],
            added_sum=state.added_sum + jnp.sum(added.improvement),
            extras_shape=jnp.asarray(transitions.shape[:2], jnp.int32),
        )


class Sampler(NamedTuple):
    genotypes: jax.Array
    fitnesses: jax.Array

    def sample(self, key: jax.Array, num_samples: int) -> jax.Array:
        idx = jax.random.randint(key, (num_samples,), 0, self.genotypes.shape[0])
        return self.genotypes[idx]


def evaluation_and_added(n: int) -> tuple[Evaluation, AddResult]:
    fitnesses = jnp.arange(n, dtype=jnp.float32)
    evaluation = Evaluation(
        fitnesses=fitnesses,
        descriptors=jnp.stack([fitnesses, -fitnesses], axis=1),
        extras={"transitions": jnp.zeros((4, n, 3))},
        env_steps=jnp.asarray(40, jnp.int32),
    )
    added = AddResult(
        added=jnp.ones((n,), bool),
        new_cell=jnp.zeros((n,), bool),
        improvement=10.0 * fitnesses,
        cell=jnp.arange(n, dtype=jnp.int32),
    )
    return evaluation, added


def test_emit_concatenates_in_emitter_order() -> None:
    multi = MultiEmitter((TaggedEmitter(3, 1.0), TaggedEmitter(2, 2.0)))
    assert multi.batch_size == 5 and multi.slices == ((0, 3), (3, 5))
    state = multi.init(jax.random.PRNGKey(0), None, None, None)  # type: ignore[arg-type]
    assert isinstance(state, tuple) and len(state) == 2
    offspring = jax.jit(multi.emit)(state, None, jax.random.PRNGKey(1))
    np.testing.assert_array_equal(offspring["x"][:, 0], [1, 1, 1, 2, 2])
    np.testing.assert_array_equal(offspring["y"], [1, 1, 1, 2, 2])


@pytest.mark.parametrize("split_extras", [False, True])
def test_update_routes_each_slice_to_its_emitter(split_extras: bool) -> None:
    axes = {"transitions": 1} if split_extras else {}
    multi = MultiEmitter((TaggedEmitter(3, 1.0), TaggedEmitter(2, 2.0)), extras_batch_axis=axes)
    state = multi.init(jax.random.PRNGKey(0), None, None, None)  # type: ignore[arg-type]
    genotypes = multi.emit(state, None, jax.random.PRNGKey(1))
    evaluation, added = evaluation_and_added(5)
    update = jax.jit(multi.update)
    state = update(state, None, genotypes, evaluation, added, jax.random.PRNGKey(2))
    state = update(state, None, genotypes, evaluation, added, jax.random.PRNGKey(3))
    first, second = state
    assert float(first.emits) == 2 and float(second.emits) == 2
    assert float(first.tag_sum) == 2 * 3 * 1.0 and float(second.tag_sum) == 2 * 2 * 2.0
    assert float(first.fitness_sum) == 2 * (0 + 1 + 2) and float(second.fitness_sum) == 2 * (3 + 4)
    assert float(first.rows) == 6 and float(second.rows) == 4
    assert float(first.added_sum) == 2 * 30.0 and float(second.added_sum) == 2 * 70.0
    if split_extras:
        np.testing.assert_array_equal(first.extras_shape, [4, 3])
        np.testing.assert_array_equal(second.extras_shape, [4, 2])
    else:  # whole, e.g. every transition into an actor-critic emitter's replay buffer
        np.testing.assert_array_equal(first.extras_shape, [4, 5])
        np.testing.assert_array_equal(second.extras_shape, [4, 5])
    # the states feed back into emit
    offspring = multi.emit(state, None, jax.random.PRNGKey(4))
    np.testing.assert_array_equal(offspring["y"], [3, 3, 3, 4, 4])


def test_with_a_ga_emitter_and_in_a_scan() -> None:
    ga = isoline_emitter(4, iso_sigma=0.1, line_sigma=0.1)

    # the GA emitter's genotypes are plain arrays, the tagged one's a dict: wrap to match
    @dataclasses.dataclass(eq=False)
    class AsDict:
        inner: Any
        batch_size: int = 4

        def init(self, *args: Any) -> None:
            return None

        def emit(self, state, repertoire, key):
            x = self.inner.emit(state, repertoire, key)
            return {"x": x, "y": x[:, 0]}

        def update(self, state, *args: Any) -> None:
            return None

    multi = MultiEmitter((AsDict(ga), TaggedEmitter(2, 5.0)))
    repertoire = Sampler(jnp.zeros((3, 2)), jnp.zeros(3))
    state = multi.init(jax.random.PRNGKey(0), repertoire, None, None)  # type: ignore[arg-type]
    evaluation, added = evaluation_and_added(6)

    def step(carry, key):
        emit_key, update_key = jax.random.split(key)
        offspring = multi.emit(carry, repertoire, emit_key)
        return multi.update(carry, repertoire, offspring, evaluation, added, update_key), offspring

    final, offspring = jax.jit(
        lambda s: jax.lax.scan(step, s, jax.random.split(jax.random.PRNGKey(1), 3))
    )(state)
    assert offspring["x"].shape == (3, 6, 2)
    np.testing.assert_array_equal(offspring["x"][:, 4:], 5.0)
    assert float(final[1].emits) == 3 and final[0] is None


def test_wrong_sizes_and_states_are_reported() -> None:
    class Liar(TaggedEmitter):
        def emit(self, state, repertoire, key):
            return {
                "x": jnp.zeros((self.batch_size + 1, 2)),
                "y": jnp.zeros((self.batch_size + 1,)),
            }

    multi = MultiEmitter((TaggedEmitter(2, 1.0), Liar(2, 2.0)))
    state = multi.init(jax.random.PRNGKey(0), None, None, None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"emitter 1 .* batch_size 2"):
        multi.emit(state, None, jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="tuple of 2 sub-states"):
        multi.emit(state[:1], None, jax.random.PRNGKey(0))
    evaluation, added = evaluation_and_added(3)
    with pytest.raises(ValueError, match="expected 4 evaluations"):
        multi.update(state, None, None, evaluation, added, jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="at least one emitter"):
        MultiEmitter(())


def test_split_batch_examples() -> None:
    assert split_batch(100, (0.5, 0.5)) == (50, 50)
    assert split_batch(10, (1, 1, 1)) == (4, 3, 3)
    assert split_batch(5, (0.5, 0.5)) == (3, 2)
    assert split_batch(7, (0.0, 1.0)) == (0, 7)
    assert split_batch(64, (0.75, 0.25)) == (48, 16)
    with pytest.raises(ValueError):
        split_batch(4, (0.0, 0.0))
    with pytest.raises(ValueError):
        split_batch(4, (-1.0, 2.0))


@settings(max_examples=60, deadline=None, database=None)
@given(
    batch_size=st.integers(min_value=0, max_value=1000),
    shares=st.lists(st.floats(min_value=0.0, max_value=10.0), min_size=1, max_size=5).filter(
        lambda s: sum(s) > 1e-3
    ),
)
def test_split_batch_sums_and_stays_within_one_of_exact(
    batch_size: int, shares: list[float]
) -> None:
    sizes = split_batch(batch_size, shares)
    assert sum(sizes) == batch_size and all(s >= 0 for s in sizes)
    total = sum(shares)
    for size, share in zip(sizes, shares, strict=True):
        assert abs(size - batch_size * share / total) < 1.0 + 1e-6
