"""Tests for qdrl.qd.repertoires.sliding: the sliding-boundaries archive against a one-at-a-time
NumPy reference of pyribs' rules (buffer, percentile edges, re-insertion), edges by hand, and
the pytree/jit contract. Batches have a fixed size, so each archive's `add` compiles once."""

from __future__ import annotations

import collections
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.repertoires import grid_repertoire
from qdrl.qd.repertoires.sliding import SlidingBoundariesArchive, sliding_boundaries_archive

SETTINGS = settings(max_examples=15, deadline=None, database=None, derandomize=True)
N = 16  # candidates per batch
EPS = 1e-6
EXAMPLE = {"w": jnp.zeros((2,), jnp.float32), "id": jnp.zeros((), jnp.int32)}
# (dims, low, high, remap_frequency, buffer_capacity): a buffer larger than the period, and
# one smaller (a segment of a batch then overflows it).
CONFIGS = {
    "2d": ((3, 4), (0.0, 0.0), (1.0, 1.0), 5, 7),
    "1d_small_buffer": ((5,), (0.0,), (1.0,), 4, 3),
}
# Few values: many ties in fitness, descriptors on and between edges, outside the bounds.
FITNESS = [math.nan, -1.0, 0.0, 0.5, 1.0, 2.0, 3.0]
DESCRIPTOR = [math.nan, -0.5, 0.0, 0.1, 0.25, 0.5, 0.7, 1.0, 1.3]


@jax.jit
def add(archive: SlidingBoundariesArchive, genotypes: Any, descriptors: Any, fitnesses: Any) -> Any:
    return archive.add(genotypes, descriptors, fitnesses)


class Sequential:
    """pyribs' rules, one candidate at a time, in float32 NumPy; elites as (fitness, descriptor, id)."""

    def __init__(self, dims: tuple[int, ...], low: Any, high: Any, period: int, capacity: int) -> None:
        self.dims, self.period = dims, period
        self.edges = [np.linspace(a, b, n + 1).astype(np.float32) for n, a, b in zip(dims, low, high, strict=True)]
        self.elites: dict[int, tuple[np.float32, np.ndarray, int]] = {}
        self.buffer: collections.deque[tuple[np.float32, np.ndarray, int]] = collections.deque(maxlen=capacity)
        self.count = 0

    def cell(self, d: np.ndarray) -> int:
        bins = [int(np.sum(e[1:n] <= d[i] + np.float32(EPS))) for i, (e, n) in enumerate(zip(self.edges, self.dims, strict=True))]
        return int(np.ravel_multi_index(bins, self.dims))

    def insert(self, fit: np.float32, d: np.ndarray, gid: int) -> tuple[int, float, int]:
        c = self.cell(d)
        old = self.elites.get(c)
        if old is None:
            self.elites[c] = (fit, d, gid)
            return 2, float(fit), c
        if fit > old[0]:
            self.elites[c] = (fit, d, gid)
            return 1, float(fit - old[0]), c
        return 0, float(fit - old[0]), c

    def offer(self, fit: np.float32, d: np.ndarray, gid: int) -> tuple[int, float, int]:
        if not (np.isfinite(fit) and np.all(np.isfinite(d))):
            return 0, -math.inf, -1
        self.buffer.append((fit, d, gid))
        self.count += 1
        if self.count % self.period:
            return self.insert(fit, d, gid)
        ranked = np.sort(np.stack([e[1] for e in self.buffer]), axis=0)
        size = len(self.buffer)
        self.edges = [
            np.array([ranked[(j * size) // n, i] for j in range(n)] + [ranked[-1, i]], np.float32)
            for i, n in enumerate(self.dims)
        ]
        former = [self.elites[c] for c in sorted(self.elites)]
        self.elites = {}
        for entry in [*former, *list(self.buffer)[:-1]]:
            self.insert(*entry)
        return self.insert(*self.buffer[-1])


def batch(draw: Any, dim: int, first_id: int) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    fitnesses = np.array(draw(st.lists(st.sampled_from(FITNESS), min_size=N, max_size=N)), np.float32)
    flat = draw(st.lists(st.sampled_from(DESCRIPTOR[1:]), min_size=N * dim, max_size=N * dim))
    descriptors = np.array(flat, np.float32).reshape(N, dim)
    nan_rows = draw(st.lists(st.booleans(), min_size=N, max_size=N))
    descriptors[np.array(nan_rows) & (np.arange(N) % 5 == 0), 0] = np.nan  # a few NaN descriptors
    ids = np.arange(first_id, first_id + N, dtype=np.int32)
    return {"w": np.stack([ids, -ids], 1).astype(np.float32), "id": ids}, descriptors, fitnesses


@pytest.mark.parametrize("config", sorted(CONFIGS))
@SETTINGS
@given(data=st.data())
def test_batches_match_inserting_one_candidate_at_a_time(config: str, data: st.DataObject) -> None:
    dims, low, high, period, capacity = CONFIGS[config]
    archive = sliding_boundaries_archive(EXAMPLE, dims, low, high, period, capacity)
    reference = Sequential(dims, low, high, period, capacity)
    for b in range(3):
        genotypes, descriptors, fitnesses = batch(data.draw, len(dims), b * N)
        archive, result = add(archive, genotypes, descriptors, fitnesses)
        expected = [reference.offer(f, d, int(i)) for f, d, i in zip(fitnesses, descriptors, genotypes["id"], strict=True)]
        status, value, cell = (np.array(v) for v in zip(*expected, strict=True))
        np.testing.assert_array_equal(np.asarray(result.status), status)
        np.testing.assert_array_equal(np.asarray(result.cell), cell)
        np.testing.assert_allclose(np.asarray(result.value), value, rtol=0, atol=1e-6)
        # `added` (the elite once its insertion is done) was an improvement at its turn.
        assert not np.any(np.asarray(result.added) & (status == 0))
    assert int(archive.count) == reference.count
    for i, (edges, n) in enumerate(zip(reference.edges, dims, strict=True)):
        np.testing.assert_array_equal(np.asarray(archive.boundaries)[i, : n + 1], edges)
    want = np.full(archive.num_cells, -np.inf, np.float32)
    want_ids = {c: gid for c, (_, _, gid) in reference.elites.items()}
    for c, (fit, _, _) in reference.elites.items():
        want[c] = fit
    np.testing.assert_array_equal(np.asarray(archive.fitnesses), want)
    filled = np.flatnonzero(np.asarray(archive.filled))
    assert {int(c): int(np.asarray(archive.genotypes["id"])[c]) for c in filled} == want_ids
    # Invariant: every elite lies in its own cell under the current edges.
    np.testing.assert_array_equal(np.asarray(archive.cell_index(archive.descriptors[filled])), filled)


def test_a_remap_puts_the_edges_at_the_buffer_percentiles() -> None:
    # 8 candidates, descriptor = fitness = 0..7 shuffled; at the 8th the edges move to the
    # values of rank floor(j * 8 / 4) = 0, 2, 4, 6 and the largest, 7.
    archive = sliding_boundaries_archive(None, (4,), 0.0, 100.0, remap_frequency=8, buffer_capacity=8)
    values = np.array([5, 0, 7, 2, 6, 1, 4, 3], np.float32)
    archive, result = add(archive, None, values[:, None], values)
    np.testing.assert_array_equal(np.asarray(archive.boundaries)[0], [0, 2, 4, 6, 7])
    # Before the remap every value fell in cell 0 ([0, 25)); after it the cells are
    # [0, 2), [2, 4), [4, 6), [6, 7], each keeping its fittest.
    np.testing.assert_array_equal(np.asarray(archive.fitnesses), [1, 3, 5, 7])
    np.testing.assert_array_equal(np.asarray(archive.centroids)[:, 0], [1, 3, 5, 6.5])
    # The trigger (3) is re-inserted last, into [2, 4) where 2 waits: it improves it by 1.
    assert int(result.status[-1]) == 1 and float(result.value[-1]) == 1.0 and int(result.cell[-1]) == 1
    np.testing.assert_array_equal(np.asarray(result.cell)[:-1], 0)
    np.testing.assert_array_equal(np.asarray(archive.lower_bounds), [0.0])
    np.testing.assert_array_equal(np.asarray(archive.upper_bounds), [7.0])


def test_before_the_first_remap_it_is_the_grid() -> None:
    rng = np.random.default_rng(0)
    descriptors = rng.uniform(-0.2, 1.2, (40, 2)).astype(np.float32)
    fitnesses = rng.normal(size=40).astype(np.float32)
    sliding = sliding_boundaries_archive(None, (5, 3), 0.0, 1.0, remap_frequency=41)
    grid = grid_repertoire(None, (5, 3), 0.0, 1.0)
    sliding, got = add(sliding, None, descriptors, fitnesses)
    grid, want = jax.jit(lambda r: r.add(None, descriptors, fitnesses))(grid)
    np.testing.assert_array_equal(np.asarray(got.cell), np.asarray(want.cell))
    np.testing.assert_array_equal(np.asarray(sliding.fitnesses), np.asarray(grid.fitnesses))
    np.testing.assert_allclose(np.asarray(sliding.centroids), np.asarray(grid.centroids), atol=1e-6)


def two_d_archive() -> SlidingBoundariesArchive:
    return sliding_boundaries_archive(EXAMPLE, *CONFIGS["2d"])


def rows(descriptors: list[list[float]], fitnesses: list[float]) -> tuple[Any, np.ndarray, np.ndarray]:
    """A batch of N for the 2-D archive: the given rows, then rows with a NaN fitness."""
    d = np.full((N, 2), 0.5, np.float32)
    f = np.full((N,), np.nan, np.float32)
    d[: len(descriptors)], f[: len(fitnesses)] = descriptors, fitnesses
    ids = np.arange(N, dtype=np.int32)
    return {"w": np.stack([ids, ids], 1).astype(np.float32), "id": ids}, d, f


def test_rejected_candidates_neither_count_nor_enter_the_buffer() -> None:
    genotypes, descriptors, fitnesses = rows(
        [[0.2, 0.2], [np.inf, 0.5], [0.7, 0.7], [0.4, 0.9]], [1.0, 2.0, np.nan, 3.0]
    )
    archive, result = add(two_d_archive(), genotypes, descriptors, fitnesses)
    assert int(archive.count) == 2 and int(archive.buffer_size) == 2
    rejected = np.ones(N, bool)  # rows 1 and 2, and the NaN rows after the four given
    rejected[[0, 3]] = False
    np.testing.assert_array_equal(np.asarray(result.cell)[rejected], -1)
    np.testing.assert_array_equal(np.asarray(result.status)[rejected], 0)
    assert np.all(np.asarray(result.value)[rejected] == -np.inf)
    np.testing.assert_array_equal(np.asarray(archive.buffer_genotypes["id"])[:2], [0, 3])
    assert archive.buffer_capacity == 7 and archive.buffer_genotypes["w"].shape == (7, 2)


def test_one_compilation_serves_every_add_and_the_archive_is_a_pytree() -> None:
    traces = []

    @jax.jit
    def step(archive: SlidingBoundariesArchive, key: jax.Array) -> Any:
        traces.append(1)
        d_key, f_key = jax.random.split(key)
        genotypes = jax.tree_util.tree_map(lambda x: jnp.zeros((N, *x.shape), x.dtype), EXAMPLE)
        descriptors = jax.random.uniform(d_key, (N, 2), minval=0.2, maxval=0.6)
        archive, _ = archive.add(genotypes, descriptors, jax.random.normal(f_key, (N,)))
        return archive

    archive = two_d_archive()
    for key in jax.random.split(jax.random.key(0), 3):
        archive = step(archive, key)
    assert len(traces) == 1 and int(archive.count) == 3 * N
    leaves, treedef = jax.tree_util.tree_flatten(archive)
    again = jax.tree_util.tree_unflatten(treedef, leaves)
    assert again.dims == (3, 4) and again.remap_frequency == 5
    # The edges followed the descriptors into [0.2, 0.6].
    assert float(archive.lower_bounds.min()) >= 0.2 and float(archive.upper_bounds.max()) <= 0.6


def test_sampling_draws_filled_cells_and_an_empty_archive_gives_nan() -> None:
    archive = two_d_archive()
    assert bool(archive.is_empty)
    assert bool(jnp.all(jnp.isnan(archive.sample(jax.random.key(0), 3)["w"])))
    archive, _ = add(archive, *rows([[0.1, 0.1], [0.9, 0.9]], [1.0, 2.0]))
    drawn = np.asarray(archive.sample(jax.random.key(1), 50)["id"])
    assert set(drawn.tolist()) == {0, 1} and int(archive.num_filled) == 2


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dims": ()}, "dims"),
        ({"dims": (3, 0)}, "dims"),
        ({"low": 1.0}, "low < high"),
        ({"remap_frequency": 0}, "remap_frequency"),
        ({"buffer_capacity": 2.5}, "buffer_capacity"),
        ({"epsilon": -1.0}, "epsilon"),
    ],
)
def test_the_builder_rejects_bad_arguments(kwargs: dict[str, Any], message: str) -> None:
    arguments: dict[str, Any] = {"genotype_example": None, "dims": (3, 3), "low": 0.0, "high": 1.0, **kwargs}
    with pytest.raises(ValueError, match=message):
        sliding_boundaries_archive(**arguments)
