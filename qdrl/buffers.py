"""Jittable ring replay buffer whose storage is any pytree.

A buffer is a `ReplayBuffer` NamedTuple, so it travels through `jax.jit`,
`jax.lax.scan` and `jax.vmap` (one buffer per population member) like any other
state. Items are arbitrary pytrees — a `qdrl.types.Transition`, or a Transition
plus extra per-transition fields such as an episode return — and every leaf of
the storage carries a leading axis of length `capacity`.

Typical use::

    buffer = buffers.init(example_transition, capacity=1_000_000)
    buffer = buffers.insert(buffer, batch_of_transitions)   # leading axis n
    batch = buffers.sample(buffer, key, batch_size=256)
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.types import Array, PRNGKey, PyTree

__all__ = [
    "ReplayBuffer",
    "TrajectoryBuffer",
    "can_sample",
    "init",
    "insert",
    "sample",
    "trajectory_init",
    "trajectory_insert",
    "trajectory_sample",
]


class ReplayBuffer(NamedTuple):
    """Ring buffer of pytree items; the oldest items are overwritten first.

    Attributes:
      data: pytree of storage arrays, each with leading axis `capacity`. Slots
        at index >= `size` have never been written and hold zeros.
      position: int32 scalar, the slot the next item is written to.
      size: int32 scalar, number of valid items (`<= capacity`).
    """

    data: PyTree
    position: Array
    size: Array

    @property
    def capacity(self) -> int:
        """Number of slots: the static leading dimension of the storage leaves."""
        return int(jax.tree_util.tree_leaves(self.data)[0].shape[0])


def _shape_dtype(leaf: Any) -> tuple[tuple[int, ...], np.dtype]:
    # `jax.ShapeDtypeStruct`, jax and numpy arrays all expose shape and dtype;
    # Python scalars go through jnp so they take JAX's default dtypes.
    if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
        return tuple(leaf.shape), np.dtype(leaf.dtype)
    arr = jnp.asarray(leaf)
    return tuple(arr.shape), np.dtype(arr.dtype)


def init(example: PyTree, capacity: int) -> ReplayBuffer:
    """Returns an empty buffer holding up to `capacity` items shaped like `example`.

    Args:
      example: one item, without batch axis. Leaves may be arrays, scalars or
        `jax.ShapeDtypeStruct`; only their shapes and dtypes are used.
      capacity: number of slots, > 0.

    Returns:
      A `ReplayBuffer` with zeroed storage, `position == size == 0`.
    """
    if isinstance(capacity, bool) or not isinstance(capacity, int | np.integer) or capacity <= 0:
        raise ValueError(f"capacity must be a positive int, got {capacity!r}")
    if not jax.tree_util.tree_leaves(example):
        raise ValueError("example has no leaves; a buffer needs at least one array to store")

    def zeros(leaf: Any) -> Array:
        shape, dtype = _shape_dtype(leaf)
        return jnp.zeros((int(capacity), *shape), dtype)

    return ReplayBuffer(
        data=jax.tree_util.tree_map(zeros, example),
        position=jnp.zeros((), jnp.int32),
        size=jnp.zeros((), jnp.int32),
    )


def _check_items(buffer: ReplayBuffer, items: PyTree) -> int:
    """Returns the batch size of `items` after checking them against the storage."""
    # Any: mypy cannot resolve jaxlib's PyTreeDef type and rejects comparing it.
    data_def: Any = jax.tree_util.tree_structure(buffer.data)
    items_def: Any = jax.tree_util.tree_structure(items)
    if items_def != data_def:
        raise ValueError(
            f"insert: items structure does not match the buffer.\n"
            f"  expected: {data_def}\n  got:      {items_def}"
        )
    storage = jax.tree_util.tree_leaves(buffer.data)
    named_items = jax.tree_util.tree_flatten_with_path(items)[0]
    batch: int | None = None
    batch_from = ""
    for (path, item), store in zip(named_items, storage, strict=True):
        name = jax.tree_util.keystr(path) or "<root>"
        shape, dtype = _shape_dtype(item)
        want_shape, want_dtype = tuple(store.shape[1:]), np.dtype(store.dtype)
        if len(shape) != len(want_shape) + 1 or shape[1:] != want_shape or dtype != want_dtype:
            raise ValueError(
                f"insert: items leaf {name} must have shape (n, *{want_shape}) and dtype "
                f"{want_dtype} (a leading batch axis, then the item shape); "
                f"got shape {shape} and dtype {dtype}"
            )
        if batch is None:
            batch, batch_from = shape[0], name
        elif shape[0] != batch:
            raise ValueError(
                f"insert: all items leaves must share the batch size; leaf {batch_from} "
                f"has {batch}, leaf {name} has {shape[0]}"
            )
    assert batch is not None  # init() guarantees at least one leaf
    return batch


def insert(buffer: ReplayBuffer, items: PyTree, num_valid: Array | None = None) -> ReplayBuffer:
    """Writes a batch of items at `position`, wrapping around the ring.

    Item `i` of the batch goes to slot `(position + i) % capacity`. When the
    batch is larger than the buffer only its last `capacity` items are kept,
    which is exactly what writing them one by one would leave behind.

    Args:
      buffer: the buffer to write to.
      items: pytree with the storage's structure; each leaf has a leading batch
        axis `n` (static) followed by the item shape, with the storage dtype.
      num_valid: when given (a traced integer in [0, n]), only the first
        `num_valid` items are written and `position` / `size` advance by that
        many: a static batch shape with a data-dependent count (e.g. the steps
        of episodes that ended early). Needs `n <= capacity`.

    Returns:
      The updated buffer. Jittable; shapes are checked at trace time.

    Raises:
      ValueError: if the structure, shapes or dtypes of `items` do not match.
    """
    n = _check_items(buffer, items)
    if n == 0:
        return buffer
    capacity = buffer.capacity
    if num_valid is not None:
        return _insert_first(buffer, items, n, jnp.clip(num_valid, 0, n).astype(jnp.int32))
    kept = min(n, capacity)
    if kept < n:
        items = jax.tree_util.tree_map(lambda x: x[n - kept :], items)
    # The first kept item is item `n - kept` of the batch; its slot follows the
    # ring from the current position. `kept <= capacity` makes the indices unique.
    start = (buffer.position + (n - kept)) % capacity
    idx = (start + jnp.arange(kept, dtype=jnp.int32)) % capacity
    data = jax.tree_util.tree_map(
        lambda store, x: store.at[idx].set(x, unique_indices=True), buffer.data, items
    )
    return ReplayBuffer(
        data=data,
        position=((buffer.position + n) % capacity).astype(jnp.int32),
        size=jnp.minimum(buffer.size + n, capacity).astype(jnp.int32),
    )


def _insert_first(buffer: ReplayBuffer, items: PyTree, n: int, num_valid: Array) -> ReplayBuffer:
    """`insert` of the first `num_valid` of `n` items; the others' writes are dropped."""
    capacity = buffer.capacity
    if n > capacity:
        raise ValueError(
            f"insert with num_valid: expected a batch of at most the capacity ({capacity}) items, "
            f"got {n}"
        )
    i = jnp.arange(n, dtype=jnp.int32)
    # Slot `capacity` is out of range: scatter mode "drop" skips the invalid items.
    idx = jnp.where(i < num_valid, (buffer.position + i) % capacity, capacity)
    data = jax.tree_util.tree_map(
        lambda store, x: store.at[idx].set(x, mode="drop"), buffer.data, items
    )
    return ReplayBuffer(
        data=data,
        position=((buffer.position + num_valid) % capacity).astype(jnp.int32),
        size=jnp.minimum(buffer.size + num_valid, capacity).astype(jnp.int32),
    )


def can_sample(buffer: ReplayBuffer, batch_size: int) -> Array:
    """Returns a bool scalar: True once the buffer holds at least `batch_size` items.

    Use it to gate learning during warm-up (e.g. inside `jax.lax.cond`);
    `sample` on a buffer for which this is False still runs but is not uniform
    over real data (see `sample`).
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    return buffer.size >= batch_size


def sample(buffer: ReplayBuffer, key: PRNGKey, batch_size: int) -> PyTree:
    """Draws `batch_size` items uniformly, with replacement, from the valid items.

    Args:
      buffer: a buffer with `size >= 1` (check with `can_sample`).
      key: PRNG key.
      batch_size: static number of items to draw.

    Returns:
      A pytree like the storage with leading axis `batch_size`.

    On an empty buffer (`size == 0`) every index is 0 and the batch is the
    zeros of the unwritten slot 0; no error is raised because `size` is traced.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    idx = jax.random.randint(key, (batch_size,), 0, buffer.size)
    return jax.tree_util.tree_map(lambda store: store[idx], buffer.data)


# --- Trajectory buffer: transitions that know their episode's return (SMERL) ---


class TrajectoryBuffer(NamedTuple):
    """A ring buffer whose items also know the return of the episode they belong to.

    SMERL (Kumar et al. 2020, "One Solution is Not All You Need", eq. 3) gates each
    transition's diversity reward on its *episode's* return, known only once the
    episode ends. Each transition is written at once into `ring` with the id of
    its episode; when an episode ends its return is written into a table slot
    `id % table_size`, tagged with the id. `trajectory_sample` looks the return up
    by id: transitions of episodes still running, or of episodes whose table slot
    has since been reused, get NaN (a NaN return never passes a `>=` gate).

    Attributes:
      ring: a `ReplayBuffer` of `(item, episode_id)` pairs.
      returns: (table_size,) float32, returns of finished episodes (NaN if none).
      return_ids: (table_size,) int32, the episode id each `returns` slot holds (-1 if none).
      episode_ids: (num_envs,) int32, the id of each environment's running episode.
      next_id: int32 scalar, the id the next episode to start gets.
    """

    ring: ReplayBuffer
    returns: Array
    return_ids: Array
    episode_ids: Array
    next_id: Array

    @property
    def size(self) -> Array:
        """Number of valid transitions, as `ReplayBuffer.size`."""
        return self.ring.size

    @property
    def capacity(self) -> int:
        return self.ring.capacity


def trajectory_init(example: PyTree, capacity: int, num_envs: int) -> TrajectoryBuffer:
    """An empty trajectory buffer of `capacity` items written by `num_envs` environments.

    The return table has `capacity + num_envs` slots, one per episode that can own a
    stored transition in the common case (episodes at least as long as the number
    of environments ending together). A slot reused by a newer episode is detected
    by its id tag: the older transitions then read NaN, never another episode's return.
    """
    if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs <= 0:
        raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
    ring = init((example, jnp.zeros((), jnp.int32)), capacity)
    table = int(capacity) + int(num_envs)
    return TrajectoryBuffer(
        ring=ring,
        returns=jnp.full((table,), jnp.nan, jnp.float32),
        return_ids=jnp.full((table,), -1, jnp.int32),
        episode_ids=jnp.arange(num_envs, dtype=jnp.int32),
        next_id=jnp.asarray(num_envs, jnp.int32),
    )


def trajectory_insert(
    buffer: TrajectoryBuffer, items: PyTree, done: Array, episode_return: Array
) -> TrajectoryBuffer:
    """Writes one step of the `num_envs` environments, and the returns of the episodes it ends.

    Args:
      buffer: the buffer.
      items: pytree whose leaves have leading axis `num_envs` (one transition per env).
      done: (num_envs,) nonzero where this step ended the env's episode.
      episode_return: (num_envs,) the ended episodes' returns (read where `done`).

    Returns:
      The buffer with the items stored under their episodes' ids; each ended
      episode's return recorded, and its environment given a fresh id.
    """
    num_envs = buffer.episode_ids.shape[0]
    done = jnp.asarray(done) > 0
    want = (num_envs,)
    if done.shape != want or jnp.shape(episode_return) != want:
        raise ValueError(
            f"trajectory_insert: done and episode_return must have shape {want}, "
            f"got {done.shape} and {jnp.shape(episode_return)}"
        )
    ring = insert(buffer.ring, (items, buffer.episode_ids))
    table = buffer.returns.shape[0]
    # Environments that did not finish write to an out-of-range slot, which "drop" discards.
    slot = jnp.where(done, buffer.episode_ids % table, table)
    returns = buffer.returns.at[slot].set(episode_return.astype(jnp.float32), mode="drop")
    return_ids = buffer.return_ids.at[slot].set(buffer.episode_ids, mode="drop")
    rank = jnp.cumsum(done.astype(jnp.int32)) - 1
    episode_ids = jnp.where(done, buffer.next_id + rank, buffer.episode_ids)
    return TrajectoryBuffer(
        ring=ring,
        returns=returns,
        return_ids=return_ids,
        episode_ids=episode_ids.astype(jnp.int32),
        next_id=(buffer.next_id + jnp.sum(done, dtype=jnp.int32)).astype(jnp.int32),
    )


def trajectory_sample(
    buffer: TrajectoryBuffer, key: PRNGKey, batch_size: int
) -> tuple[PyTree, Array]:
    """Draws `batch_size` items uniformly with replacement, with their episodes' returns.

    Returns:
      `(items, episode_returns)`: the items (leading axis `batch_size`) and a
      (batch_size,) float32 array, NaN for a transition whose episode has not
      ended yet (or whose return was overwritten).
    """
    items, ids = sample(buffer.ring, key, batch_size)
    slot = ids % buffer.returns.shape[0]
    known = buffer.return_ids[slot] == ids
    return items, jnp.where(known, buffer.returns[slot], jnp.nan)
