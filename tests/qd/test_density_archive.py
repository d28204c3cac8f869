"""Tests for qdrl.qd.repertoires.density: the KDE against NumPy, the reservoir, the add result.

The KDE is checked against a NumPy transcription of pyribs' formula, the reservoir by
its invariants (the buffer holds distinct stream items, `added` says which) and by the
uniformity of its sample over many seeds, `add` against the KDE of the buffer before
the batch. Shapes are fixed so that each jitted function compiles once.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.repertoires.density import DensityArchive, density_archive, kde_density

N = 8  # candidates per batch


def numpy_kde(points: np.ndarray, buffer: np.ndarray, h: float) -> np.ndarray:
    """pyribs' KDE by hand: sum_j exp(-|x - b_j|^2 / (2 h^2)) / sqrt(2 pi) / (len(buffer) h)."""
    if len(buffer) == 0:
        return np.zeros(len(points))
    dist = np.sqrt(((points[:, None, :] - buffer[None, :, :]) ** 2).sum(-1))
    return np.exp(-0.5 * (dist / h) ** 2).sum(1) / math.sqrt(2 * math.pi) / (len(buffer) * h)


def make(buffer_size: int = 16, bandwidth: float = 0.5, seed: int = 0) -> DensityArchive:
    return density_archive(2, buffer_size, bandwidth, key=jax.random.PRNGKey(seed))


_add = jax.jit(lambda a, d, f: a.add(None, d, f))


def test_kde_matches_a_numpy_hand_computation() -> None:
    rng = np.random.default_rng(0)
    buffer = rng.normal(size=(12, 3)).astype(np.float32)
    points = rng.normal(size=(7, 3)).astype(np.float32)
    for count in (1, 5, 12):
        got = np.asarray(kde_density(points, buffer, count, 0.7))
        np.testing.assert_allclose(got, numpy_kde(points, buffer[:count], 0.7), rtol=1e-5)
    # Rows past `count` are ignored whatever they hold; an empty buffer gives 0.
    garbage = buffer.copy()
    garbage[5:] = 1e3
    np.testing.assert_allclose(
        np.asarray(kde_density(points, garbage, 5, 0.7)), numpy_kde(points, buffer[:5], 0.7), rtol=1e-5
    )
    np.testing.assert_array_equal(np.asarray(kde_density(points, buffer, 0, 0.7)), np.zeros(7))


def test_kde_of_four_corners_at_the_origin() -> None:
    # pyribs' own check: every corner is sqrt(2) from the origin, so the mean of four
    # kernels is one kernel.
    corners = np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]], np.float32)
    h = 2.0
    want = math.exp(-0.5 * (math.sqrt(2) / h) ** 2) / math.sqrt(2 * math.pi) / h
    got = float(kde_density(np.zeros((1, 2), np.float32), corners, 4, h)[0])
    assert got == pytest.approx(want, rel=1e-6)


def test_add_judges_against_the_buffer_before_the_batch() -> None:
    rng = np.random.default_rng(1)
    archive = make()
    first = rng.normal(size=(N, 2)).astype(np.float32)
    archive, result = _add(archive, first, np.zeros(N, np.float32))
    assert result.status is not None and result.value is not None and result.info is not None
    # An empty buffer: density 0 everywhere (pyribs), every candidate new (status 2).
    np.testing.assert_array_equal(np.asarray(result.info["density"]), np.zeros(N))
    np.testing.assert_array_equal(np.asarray(result.status), np.full(N, 2))
    # Not full: the batch fills rows 0..N-1 in order (pyribs' test_add_to_buffer).
    np.testing.assert_array_equal(np.asarray(archive.buffer[:N]), first)
    np.testing.assert_array_equal(np.asarray(result.cell), np.arange(N))
    assert bool(result.added.all()) and bool(result.new_cell.all())

    second = rng.normal(size=(N, 2)).astype(np.float32)
    fitnesses = np.zeros(N, np.float32)
    fitnesses[2] = np.nan  # a failed evaluation
    second[5, 1] = np.inf  # a non-finite descriptor
    archive, result = _add(archive, second, fitnesses)
    assert result.status is not None and result.value is not None and result.info is not None
    valid = np.ones(N, bool)
    valid[[2, 5]] = False
    density = numpy_kde(second[valid], first, 0.5)  # the first batch only, not the second
    np.testing.assert_allclose(np.asarray(result.info["density"])[valid], density, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(result.value)[valid], -density, rtol=1e-5)
    np.testing.assert_array_equal(np.asarray(result.improvement), np.asarray(result.value))
    np.testing.assert_array_equal(np.asarray(result.status), np.where(valid, 2, 0))
    assert np.all(np.asarray(result.value)[~valid] == -np.inf)
    assert np.all(np.asarray(result.info["density"])[~valid] == np.inf)
    # Rejected candidates never enter the buffer nor count in the stream.
    assert int(archive.seen) == 2 * N - 2 and int(archive.num_filled) == 2 * N - 2
    np.testing.assert_array_equal(np.asarray(archive.buffer[N : 2 * N - 2]), second[valid])
    np.testing.assert_array_equal(np.asarray(result.cell)[~valid], [-1, -1])
    np.testing.assert_allclose(
        np.asarray(archive.density(second[:1])),
        numpy_kde(second[:1], np.concatenate([first, second[valid]]), 0.5),
        rtol=1e-5,
    )


def test_reservoir_when_full_keeps_distinct_stream_items_and_reports_them() -> None:
    archive = make(buffer_size=10, seed=3)
    stream = np.arange(5 * N, dtype=np.float32)
    for b in range(5):
        items = stream[b * N : (b + 1) * N]
        before = np.asarray(archive.buffer).copy()
        descriptors = np.stack([items, -items], axis=1)
        archive, result = _add(archive, descriptors, np.zeros(N, np.float32))
        buf = np.asarray(archive.buffer)[: int(archive.num_filled)]
        assert int(archive.num_filled) == min(10, (b + 1) * N)
        assert len(set(buf[:, 0].tolist())) == len(buf)  # distinct items
        assert set(buf[:, 0].tolist()) <= set(stream[: (b + 1) * N].tolist())
        np.testing.assert_array_equal(buf[:, 1], -buf[:, 0])  # rows are written whole
        cell = np.asarray(result.cell)
        added = np.asarray(result.added)
        # `added` candidates sit at their `cell`; the others are not in the buffer.
        np.testing.assert_array_equal(buf[cell[added], 0], items[added])
        assert not set(items[~added].tolist()) & set(buf[:, 0].tolist())
        # Rows in use before the batch that nobody wrote keep their descriptor.
        untouched = np.setdiff1d(np.arange(min(10, b * N)), cell[added])
        np.testing.assert_array_equal(buf[untouched], before[untouched])
        # Every valid candidate gets status 2, as in pyribs, kept or not.
        np.testing.assert_array_equal(np.asarray(result.status), np.full(N, 2))


def test_reservoir_sample_is_uniform_over_the_stream() -> None:
    # K = 8 rows, a stream of 64 items in 8 batches of 8: each item (first or last of
    # its batch alike) must end in the buffer with probability 8 / 64.
    size, batches, seeds = 8, 8, 4000
    stream = jnp.arange(batches * N, dtype=jnp.float32).reshape(batches, N, 1)

    def run(key: jax.Array) -> jax.Array:
        archive = density_archive(1, size, 1.0, key=key)

        def body(a: DensityArchive, items: jax.Array) -> tuple[DensityArchive, None]:
            return a.add(None, items, jnp.zeros(N))[0], None

        final, _ = jax.lax.scan(body, archive, stream)
        return final.buffer[:, 0]

    buffers = np.asarray(jax.jit(jax.vmap(run))(jax.random.split(jax.random.PRNGKey(0), seeds)))
    counts = np.zeros(batches * N)
    for row in buffers.astype(int):
        assert len(set(row.tolist())) == size
        counts[row] += 1
    freq = counts / seeds
    # 6 standard deviations of a frequency of 1/8 over 4000 runs
    assert np.max(np.abs(freq - size / (batches * N))) < 6 * math.sqrt(0.125 * 0.875 / seeds)


def test_add_compiles_once_and_runs_under_scan() -> None:
    traces: list[None] = []

    def counted(a: DensityArchive, d: jax.Array, f: jax.Array) -> Any:
        traces.append(None)
        return a.add(None, d, f)

    add = jax.jit(counted)
    archive = make(buffer_size=12)
    structure: Any = jax.tree_util.tree_structure(archive)  # Any: mypy cannot type PyTreeDef
    rng = np.random.default_rng(2)
    for _ in range(4):
        archive, _ = add(archive, rng.normal(size=(N, 2)).astype(np.float32), np.zeros(N, np.float32))
    assert len(traces) == 1
    assert jax.tree_util.tree_structure(archive) == structure
    assert int(archive.seen) == 4 * N and int(archive.num_filled) == 12

    # A checkpoint of the leaves resumes bit-exactly (the key is a leaf).
    leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(archive)]
    resumed = jax.tree_util.tree_unflatten(structure, [jnp.asarray(x) for x in leaves])
    batch = rng.normal(size=(N, 2)).astype(np.float32)
    a, ra = add(archive, batch, np.zeros(N, np.float32))
    b, rb = add(resumed, batch, np.zeros(N, np.float32))
    for x, y in zip(jax.tree_util.tree_leaves((a, ra)), jax.tree_util.tree_leaves((b, rb)), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_views_of_an_archive_without_solutions() -> None:
    archive = make(buffer_size=12)
    assert archive.genotypes is None and archive.num_cells == 12 and bool(archive.is_empty)
    archive, _ = _add(archive, np.ones((N, 2), np.float32), np.zeros(N, np.float32))
    np.testing.assert_array_equal(np.asarray(archive.filled), np.arange(12) < N)
    np.testing.assert_array_equal(
        np.asarray(archive.fitnesses), np.where(np.arange(12) < N, 0.0, -np.inf)
    )
    assert not bool(archive.is_empty)
    with pytest.raises(NotImplementedError, match="result archive"):
        archive.sample(jax.random.PRNGKey(0), 4)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"bandwidth": 0.0}, "bandwidth"),
        ({"bandwidth": -1.0}, "bandwidth"),
        ({"bandwidth": math.nan}, "bandwidth"),
        ({"buffer_size": 0}, "buffer_size"),
        ({"buffer_size": 2.5}, "buffer_size"),
        ({"descriptor_dim": 0}, "descriptor_dim"),
    ],
)
def test_bad_parameters_raise_naming_them(kwargs: dict[str, Any], name: str) -> None:
    args: dict[str, Any] = {"descriptor_dim": 2, "buffer_size": 10, "bandwidth": 1.0, **kwargs}
    with pytest.raises(ValueError, match=f"^{name}:"):
        density_archive(**args, key=jax.random.PRNGKey(0))


def test_add_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match="descriptors must have shape"):
        make().add(None, np.zeros((N, 3), np.float32), np.zeros(N, np.float32))
