"""Tests for qdrl.qd.repertoires.categorical: cells of category indices by hand, invalid indices
rejected, insertion against a NumPy reference on hypothesis-drawn batches, names, CMA-MAE
thresholds, exports and the pytree/jit contract."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.repertoires import export_npz, to_table
from qdrl.qd.repertoires.categorical import CategoricalArchive, categorical_archive

SETTINGS = settings(max_examples=25, deadline=None, database=None, derandomize=True)
N = 12
CATEGORIES = [["rock", "paper", "scissors"], ["day", "night"]]
# Valid indices, and values that are not: fractions, out of range, non-finite.
INDEX_VALUES = [0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 0.5, -1.0, 3.0, math.nan, math.inf]
FITNESS_VALUES = [math.nan, -1.0, 0.0, 1.0, 2.0, 2.0]


@jax.jit
def add(archive: CategoricalArchive, genotypes: Any, descriptors: Any, fitnesses: Any) -> Any:
    return archive.add(genotypes, descriptors, fitnesses)


def empty() -> CategoricalArchive:
    return categorical_archive(jnp.zeros((), jnp.int32), CATEGORIES)


def test_cells_are_the_category_indices_and_invalid_ones_are_rejected() -> None:
    archive = empty()
    assert archive.num_cells == 6 and archive.dims == (3, 2) and archive.grid_shape == (3, 2)
    descriptors = np.array(
        [[2, 1], [0, 0], [1.5, 0], [3, 1], [-1, 0], [np.nan, 1], [1, np.inf], [2, 1]] + [[0, 1]] * 4,
        np.float32,
    )
    fitnesses = np.array([1.0, 2.0, 9.0, 9.0, 9.0, 9.0, 9.0, 3.0, 0.0, 0.0, 0.0, 0.0], np.float32)
    archive, result = add(archive, jnp.arange(N, dtype=jnp.int32), descriptors, fitnesses)
    # (scissors, night) is cell 2 * 2 + 1 = 5; (rock, day) cell 0; (rock, night) cell 1.
    np.testing.assert_array_equal(np.asarray(result.cell), [5, 0, -1, -1, -1, -1, -1, 5, 1, 1, 1, 1])
    np.testing.assert_array_equal(np.asarray(archive.fitnesses), [2.0, 0.0, -np.inf, -np.inf, -np.inf, 3.0])
    np.testing.assert_array_equal(np.asarray(archive.genotypes)[[0, 1, 5]], [1, 8, 7])  # ties: the first
    assert not np.any(np.asarray(result.added)[2:7])
    assert archive.decode(archive.descriptors[jnp.array([0, 5])]) == [("rock", "day"), ("scissors", "night")]
    assert archive.decode(np.array([[0.5, 0.0]])) == [None]


def reference(descriptors: np.ndarray, fitnesses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cell of each candidate, -1 if rejected; the cells' fitnesses; each cell's winner, -1)."""
    dims = np.array([3, 2])
    ok = np.all((descriptors == np.floor(descriptors)) & (descriptors >= 0) & (descriptors < dims), axis=1)
    ok &= np.isfinite(fitnesses)
    cells = np.full(len(fitnesses), -1)
    best, winner = np.full(6, -np.inf, np.float32), np.full(6, -1)
    for i in np.flatnonzero(ok):
        cells[i] = int(descriptors[i, 0]) * 2 + int(descriptors[i, 1])
        if fitnesses[i] > best[cells[i]]:
            best[cells[i]], winner[cells[i]] = fitnesses[i], i
    return cells, best, winner


@SETTINGS
@given(
    flat=st.lists(st.sampled_from(INDEX_VALUES), min_size=2 * N, max_size=2 * N),
    fit=st.lists(st.sampled_from(FITNESS_VALUES), min_size=N, max_size=N),
)
def test_insertion_matches_a_reference_on_drawn_batches(flat: list[float], fit: list[float]) -> None:
    descriptors = np.array(flat, np.float32).reshape(N, 2)
    fitnesses = np.array(fit, np.float32)
    archive, result = add(empty(), jnp.arange(N, dtype=jnp.int32), descriptors, fitnesses)
    cells, best, winner = reference(descriptors, fitnesses)
    np.testing.assert_array_equal(np.asarray(result.cell), cells)
    np.testing.assert_array_equal(np.asarray(archive.fitnesses), best)
    filled = winner >= 0
    np.testing.assert_array_equal(np.asarray(archive.genotypes)[filled], winner[filled])
    np.testing.assert_array_equal(np.flatnonzero(np.asarray(result.added)), np.sort(winner[filled]))


def test_names_encode_to_indices_and_back() -> None:
    archive = empty()
    rows = [("scissors", "day"), ("paper", "night")]
    encoded = archive.encode(rows)
    np.testing.assert_array_equal(encoded, [[2, 0], [1, 1]])
    assert archive.decode(encoded) == rows
    with pytest.raises(KeyError, match="'dusk' is not a category of dimension 1"):
        archive.encode([("rock", "dusk")])


def test_cma_mae_thresholds_and_exports(tmp_path: Path) -> None:
    archive = empty().with_learning_rate(0.5, threshold_min=0.0)
    assert archive.threshold_min == 0.0 and archive.thresholds is not None
    descriptors = np.zeros((N, 2), np.float32)
    descriptors[1] = [1, 1]
    fitnesses = np.full(N, np.nan, np.float32)
    fitnesses[:2] = [4.0, 2.0]
    archive, result = add(archive, jnp.arange(N, dtype=jnp.int32), descriptors, fitnesses)
    # Each cell's threshold moves half way from 0 to its candidate: 2 and 1.
    np.testing.assert_allclose(np.asarray(archive.thresholds)[[0, 3]], [2.0, 1.0])
    np.testing.assert_allclose(np.asarray(result.improvement)[:2], [4.0, 2.0])
    table = to_table(archive, ["hand", "time"])
    np.testing.assert_array_equal(table["descriptor_hand"], [0.0, 1.0])
    np.testing.assert_array_equal(table["centroid_time"], [0.0, 1.0])
    with np.load(export_npz(archive, tmp_path / "categorical.npz")) as f:
        assert tuple(f["grid_shape"]) == (3, 2) and f["low"].tolist() == [-0.5, -0.5]


def test_the_archive_is_a_pytree_and_jit_compiles_once() -> None:
    traces = []

    @jax.jit
    def step(archive: CategoricalArchive, key: jax.Array) -> CategoricalArchive:
        traces.append(1)
        descriptors = jax.random.randint(key, (N, 2), 0, 2).astype(jnp.float32)
        return archive.add(jnp.zeros((N,), jnp.int32), descriptors, jnp.ones((N,)))[0]

    archive = empty()
    for key in jax.random.split(jax.random.key(0), 3):
        archive = step(archive, key)
    assert len(traces) == 1 and archive.categories == (("rock", "paper", "scissors"), ("day", "night"))
    leaves, treedef = jax.tree_util.tree_flatten(archive)
    assert jax.tree_util.tree_unflatten(treedef, leaves).categories == archive.categories
    assert int(archive.num_filled) >= 1 and not bool(archive.is_empty)
    drawn = archive.sample(jax.random.key(1), 4)
    assert drawn.shape == (4,)


@pytest.mark.parametrize(
    ("categories", "message"),
    [([], "non-empty"), ("abc", "non-empty"), ([["a"], []], r"categories\[1\]"), ([["a", "a"]], "unique")],
)
def test_the_builder_rejects_bad_categories(categories: Any, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        categorical_archive(None, categories)
