"""Tests for qdrl.buffers: ring semantics against a deque model, sampling, jit, errors."""

from __future__ import annotations

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl import buffers
from qdrl.types import Transition

# Items are identified by an integer payload >= 1, so an unwritten (zero) slot
# can never be mistaken for a real item. `v` repeats the payload to check that
# all leaves of one item stay together.
EXAMPLE = {"x": jnp.zeros((), jnp.int32), "v": jnp.zeros((2,), jnp.float32)}


def make_items(first: int, n: int) -> dict[str, jax.Array]:
    ids = np.arange(first, first + n, dtype=np.int32)
    return {
        "x": jnp.asarray(ids),
        "v": jnp.asarray(np.stack([ids, -ids], axis=-1).astype(np.float32)),
    }


def fill(capacity: int, batch_sizes: list[int], insert_fn=buffers.insert):
    """Inserts consecutive payloads in batches; returns the buffer and a deque model."""
    buffer = buffers.init(EXAMPLE, capacity)
    model: deque[int] = deque(maxlen=capacity)
    nxt = 1
    for n in batch_sizes:
        buffer = insert_fn(buffer, make_items(nxt, n))
        model.extend(range(nxt, nxt + n))
        nxt += n
    return buffer, model, nxt - 1


capacities = st.integers(min_value=1, max_value=8)
batch_lists = st.lists(st.integers(min_value=0, max_value=12), min_size=1, max_size=6)


@settings(max_examples=40, deadline=None, database=None)
@given(capacity=capacities, batch_sizes=batch_lists)
def test_insert_matches_deque_model(capacity: int, batch_sizes: list[int]) -> None:
    buffer, model, total = fill(capacity, batch_sizes)

    assert buffer.capacity == capacity
    assert buffer.size.dtype == jnp.int32 and buffer.position.dtype == jnp.int32
    assert int(buffer.size) == min(total, capacity)
    assert int(buffer.position) == total % capacity

    x = np.asarray(buffer.data["x"])
    v = np.asarray(buffer.data["v"])
    size = int(buffer.size)
    # Multiset of valid items equals the last `capacity` inserted.
    assert sorted(x[:size].tolist()) == sorted(model)
    # Stronger: item number j (1-based) sits in slot (j - 1) % capacity.
    for j in model:
        assert x[(j - 1) % capacity] == j
    # Leaves of one item stay aligned, and unwritten slots are still zero.
    np.testing.assert_array_equal(v[:, 0], x.astype(np.float32))
    np.testing.assert_array_equal(v[:, 1], -x.astype(np.float32))
    assert (x[size:] == 0).all()


@settings(max_examples=30, deadline=None, database=None)
@given(capacity=capacities, batch_sizes=batch_lists, seed=st.integers(0, 2**31 - 1))
def test_sample_only_returns_valid_items(capacity: int, batch_sizes: list[int], seed: int) -> None:
    buffer, model, _ = fill(capacity, batch_sizes)
    if not model:
        assert not bool(buffers.can_sample(buffer, 1))
        return
    batch = buffers.sample(buffer, jax.random.PRNGKey(seed), 16)
    ids = np.asarray(batch["x"])
    assert ids.shape == (16,) and batch["v"].shape == (16, 2)
    assert set(ids.tolist()) <= set(model)
    np.testing.assert_array_equal(np.asarray(batch["v"])[:, 0], ids.astype(np.float32))


_jit_insert = jax.jit(buffers.insert)


@settings(max_examples=25, deadline=None, database=None)
@given(batch_sizes=st.lists(st.sampled_from([1, 3, 7]), min_size=1, max_size=6))
def test_jit_insert_equals_eager(batch_sizes: list[int]) -> None:
    # Few distinct shapes (capacity 5; n in {1, 3, 7}) so the jit cache is reused.
    eager, _, _ = fill(5, batch_sizes)
    jitted, _, _ = fill(5, batch_sizes, insert_fn=_jit_insert)
    for a, b in zip(
        jax.tree_util.tree_leaves(eager), jax.tree_util.tree_leaves(jitted), strict=True
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_insert_in_scan_wraps_like_the_model() -> None:
    capacity, n, steps = 7, 3, 10

    def body(buffer: buffers.ReplayBuffer, t: jax.Array):
        ids = (1 + t * n + jnp.arange(n)).astype(jnp.int32)
        items = {"x": ids, "v": jnp.stack([ids, -ids], axis=-1).astype(jnp.float32)}
        return buffers.insert(buffer, items), None

    buffer, _ = jax.jit(lambda b: jax.lax.scan(body, b, jnp.arange(steps)))(
        buffers.init(EXAMPLE, capacity)
    )
    total = n * steps
    assert int(buffer.size) == capacity
    assert int(buffer.position) == total % capacity
    assert sorted(np.asarray(buffer.data["x"]).tolist()) == list(
        range(total - capacity + 1, total + 1)
    )


def test_batch_larger_than_capacity_keeps_last_items() -> None:
    buffer = buffers.insert(buffers.init(EXAMPLE, 4), make_items(1, 2))
    buffer = buffers.insert(buffer, make_items(3, 10))  # items 3..12, only 9..12 survive
    # Sequential writes would leave item j in slot (j - 1) % 4.
    np.testing.assert_array_equal(np.asarray(buffer.data["x"]), [9, 10, 11, 12])
    assert int(buffer.position) == 12 % 4 and int(buffer.size) == 4


def test_sample_is_uniform_over_valid_items() -> None:
    buffer = buffers.insert(buffers.init(EXAMPLE, 10), make_items(1, 4))
    ids = np.asarray(buffers.sample(buffer, jax.random.PRNGKey(0), 40_000)["x"])
    counts = np.bincount(ids, minlength=11)
    assert counts[0] == 0 and counts[5:].sum() == 0
    # Each of 4 items expects 10_000 draws, std ~87; 5 std is a safe margin.
    np.testing.assert_allclose(counts[1:5], 10_000, atol=450)


def test_empty_buffer_sample_returns_slot_zero_and_can_sample() -> None:
    buffer = buffers.init(EXAMPLE, 3)
    assert not bool(buffers.can_sample(buffer, 1))
    batch = buffers.sample(buffer, jax.random.PRNGKey(0), 5)
    np.testing.assert_array_equal(np.asarray(batch["x"]), np.zeros(5))
    buffer = buffers.insert(buffer, make_items(1, 2))
    assert bool(buffers.can_sample(buffer, 2)) and not bool(buffers.can_sample(buffer, 3))
    assert bool(jax.jit(buffers.can_sample, static_argnums=1)(buffer, 1))


def transition(obs_dim: int = 3, act_dim: int = 2, batch: tuple[int, ...] = ()) -> Transition:
    def f(*shape: int) -> jax.Array:
        return jnp.ones((*batch, *shape), jnp.float32)

    return Transition(
        obs=f(obs_dim),
        action=f(act_dim),
        reward=f(),
        next_obs=f(obs_dim),
        terminated=f(),
        truncated=f(),
        desc=f(2),
        next_desc=f(2),
    )


def test_transition_items_and_extra_fields() -> None:
    # ShapeDtypeStruct leaves are accepted for the example.
    spec = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), transition())
    buffer = buffers.init(spec, 6)
    assert isinstance(buffer.data, Transition)
    assert buffer.data.obs.shape == (6, 3) and buffer.data.reward.shape == (6,)
    buffer = jax.jit(buffers.insert)(buffer, transition(batch=(4,)))
    batch = buffers.sample(buffer, jax.random.PRNGKey(1), 8)
    assert isinstance(batch, Transition)
    assert batch.obs.shape == (8, 3) and batch.action.shape == (8, 2) and batch.reward.shape == (8,)
    np.testing.assert_array_equal(np.asarray(batch.discount_mask), np.zeros(8))

    # Extra per-transition fields (e.g. SMERL's episode return) are just more leaves.
    extra = buffers.init({"t": transition(), "episode_return": jnp.zeros(())}, 6)
    extra = buffers.insert(
        extra, {"t": transition(batch=(2,)), "episode_return": jnp.array([1.0, 2.0])}
    )
    np.testing.assert_array_equal(np.asarray(extra.data["episode_return"]), [1, 2, 0, 0, 0, 0])


def test_vmap_over_a_population_of_buffers() -> None:
    pop = jax.vmap(lambda _: buffers.init(EXAMPLE, 4))(jnp.arange(3))
    items = jax.vmap(lambda i: make_items(1, 2) | {"x": jnp.array([1, 2], jnp.int32) * (i + 1)})(
        jnp.arange(3)
    )
    pop = jax.vmap(buffers.insert)(pop, items)
    np.testing.assert_array_equal(np.asarray(pop.size), [2, 2, 2])
    np.testing.assert_array_equal(np.asarray(pop.data["x"])[:, :2], [[1, 2], [2, 4], [3, 6]])


@pytest.mark.parametrize(
    ("items", "match"),
    [
        (
            {"x": jnp.ones((2,), jnp.int32), "v": jnp.ones((2, 3), jnp.float32)},
            r"\['v'\] must have shape \(n, \*\(2,\)\) and dtype float32.*got shape \(2, 3\)",
        ),
        (
            {"x": jnp.ones((2,), jnp.float32), "v": jnp.ones((2, 2), jnp.float32)},
            r"\['x'\] must have shape \(n, \*\(\)\) and dtype int32.*dtype float32",
        ),
        (
            {"x": jnp.ones((), jnp.int32), "v": jnp.ones((2,), jnp.float32)},
            r"\['v'\].*got shape \(2,\)",
        ),  # forgot the batch axis
        ({"x": jnp.ones((2,), jnp.int32)}, r"structure does not match"),
        (
            {"x": jnp.ones((2,), jnp.int32), "v": jnp.ones((3, 2), jnp.float32)},
            r"share the batch size.*\['v'\] has 3, leaf \['x'\] has 2",
        ),
    ],
)
def test_insert_rejects_mismatched_items(items: dict, match: str) -> None:
    buffer = buffers.init(EXAMPLE, 4)
    with pytest.raises(ValueError, match=match):
        buffers.insert(buffer, items)
    with pytest.raises(ValueError, match=match):
        jax.jit(buffers.insert)(buffer, items)


@pytest.mark.parametrize("capacity", [0, -3, 2.5, True])
def test_init_rejects_bad_capacity(capacity) -> None:
    with pytest.raises(ValueError, match="capacity"):
        buffers.init(EXAMPLE, capacity)


def test_init_rejects_empty_example_and_sample_rejects_bad_batch() -> None:
    with pytest.raises(ValueError, match="no leaves"):
        buffers.init({}, 4)
    buffer = buffers.init(EXAMPLE, 4)
    with pytest.raises(ValueError, match="batch_size"):
        buffers.sample(buffer, jax.random.PRNGKey(0), 0)
    with pytest.raises(ValueError, match="batch_size"):
        buffers.can_sample(buffer, 0)


@settings(max_examples=30, deadline=None, database=None)
@given(
    capacity=st.integers(min_value=4, max_value=8),
    counts=st.lists(st.integers(min_value=0, max_value=4), min_size=1, max_size=6),
)
def test_insert_num_valid_writes_only_the_first_items(capacity: int, counts: list[int]) -> None:
    """A batch of 4 with a traced valid count acts like inserting only its first items."""
    insert = jax.jit(buffers.insert)
    buffer = buffers.init(EXAMPLE, capacity)
    model: deque[int] = deque(maxlen=capacity)
    nxt = 1
    for k in counts:
        batch = make_items(nxt, 4)  # items nxt .. nxt+3, of which the first k are valid
        buffer = insert(buffer, batch, jnp.int32(k))
        model.extend(range(nxt, nxt + k))
        nxt += 4
    written = len(model) if len(model) < capacity else capacity
    total = sum(counts)
    assert int(buffer.size) == min(total, capacity)
    assert int(buffer.position) == total % capacity
    x = np.asarray(buffer.data["x"])
    assert sorted(x[:written].tolist()) == sorted(model)
    # Item number j (1-based among the valid ones) sits in slot (j - 1) % capacity.
    for j, item in enumerate(model, start=total - len(model) + 1):
        assert x[(j - 1) % capacity] == item
    np.testing.assert_array_equal(np.asarray(buffer.data["v"])[:, 0], x.astype(np.float32))


def test_insert_num_valid_rejects_a_batch_larger_than_the_ring() -> None:
    with pytest.raises(ValueError, match="at most the capacity"):
        buffers.insert(buffers.init(EXAMPLE, 2), make_items(1, 3), jnp.int32(1))
