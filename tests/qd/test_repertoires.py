"""Tests for qdrl.qd.repertoires: grid, CVT and unstructured insertion rules, sampling, export.

Insertion is checked against NumPy reference implementations on hypothesis-drawn
batches; shapes are fixed so that each jitted `add` compiles once for the module.
The drawn fitnesses include NaN, +-inf and subnormals, the drawn descriptors NaN
and +-inf: the references reject every non-finite value and compare fitnesses with
subnormals flushed to 0 (NumPy does not flush them; XLA on a CPU does).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.base import AddResult
from qdrl.qd.metrics import qd_metrics
from qdrl.qd.repertoires import (
    CellRepertoire,
    UnstructuredRepertoire,
    cvt_centroids,
    cvt_repertoire,
    descriptor_columns,
    export_npz,
    grid_repertoire,
    observe,
    passive_archive,
    to_table,
    unstructured_repertoire,
    write_csv,
)
from qdrl.qd.repertoires.cells import flush_subnormals

SETTINGS = settings(max_examples=25, deadline=None, database=None, derandomize=True)
N = 16  # candidates per batch, fixed so that jitted adds compile once
GRID_SHAPE = (4, 5)
LOW, HIGH = (-1.0, 0.0), (1.0, 2.0)
SUBNORMAL = 4e-41  # a float32 subnormal: XLA on a CPU compares it equal to 0
# Few values (many ties); the non-finite ones are rejected, the subnormals tie with 0.
FITNESS_VALUES = [
    math.nan, -1.0, 0.0, 0.5, 1.0, 2.0, 3.0, math.inf, -math.inf, SUBNORMAL, -SUBNORMAL
]
BAD_DESCRIPTOR_VALUES = (None,) * 7 + (math.nan, math.inf, -math.inf)  # None: finite
TINY = np.finfo(np.float32).tiny

# A haiku-like parameter tree; every leaf of a candidate holds its id.
PARAMS_EXAMPLE = {
    "linear": {"w": jnp.zeros((2, 3), jnp.float32), "b": jnp.zeros((3,), jnp.float32)},
    "tag": jnp.zeros((), jnp.int32),
}


@jax.jit
def jit_add(repertoire, genotypes, descriptors, fitnesses):
    return repertoire.add(genotypes, descriptors, fitnesses)


def add_padded(repertoire, ids, descriptors, fitnesses):
    """`jit_add` of k <= N candidates, padded to N with NaN-fitness ones (always rejected),
    so that every test shares one compilation per repertoire kind; returns k results."""
    descriptors = np.asarray(descriptors, np.float32)
    k = descriptors.shape[0]
    pad = N - k
    descriptors = np.concatenate([descriptors, np.zeros((pad, descriptors.shape[1]), np.float32)])
    fitnesses = np.concatenate(
        [np.asarray(fitnesses, np.float32), np.full(pad, np.nan, np.float32)]
    )
    genotypes = None if ids is None else params_batch(np.concatenate([ids, np.zeros(pad, int)]))
    new, result = jit_add(repertoire, genotypes, descriptors, fitnesses)
    assert not bool(jnp.any(result.added[k:]))
    return new, jax.tree.map(lambda x: x[:k], result)


def params_batch(ids: np.ndarray) -> dict:
    ids = np.asarray(ids)
    return {
        "linear": {
            "w": jnp.asarray(np.broadcast_to(ids[:, None, None], (len(ids), 2, 3)), jnp.float32),
            "b": jnp.asarray(np.broadcast_to(ids[:, None], (len(ids), 3)), jnp.float32),
        },
        "tag": jnp.asarray(ids, jnp.int32),
    }


def stored_ids(genotypes: dict) -> np.ndarray:
    return np.asarray(genotypes["tag"])


def cvt_fixture_centroids() -> np.ndarray:
    """12 well-separated 2-D centroids (min pairwise distance 0.5)."""
    xs, ys = np.meshgrid(np.arange(4) * 0.5, np.arange(3) * 0.5, indexing="ij")
    return np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.float32)


CVT_CENTROIDS = cvt_fixture_centroids()


# --- NumPy references ----------------------------------------------------------------


class Expected(NamedTuple):
    """A reference `AddResult`, in NumPy."""

    added: np.ndarray
    new_cell: np.ndarray
    improvement: np.ndarray
    cell: np.ndarray


def reference_flush(fitnesses):
    """The repertoires' rule: subnormal fitnesses (and -0.0) count, and are stored, as +0.0."""
    fitnesses = np.asarray(fitnesses, np.float32)
    return np.where(np.abs(fitnesses) < TINY, np.float32(0.0), fitnesses)


def reference_valid(descriptors, fitnesses):
    """The repertoires' rule: finite fitness and finite descriptor."""
    return np.isfinite(fitnesses) & np.all(np.isfinite(descriptors), axis=-1)


def reference_cell_insert(store, cells, descriptors, fitnesses, ids):
    """Best-per-cell insertion, strictly-better replacement; cells[i] == -1 means rejected."""
    fitnesses = reference_flush(fitnesses)
    store_f, store_d, store_ids = (x.copy() for x in store)
    n = len(fitnesses)
    added = np.zeros(n, bool)
    new_cell = np.zeros(n, bool)
    improvement = np.full(n, -np.inf, np.float32)
    old_f = store_f.copy()
    for i in range(n):
        if cells[i] >= 0:
            prev = old_f[cells[i]]
            improvement[i] = fitnesses[i] - prev if prev > -np.inf else fitnesses[i]
    for c in np.unique(cells[cells >= 0]):
        members = np.flatnonzero(cells == c)
        best = fitnesses[members].max()
        winner = members[fitnesses[members] == best].min()
        if best > old_f[c]:
            added[winner] = True
            new_cell[winner] = old_f[c] == -np.inf
            store_f[c], store_d[c], store_ids[c] = best, descriptors[winner], ids[winner]
    return (store_f, store_d, store_ids), Expected(added, new_cell, improvement, cells)


def reference_unstructured_insert(store, l_value, descriptors, fitnesses, ids):
    """Sequential novelty-threshold insertion with the second-nearest rule."""
    valid = reference_valid(descriptors, fitnesses)
    fitnesses = reference_flush(fitnesses)
    store_f, store_d, store_ids = (x.copy() for x in store)
    n = len(fitnesses)
    out = Expected(
        np.zeros(n, bool), np.zeros(n, bool), np.full(n, -np.inf, np.float32), np.full(n, -1)
    )
    for i in range(n):
        f, d = fitnesses[i], descriptors[i]
        if not valid[i]:
            continue
        filled = store_f > -np.inf
        dist = np.where(filled, np.sqrt(((store_d - d) ** 2).sum(-1)), np.inf)
        order = np.argsort(dist, kind="stable")
        nearest, second = order[0], (dist[order[1]] if len(order) > 1 else np.inf)
        if dist[nearest] >= l_value:
            free = np.flatnonzero(~filled)
            out.improvement[i] = f
            if len(free):
                out.cell[i] = free[0]
                out.added[i] = out.new_cell[i] = True
                store_f[free[0]], store_d[free[0]], store_ids[free[0]] = f, d, ids[i]
        else:
            out.cell[i] = nearest
            out.improvement[i] = f - store_f[nearest]
            if f > store_f[nearest] and second >= l_value:
                out.added[i] = True
                store_f[nearest], store_d[nearest], store_ids[nearest] = f, d, ids[i]
    return (store_f, store_d, store_ids), out


def assert_result_equal(result: AddResult, expected: Expected) -> None:
    np.testing.assert_array_equal(np.asarray(result.cell), expected.cell)
    np.testing.assert_array_equal(np.asarray(result.added), expected.added)
    np.testing.assert_array_equal(np.asarray(result.new_cell), expected.new_cell)
    np.testing.assert_allclose(np.asarray(result.improvement), expected.improvement, rtol=1e-6)


def assert_store_equal(repertoire, store) -> None:
    store_f, store_d, store_ids = store
    np.testing.assert_array_equal(np.asarray(repertoire.fitnesses), store_f)
    filled = store_f > -np.inf
    np.testing.assert_array_equal(np.asarray(repertoire.descriptors)[filled], store_d[filled])
    np.testing.assert_array_equal(stored_ids(repertoire.genotypes), store_ids)
    w = np.asarray(repertoire.genotypes["linear"]["w"])
    np.testing.assert_array_equal(w, np.broadcast_to(store_ids[:, None, None], w.shape))


def empty_store(repertoire):
    c, d = repertoire.fitnesses.shape[0], repertoire.descriptors.shape[1]
    return np.full(c, -np.inf, np.float32), np.zeros((c, d), np.float32), np.zeros(c, np.int64)


# --- strategies -------------------------------------------------------------------

fitness_st = st.sampled_from(FITNESS_VALUES)
grid_candidate_st = st.tuples(
    st.integers(-2, GRID_SHAPE[0] + 1),  # bins outside [0, n) are out of bounds
    st.integers(-2, GRID_SHAPE[1] + 1),
    st.floats(0.1, 0.9),  # position inside the bin, away from its edges
    st.floats(0.1, 0.9),
    fitness_st,
    st.sampled_from(BAD_DESCRIPTOR_VALUES),  # NaN or +-inf in the descriptor, 3 times in 10
    st.integers(0, 1),  # ... in this dimension
)
grid_batches_st = st.lists(
    st.lists(grid_candidate_st, min_size=N, max_size=N), min_size=1, max_size=3
)


def set_bad_descriptors(descriptors, candidates, at: int) -> None:
    """Writes each candidate's drawn non-finite value (fields at, at + 1: value, dimension)."""
    for i, c in enumerate(candidates):
        if c[at] is not None:
            descriptors[i, c[at + 1]] = c[at]


def grid_batch(candidates, first_id: int):
    bins = np.array([[c[0], c[1]] for c in candidates])
    offsets = np.array([[c[2], c[3]] for c in candidates])
    width = (np.array(HIGH) - np.array(LOW)) / np.array(GRID_SHAPE)
    descriptors = (np.array(LOW) + (bins + offsets) * width).astype(np.float32)
    set_bad_descriptors(descriptors, candidates, 5)
    fitnesses = np.array([c[4] for c in candidates], np.float32)
    clipped = np.clip(bins, 0, np.array(GRID_SHAPE) - 1)
    cells = clipped[:, 0] * GRID_SHAPE[1] + clipped[:, 1]
    cells = np.where(reference_valid(descriptors, fitnesses), cells, -1)
    ids = first_id + np.arange(len(candidates))
    return descriptors, fitnesses, cells, ids


cvt_candidate_st = st.tuples(
    st.integers(0, len(CVT_CENTROIDS) - 1),
    st.floats(-0.2, 0.2),  # |offset| < 0.25 = half the minimum centroid distance
    st.floats(-0.17, 0.17),
    fitness_st,
    st.sampled_from(BAD_DESCRIPTOR_VALUES),
    st.integers(0, 1),
)
cvt_batches_st = st.lists(
    st.lists(cvt_candidate_st, min_size=N, max_size=N), min_size=1, max_size=3
)


# --- grid -------------------------------------------------------------------------


def test_grid_direct_indexing_matches_hand_computation():
    rep = grid_repertoire(None, GRID_SHAPE, LOW, HIGH)
    # bin_k = floor((d_k - low_k) / (high_k - low_k) * n_k), clipped; cell = b0 * 5 + b1.
    descriptors = jnp.array(
        [[-0.9, 0.1], [0.1, 1.3], [1.0, 2.0], [-5.0, 10.0], [jnp.inf, -jnp.inf], [0.0, 1.0]]
    )
    expected = [0, 2 * 5 + 3, 3 * 5 + 4, 0 * 5 + 4, 3 * 5 + 0, 2 * 5 + 2]
    np.testing.assert_array_equal(np.asarray(rep.cell_index(descriptors)), expected)
    np.testing.assert_allclose(np.asarray(rep.centroids[13]), [0.25, 1.4], rtol=1e-6)
    assert rep.num_cells == 20 and rep.is_grid and rep.descriptor_dim == 2
    assert rep.centroids.shape == (20, 2)


@SETTINGS
@given(batches=grid_batches_st)
def test_grid_add_matches_numpy_reference(batches):
    rep = grid_repertoire(PARAMS_EXAMPLE, GRID_SHAPE, LOW, HIGH)
    store = empty_store(rep)
    for b, candidates in enumerate(batches):
        descriptors, fitnesses, cells, ids = grid_batch(candidates, 1 + 100 * b)
        before = np.asarray(rep.fitnesses)
        rep, result = jit_add(rep, params_batch(ids), descriptors, fitnesses)
        store, expected = reference_cell_insert(store, cells, descriptors, fitnesses, ids)
        assert_result_equal(result, expected)
        assert_store_equal(rep, store)
        # A cell's fitness never decreases; NaN is never stored.
        after = np.asarray(rep.fitnesses)
        assert np.all(after >= before) and not np.any(np.isnan(after))
        assert int(rep.num_filled) == int(np.sum(after > -np.inf))


def test_out_of_bounds_descriptors_go_to_edge_cells():
    rep = grid_repertoire(None, GRID_SHAPE, LOW, HIGH)
    descriptors = jnp.array([[-100.0, -100.0], [100.0, 100.0], [-100.0, 100.0], [0.5, -1e30]])
    rep, result = add_padded(rep, None, descriptors, np.arange(4.0) + 1.0)
    np.testing.assert_array_equal(np.asarray(result.cell), [0, 19, 4, 15])
    assert bool(jnp.all(result.added))
    # The stored descriptor is the candidate's own, unclipped one.
    np.testing.assert_array_equal(np.asarray(rep.descriptors[19]), [100.0, 100.0])


def test_ties_keep_lowest_index_and_equal_never_replaces():
    rep = grid_repertoire(PARAMS_EXAMPLE, GRID_SHAPE, LOW, HIGH)
    d = jnp.zeros((3, 2)) + jnp.array([0.1, 0.1])
    rep, result = add_padded(rep, np.array([7, 8, 9]), d, [1.0, 2.0, 2.0])
    np.testing.assert_array_equal(np.asarray(result.added), [False, True, False])
    cell = int(result.cell[1])
    assert int(rep.genotypes["tag"][cell]) == 8
    # An equal candidate does not replace; a worse one neither; a better one does.
    rep, result = add_padded(rep, np.array([10, 11]), d[:2], [2.0, 1.5])
    assert not bool(jnp.any(result.added)) and int(rep.genotypes["tag"][cell]) == 8
    np.testing.assert_allclose(np.asarray(result.improvement), [0.0, -0.5])
    rep, result = add_padded(rep, np.array([12]), d[:1], [2.5])
    assert bool(result.added[0]) and not bool(result.new_cell[0])
    assert int(rep.genotypes["tag"][cell]) == 12 and float(result.improvement[0]) == 0.5


NON_FINITE_DESCRIPTORS = [[np.inf, 0.0], [-np.inf, 0.0], [0.5, np.inf], [np.nan, 0.5]]


@pytest.mark.parametrize("kind", ["grid", "cvt", "cvt_lookup", "unstructured", "passive"])
def test_non_finite_fitnesses_and_descriptors_are_rejected(kind):
    rep = make_repertoire(kind, None if kind == "passive" else PARAMS_EXAMPLE)
    ids = None if kind == "passive" else np.arange(1, 11)
    # +inf, -inf and NaN fitnesses at a good descriptor; then non-finite descriptors
    # (which a CVT search would send to centroid 0) with a good fitness.
    descriptors = np.array([[0.1, 0.1]] * 3 + NON_FINITE_DESCRIPTORS + [[0.1, 0.1]] * 3, np.float32)
    fitnesses = np.array([np.inf, -np.inf, np.nan] + [1.0] * 4 + [np.inf, np.nan, 1.0], np.float32)
    descriptors[8, 0] = np.inf  # a NaN fitness AND an infinite descriptor
    new, result = add_padded(rep, ids, descriptors, fitnesses)
    np.testing.assert_array_equal(np.asarray(result.cell)[:9], [-1] * 9)
    assert not bool(jnp.any(result.added[:9])) and not bool(jnp.any(result.new_cell[:9]))
    assert bool(jnp.all(result.improvement[:9] == -jnp.inf))
    # Only the last, finite candidate is stored; the metrics stay finite.
    assert bool(result.added[9]) and int(new.num_filled) == 1
    assert np.all(np.isfinite(np.asarray(new.fitnesses)) | (np.asarray(new.fitnesses) == -np.inf))
    metrics = qd_metrics(new, qd_offset=-1.0)
    assert float(metrics["qd_score"]) == 2.0 and float(metrics["max_fitness"]) == 1.0
    # Its cell can still be improved (a stored +inf could never be).
    new, result = add_padded(new, None if ids is None else ids[:1], descriptors[9:], [1.5])
    assert bool(result.added[0]) and float(jnp.max(new.fitnesses)) == 1.5


def test_minus_inf_fitness_is_never_stored():
    rep = grid_repertoire(None, GRID_SHAPE, LOW, HIGH)
    rep, result = add_padded(rep, None, np.zeros((1, 2)) + 0.5, [-np.inf])
    assert not bool(result.added[0]) and bool(rep.is_empty)


def test_flush_subnormals_maps_them_and_minus_zero_to_plus_zero():
    x = jnp.array([SUBNORMAL, -SUBNORMAL, 1e-45, -0.0, TINY, -TINY, 1.0, np.inf, np.nan])
    got = np.asarray(jax.jit(flush_subnormals)(x))
    np.testing.assert_array_equal(got[:4], 0.0)
    assert not np.any(np.signbit(got[:4]))  # +0.0, never -0.0
    np.testing.assert_array_equal(got[4:8], [TINY, -TINY, 1.0, np.inf])
    assert np.isnan(got[8])


@pytest.mark.parametrize("kind", ["grid", "cvt", "unstructured"])
def test_subnormal_fitnesses_compare_as_zero(kind):
    """The same rule on every backend: a subnormal ties with 0, the first of a tie wins."""
    rep = make_repertoire(kind, PARAMS_EXAMPLE)
    d = np.array([[0.1, 0.1]] * 3, np.float32)
    rep, result = add_padded(rep, np.array([1, 2, 3]), d, [-SUBNORMAL, SUBNORMAL, 0.0])
    np.testing.assert_array_equal(np.asarray(result.added), [True, False, False])
    cell = int(result.cell[0])
    stored = np.asarray(rep.fitnesses)[cell]
    assert stored == 0.0 and not np.signbit(stored) and int(rep.genotypes["tag"][cell]) == 1
    # A larger subnormal is not strictly better than the stored 0; a normal float is.
    rep, result = add_padded(rep, np.array([4, 5]), d[:2], [1e-39, 2 * TINY])
    np.testing.assert_array_equal(np.asarray(result.added), [False, True])
    np.testing.assert_array_equal(np.asarray(result.improvement), [0.0, 2 * TINY])


# --- CVT --------------------------------------------------------------------------


def cvt_batch(candidates, first_id: int):
    cells = np.array([c[0] for c in candidates])
    offsets = np.array([[c[1], c[2]] for c in candidates])
    descriptors = (CVT_CENTROIDS[cells] + offsets).astype(np.float32)
    set_bad_descriptors(descriptors, candidates, 4)
    fitnesses = np.array([c[3] for c in candidates], np.float32)
    cells = np.where(reference_valid(descriptors, fitnesses), cells, -1)
    return descriptors, fitnesses, cells, first_id + np.arange(len(candidates))


# A box around the fixture's centroids: candidates (within 0.2 of a centroid) fall
# inside and outside it, so the lookup grid's brute-force fallback is exercised too.
CVT_LOW, CVT_HIGH = (0.0, 0.0), (1.5, 1.0)


@SETTINGS
@given(batches=cvt_batches_st, lookup=st.booleans())
def test_cvt_add_matches_numpy_reference(batches, lookup):
    bounds = (CVT_LOW, CVT_HIGH) if lookup else (None, None)
    rep = cvt_repertoire(PARAMS_EXAMPLE, CVT_CENTROIDS, *bounds)
    assert (rep.lookup is not None) == lookup
    store = empty_store(rep)
    for b, candidates in enumerate(batches):
        descriptors, fitnesses, cells, ids = cvt_batch(candidates, 1 + 100 * b)
        before = np.asarray(rep.fitnesses)
        rep, result = jit_add(rep, params_batch(ids), descriptors, fitnesses)
        store, expected = reference_cell_insert(store, cells, descriptors, fitnesses, ids)
        assert_result_equal(result, expected)
        assert_store_equal(rep, store)
        assert np.all(np.asarray(rep.fitnesses) >= before)


def test_cvt_indexing_is_brute_force_nearest_centroid():
    centroids = np.random.default_rng(0).uniform(-1, 1, size=(50, 3)).astype(np.float32)
    rep = cvt_repertoire(None, centroids)
    # Points inside and far outside the box: every point has a nearest centroid.
    points = np.random.default_rng(1).uniform(-3, 3, size=(500, 3)).astype(np.float32)
    cells = np.asarray(rep.cell_index(jnp.asarray(points)))
    dist = np.sqrt(((points[:, None, :].astype(np.float64) - centroids[None]) ** 2).sum(-1))
    np.testing.assert_allclose(dist[np.arange(len(points)), cells], dist.min(1), rtol=1e-5)
    assert (cells == dist.argmin(1)).mean() > 0.99
    assert not rep.is_grid and rep.grid_shape is None


def test_cvt_centroids_reproducible_inside_box_and_spread():
    key = jax.random.key(3)
    c1 = np.asarray(cvt_centroids(key, 64, 10_000, (0.0, 0.0), (1.0, 1.0), num_iters=20))
    c2 = np.asarray(cvt_centroids(key, 64, 10_000, (0.0, 0.0), (1.0, 1.0), num_iters=20))
    c3 = np.asarray(
        cvt_centroids(jax.random.key(4), 64, 10_000, (0.0, 0.0), (1.0, 1.0), num_iters=20)
    )
    np.testing.assert_array_equal(c1, c2)
    assert not np.array_equal(c1, c3)
    assert c1.shape == (64, 2) and c1.dtype == np.float32
    assert np.all(c1 >= 0.0) and np.all(c1 <= 1.0)
    # Spread: every point of the square is near a centroid, and no two centroids crowd.
    points = np.random.default_rng(0).uniform(size=(5_000, 2))
    nearest = np.sqrt(((points[:, None] - c1[None]) ** 2).sum(-1)).min(1)
    assert nearest.max() < 0.14  # a cell has area 1/64: radius about 0.07
    pairwise = np.sqrt(((c1[:, None] - c1[None]) ** 2).sum(-1)) + 9 * np.eye(64)
    assert pairwise.min() > 0.05


def test_cvt_centroids_close_to_a_centroidal_tessellation():
    # Greedy k-means++ seeding then Lloyd: the mean squared distance of uniform points to
    # their nearest centroid (the quantisation error, 1e-4 units). Hexagonal cells of area
    # 1/128 would give 12.53 (boundary cells add to it). Seeds 0-4 here: 13.25-13.50;
    # scikit-learn's k-means (k-means++, one start) on 10,000 samples: 13.40-13.62; Lloyd
    # from a random subset of the samples (qdrl before) stalls at 13.43-13.75 (13.67 on
    # average over seeds 0-2).
    points = np.random.default_rng(123).uniform(size=(50_000, 2)).astype(np.float32)
    errors = []
    for seed in range(3):
        c = np.asarray(cvt_centroids(jax.random.key(seed), 128, 10_000, (0.0, 0.0), (1.0, 1.0)))
        errors.append(((points[:, None] - c[None]) ** 2).sum(-1).min(1).mean() * 1e4)
    assert 12.53 < np.mean(errors) < 13.55, errors


def test_cvt_centroids_scalar_bounds_and_errors():
    c = cvt_centroids(jax.random.key(0), 8, 200, -2.0, 2.0, num_iters=5, num_descriptors=3)
    assert c.shape == (8, 3) and bool(jnp.all(jnp.abs(c) <= 2.0))
    with pytest.raises(ValueError, match="num_descriptors"):
        cvt_centroids(jax.random.key(0), 8, 200, 0.0, 1.0)
    with pytest.raises(ValueError, match="num_centroids"):
        cvt_centroids(jax.random.key(0), 300, 200, (0.0,), (1.0,))
    with pytest.raises(ValueError, match="low < high"):
        cvt_centroids(jax.random.key(0), 8, 200, (0.0, 1.0), (1.0, 1.0))


# --- unstructured -------------------------------------------------------------------

L_VALUE = 0.25  # descriptors on a 0.1 lattice: no squared distance equals 0.0625
unstructured_candidate_st = st.tuples(
    st.integers(0, 10),
    st.integers(0, 10),
    fitness_st,
    st.sampled_from(BAD_DESCRIPTOR_VALUES),
    st.integers(0, 1),
)


def unstructured_batch(candidates, first_id: int):
    descriptors = np.array([[c[0], c[1]] for c in candidates], np.float32) * np.float32(0.1)
    set_bad_descriptors(descriptors, candidates, 3)
    fitnesses = np.array([c[2] for c in candidates], np.float32)
    return descriptors, fitnesses, first_id + np.arange(len(candidates))


@SETTINGS
@given(
    batches=st.lists(
        st.lists(unstructured_candidate_st, min_size=N, max_size=N), min_size=1, max_size=3
    )
)
def test_unstructured_add_matches_sequential_reference(batches):
    rep = unstructured_repertoire(PARAMS_EXAMPLE, 24, 2, L_VALUE)
    store = empty_store(rep)
    for b, candidates in enumerate(batches):
        descriptors, fitnesses, ids = unstructured_batch(candidates, 1 + 100 * b)
        before = np.asarray(rep.fitnesses)
        rep, result = jit_add(rep, params_batch(ids), descriptors, fitnesses)
        store, expected = reference_unstructured_insert(store, L_VALUE, descriptors, fitnesses, ids)
        assert_result_equal(result, expected)
        assert_store_equal(rep, store)
        assert np.all(np.asarray(rep.fitnesses) >= before)
        # Invariant of the second-nearest rule: elites stay pairwise >= l_value apart.
        kept = np.asarray(rep.descriptors)[np.asarray(rep.filled)]
        pairwise = np.sqrt(((kept[:, None] - kept[None]) ** 2).sum(-1)) + 9 * np.eye(len(kept))
        assert pairwise.size == 0 or pairwise.min() >= L_VALUE - 1e-6


def test_unstructured_threshold_on_constructed_example():
    rep = unstructured_repertoire(PARAMS_EXAMPLE, 3, 1, 1.0)
    # A at 0, B at 1.5: both novel (1.5 >= 1).
    rep, r = add_padded(rep, np.array([1, 2]), [[0.0], [1.5]], [1.0, 1.0])
    np.testing.assert_array_equal(np.asarray(r.cell), [0, 1])
    assert bool(jnp.all(r.new_cell))
    # C at 0.75 is within 1 of A and of B: replacing A would put it within 1 of B.
    # D at -0.5 is within 1 of A only, and fitter: replaces A.
    # E at -0.4 is within 1 of D (just stored): worse, so rejected.
    rep, r = add_padded(rep, np.array([3, 4, 5]), [[0.75], [-0.5], [-0.4]], [10.0, 10.0, 5.0])
    np.testing.assert_array_equal(np.asarray(r.added), [False, True, False])
    np.testing.assert_array_equal(np.asarray(r.cell), [0, 0, 0])
    np.testing.assert_allclose(np.asarray(r.improvement), [9.0, 9.0, -5.0])
    np.testing.assert_array_equal(stored_ids(rep.genotypes)[:2], [4, 2])
    # F novel fills the last slot; G novel finds the container full (cell -1).
    rep, r = add_padded(rep, np.array([6, 7]), [[5.0], [10.0]], [0.0, 0.0])
    np.testing.assert_array_equal(np.asarray(r.added), [True, False])
    np.testing.assert_array_equal(np.asarray(r.new_cell), [True, False])
    np.testing.assert_array_equal(np.asarray(r.cell), [2, -1])
    assert int(rep.num_filled) == rep.num_cells == rep.capacity == 3
    # With l = 2.5, H at 0.5 is within 2.5 of D and B: rejected however fit; I at 7
    # is within 2.5 of F only: replaces it. Stored elites are left as they are.
    wide = rep.with_l_value(2.5)
    assert float(wide.l_value) == 2.5 and wide.l_value.dtype == jnp.float32
    wide, r = add_padded(wide, np.array([8, 9]), [[0.5], [7.0]], [100.0, 100.0])
    np.testing.assert_array_equal(np.asarray(r.added), [False, True])
    np.testing.assert_array_equal(stored_ids(wide.genotypes), [4, 2, 9])


def test_unstructured_constructor_errors():
    with pytest.raises(ValueError, match="l_value"):
        unstructured_repertoire(None, 4, 2, 0.0)
    with pytest.raises(ValueError, match="capacity"):
        unstructured_repertoire(None, 0, 2, 1.0)


# --- sampling -----------------------------------------------------------------------


def make_repertoire(kind: str, genotype_example):
    if kind == "grid":
        return grid_repertoire(genotype_example, GRID_SHAPE, LOW, HIGH)
    if kind == "cvt":
        return cvt_repertoire(genotype_example, CVT_CENTROIDS)
    if kind == "cvt_lookup":
        return cvt_repertoire(genotype_example, CVT_CENTROIDS, CVT_LOW, CVT_HIGH)
    if kind == "passive":
        return passive_archive("cvt", centroids=CVT_CENTROIDS)
    return unstructured_repertoire(genotype_example, 24, 2, L_VALUE)


@pytest.mark.parametrize("kind", ["grid", "cvt", "unstructured"])
def test_sample_draws_only_filled_cells_uniformly(kind):
    rep = make_repertoire(kind, PARAMS_EXAMPLE)
    rng = np.random.default_rng(0)
    descriptors = rng.uniform(0.0, 1.5, size=(N, 2)).astype(np.float32)
    rep, _ = jit_add(rep, params_batch(np.arange(1, N + 1)), descriptors, np.ones(N, np.float32))
    filled = np.asarray(rep.filled)
    assert 1 < filled.sum() < rep.num_cells  # some cells filled, some empty
    samples = rep.sample(jax.random.key(0), 4_000)
    ids = stored_ids(samples)
    elite_ids = stored_ids(rep.genotypes)[filled]
    assert set(ids.tolist()) == set(elite_ids.tolist())  # every elite, and only elites
    np.testing.assert_array_equal(
        np.asarray(samples["linear"]["w"]), np.broadcast_to(ids[:, None, None], (4_000, 2, 3))
    )
    counts = np.unique(ids, return_counts=True)[1]
    expected = 4_000 / filled.sum()
    assert counts.min() > 0.7 * expected and counts.max() < 1.3 * expected


@pytest.mark.parametrize("kind", ["grid", "cvt", "unstructured"])
def test_sample_empty_repertoire_returns_nan_genotypes(kind):
    """Jitted code cannot raise: an empty repertoire's samples are NaN (ints 0), never zeros."""
    rep = make_repertoire(kind, PARAMS_EXAMPLE)
    assert bool(rep.is_empty) and int(rep.num_filled) == 0
    samples = jax.jit(lambda r, k: r.sample(k, 5))(rep, jax.random.key(1))
    assert samples["linear"]["w"].shape == (5, 2, 3)
    assert bool(jnp.all(jnp.isnan(samples["linear"]["w"])))
    assert bool(jnp.all(jnp.isnan(samples["linear"]["b"])))
    np.testing.assert_array_equal(np.asarray(samples["tag"]), 0)


@pytest.mark.parametrize("kind", ["grid", "cvt", "unstructured"])
def test_genotype_none(kind):
    rep = make_repertoire(kind, None)
    assert rep.genotypes is None
    rep, result = add_padded(rep, None, [[0.1, 0.1], [1.0, 1.0]], [1.0, 2.0])
    assert bool(jnp.all(result.added)) and int(rep.num_filled) == 2
    assert rep.sample(jax.random.key(0), 3) is None


# --- jit, shapes, compilation --------------------------------------------------------


@pytest.mark.parametrize("kind", ["grid", "cvt", "unstructured"])
def test_jit_add_equals_eager_add(kind):
    rep = make_repertoire(kind, PARAMS_EXAMPLE)
    rng = np.random.default_rng(2)
    for b in range(2):
        genotypes = params_batch(np.arange(N) + 1 + 100 * b)
        descriptors = rng.uniform(-0.5, 1.5, size=(N, 2)).astype(np.float32)
        fitnesses = rng.choice(np.array(FITNESS_VALUES, np.float32), size=N)
        eager, eager_result = rep.add(genotypes, descriptors, fitnesses)
        jitted, jit_result = jit_add(rep, genotypes, descriptors, fitnesses)
        for a, b in zip(
            jax.tree_util.tree_leaves((eager, eager_result)),
            jax.tree_util.tree_leaves((jitted, jit_result)),
            strict=True,
        ):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        rep = jitted


@pytest.mark.parametrize("kind", ["grid", "cvt", "unstructured"])
def test_add_compiles_once_and_keeps_the_pytree_type(kind):
    traces = []

    @jax.jit
    def add(repertoire, genotypes, descriptors, fitnesses):
        traces.append(1)
        return repertoire.add(genotypes, descriptors, fitnesses)

    rep = make_repertoire(kind, PARAMS_EXAMPLE)
    structure: Any = jax.tree_util.tree_structure(rep)  # Any: mypy cannot type PyTreeDef
    avals = [jax.typeof(leaf) for leaf in jax.tree_util.tree_leaves(rep)]
    rng = np.random.default_rng(3)
    for b in range(3):
        descriptors = rng.uniform(0, 1, size=(N, 2)).astype(np.float32)
        rep, _ = add(
            rep, params_batch(np.arange(N) + 100 * b), descriptors, np.ones(N, np.float32) * b
        )
    assert len(traces) == 1
    assert jax.tree_util.tree_structure(rep) == structure
    assert [jax.typeof(leaf) for leaf in jax.tree_util.tree_leaves(rep)] == avals

    # The whole insertion loop also runs under lax.scan.
    def body(r, xs):
        return r.add(*xs)[0], None

    descriptors = rng.uniform(0, 1, size=(4, N, 2)).astype(np.float32)
    ids = np.arange(4 * N).reshape(4, N)
    genotypes = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[params_batch(i) for i in ids])
    scanned, _ = jax.jit(lambda r, xs: jax.lax.scan(body, r, xs))(
        rep, (genotypes, descriptors, jnp.full((4, N), 10.0))
    )
    assert isinstance(scanned, type(rep)) and int(scanned.num_filled) >= int(rep.num_filled)


def test_add_rejects_bad_shapes_with_clear_messages():
    rep = grid_repertoire(PARAMS_EXAMPLE, GRID_SHAPE, LOW, HIGH)
    genotypes = params_batch(np.arange(3))
    with pytest.raises(ValueError, match=r"descriptors must have shape \(n, D\)"):
        rep.add(genotypes, jnp.zeros((3, 3)), jnp.zeros(3))
    with pytest.raises(ValueError, match="fitnesses must have shape"):
        rep.add(genotypes, jnp.zeros((3, 2)), jnp.zeros((3, 1)))
    with pytest.raises(ValueError, match="structure does not match"):
        rep.add({"w": jnp.zeros((3,))}, jnp.zeros((3, 2)), jnp.zeros(3))
    bad = dict(genotypes, tag=jnp.zeros((2,), jnp.int32))
    with pytest.raises(ValueError, match=r"leaf \['tag'\] must have shape \(3,\)"):
        rep.add(bad, jnp.zeros((3, 2)), jnp.zeros(3))


def test_constructor_errors():
    with pytest.raises(ValueError, match="grid_shape"):
        grid_repertoire(None, (0, 3), 0.0, 1.0)
    with pytest.raises(ValueError, match="low < high"):
        grid_repertoire(None, (2, 3), (0.0, 1.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="2 entries"):
        grid_repertoire(None, (2, 3), (0.0, 0.0, 0.0), 1.0)
    with pytest.raises(ValueError, match=r"shape \(C, D\)"):
        cvt_repertoire(None, np.zeros((3,)))


# --- passive archive and export ------------------------------------------------------


def test_passive_archive_observes_without_genotypes():
    grid = passive_archive("grid", grid_shape=GRID_SHAPE, low=LOW, high=HIGH)
    cvt = passive_archive("cvt", centroids=CVT_CENTROIDS)
    descriptors = jnp.array([[0.1, 0.1], [0.1, 0.1], [0.9, 1.9], [0.0, jnp.nan]])
    fitnesses = jnp.array([1.0, 3.0, 2.0, 5.0])
    for archive in (grid, cvt):
        assert isinstance(archive, CellRepertoire) and archive.genotypes is None
        archive = jax.jit(observe)(archive, descriptors, fitnesses)
        assert int(archive.num_filled) == 2
        assert float(jnp.max(archive.fitnesses)) == 3.0
    with pytest.raises(ValueError, match="grid_shape"):
        passive_archive("grid", grid_shape=GRID_SHAPE)
    with pytest.raises(ValueError, match="centroids"):
        passive_archive("cvt")
    with pytest.raises(ValueError, match="kind"):
        passive_archive("mome")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="passive"):
        observe(grid_repertoire(PARAMS_EXAMPLE, GRID_SHAPE, LOW, HIGH), descriptors, fitnesses)
    unstructured = observe(unstructured_repertoire(None, 8, 2, 0.5), descriptors, fitnesses)
    assert isinstance(unstructured, UnstructuredRepertoire) and int(unstructured.num_filled) == 2


def filled_grid() -> CellRepertoire:
    rep = grid_repertoire(PARAMS_EXAMPLE, GRID_SHAPE, LOW, HIGH)
    descriptors = jnp.array([[-0.9, 0.1], [0.1, 1.3], [0.9, 1.9]])
    rep, _ = add_padded(rep, np.array([1, 2, 3]), descriptors, [0.5, -1.0, 2.25])
    return rep


def test_to_table_and_csv_one_row_per_elite(tmp_path: Path):
    pandas = pytest.importorskip("pandas")
    rep = filled_grid()
    table = to_table(rep)
    assert list(table) == [
        "cell", "fitness", "descriptor_0", "descriptor_1", "centroid_0", "centroid_1"
    ]  # fmt: skip
    np.testing.assert_array_equal(table["cell"], [0, 13, 19])
    path = write_csv(rep, tmp_path / "sub" / "elites.csv")
    frame = pandas.read_csv(path)
    assert len(frame) == int(rep.num_filled) == 3
    np.testing.assert_array_equal(frame["cell"].to_numpy(), [0, 13, 19])
    np.testing.assert_array_equal(frame["fitness"].to_numpy(), [0.5, -1.0, 2.25])
    np.testing.assert_allclose(frame["descriptor_1"].to_numpy(), [0.1, 1.3, 1.9], rtol=1e-6)
    np.testing.assert_allclose(
        frame["centroid_0"].to_numpy(), np.asarray(rep.centroids)[[0, 13, 19], 0]
    )
    # Unstructured: no centroid columns; an empty repertoire gives a header only.
    empty = unstructured_repertoire(None, 4, 3, 1.0)
    assert list(to_table(empty)) == [
        "cell",
        "fitness",
        "descriptor_0",
        "descriptor_1",
        "descriptor_2",
    ]
    assert len(pandas.read_csv(write_csv(empty, tmp_path / "empty.csv"))) == 0
    # Columns named from the task's descriptor names (the summary's), as identifiers.
    named = pandas.read_csv(write_csv(rep, tmp_path / "named.csv", ("Back foot contact", "front-foot contact")))
    assert list(named)[2:] == [
        "descriptor_back_foot_contact", "descriptor_front_foot_contact",
        "centroid_back_foot_contact", "centroid_front_foot_contact",
    ]  # fmt: skip
    np.testing.assert_allclose(named["descriptor_front_foot_contact"].to_numpy(), [0.1, 1.3, 1.9], rtol=1e-6)
    assert descriptor_columns(("descriptor 0", "descriptor 1"), 2) == ["0", "1"]  # a task's default names
    assert descriptor_columns(("x", "X"), 2) == ["0", "1"]  # names that collide: indices


def test_export_npz_round_trip(tmp_path: Path):
    rep = filled_grid()
    path = export_npz(rep, tmp_path / "rep.npz")
    with np.load(path) as data:
        np.testing.assert_array_equal(data["fitnesses"], np.asarray(rep.fitnesses))
        np.testing.assert_array_equal(data["filled"], np.asarray(rep.filled))
        np.testing.assert_array_equal(data["grid_shape"], GRID_SHAPE)
        np.testing.assert_array_equal(
            data["genotypes['linear']['w']"], np.asarray(rep.genotypes["linear"]["w"])
        )
        assert data["centroids"].shape == (20, 2)


def test_repertoire_is_a_frozen_pytree():
    rep = grid_repertoire(None, GRID_SHAPE, LOW, HIGH)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rep.fitnesses = jnp.zeros(20)  # type: ignore[misc]
    leaves, treedef = jax.tree_util.tree_flatten(rep)
    assert len(leaves) == 3  # fitnesses, descriptors, centroids (genotypes None)
    rebuilt = jax.tree_util.tree_unflatten(treedef, leaves)
    assert rebuilt.grid_shape == GRID_SHAPE and rebuilt.low == LOW and rebuilt.high == HIGH


def test_cvt_lookup_grid_is_exact_and_used() -> None:
    """The lookup grid gives the brute-force nearest centroid, inside and outside the box."""
    from qdrl.qd.repertoires.lookup import brute_nearest, direct_nearest

    centroids = cvt_centroids(jax.random.PRNGKey(3), 300, 6_000, (0.0, -1.0), (2.0, 1.0))
    fast = cvt_repertoire(None, centroids, (0.0, -1.0), (2.0, 1.0))
    slow = cvt_repertoire(None, centroids)
    assert fast.lookup is not None and slow.lookup is None
    assert fast.lookup_table.shape[0] >= 4 * 300 and fast.lookup_table.shape[1] < 40
    points = jax.random.uniform(jax.random.PRNGKey(4), (5_000, 2), minval=-0.3, maxval=2.3)
    points = points.at[:, 1].add(-1.0)  # y in [-1.3, 1.3]: some outside the box
    got = np.asarray(jax.jit(fast.cell_index)(points))
    want = np.asarray(brute_nearest(points, fast.centroids))
    p, c = np.asarray(points, np.float64), np.asarray(centroids, np.float64)
    d_got = ((p - c[got]) ** 2).sum(-1)
    d_want = ((p - c[want]) ** 2).sum(-1)
    np.testing.assert_allclose(d_got, d_want, rtol=1e-5, atol=1e-9)
    assert np.mean(got == want) > 0.999
    np.testing.assert_array_equal(np.asarray(slow.cell_index(points)), want)
    # The search used off the CPU: the same cells (up to float32 near-ties).
    direct = np.asarray(jax.jit(direct_nearest)(points, fast.centroids))
    np.testing.assert_allclose(((p - c[direct]) ** 2).sum(-1), d_want, rtol=1e-5, atol=1e-9)
    assert np.mean(direct == want) > 0.999


def test_cvt_search_is_chosen_per_backend_when_lowered() -> None:
    """CPU: the lookup grid (gathers; in 2-D no conditional, the hull is searched for every
    row); GPU: the direct search, with no conditional (a host round trip on a GPU)."""
    # 1024 centroids spread like a CVT's (a jittered 32 x 32 grid; k-means would take seconds)
    grid = (np.stack(np.meshgrid(np.arange(32), np.arange(32)), -1).reshape(-1, 2) + 0.5) / 32
    jitter = np.random.default_rng(3).uniform(-0.3, 0.3, grid.shape) / 32
    rep = cvt_repertoire(None, grid + jitter, (0.0, 0.0), (1.0, 1.0))
    assert rep.lookup_hull is not None and 4 * rep.lookup_hull.shape[0] <= 1024

    def lowered(r: CellRepertoire, platform: str) -> str:
        traced = jax.jit(r.cell_index).trace(jnp.zeros((8, r.descriptor_dim)))
        return traced.lower(lowering_platforms=(platform,)).as_text(dialect="hlo")

    cpu, cuda = lowered(rep, "cpu"), lowered(rep, "cuda")
    assert " conditional(" not in cpu and " gather(" in cpu
    assert " conditional(" not in cuda and " gather(" not in cuda and " dot(" not in cuda
    # 3-D: the hull is most of the centroids, searched only when some row is outside the box
    c3 = cvt_centroids(jax.random.PRNGKey(3), 256, 5_000, (0.0,) * 3, (1.0,) * 3)
    rep3 = cvt_repertoire(None, c3, (0.0,) * 3, (1.0,) * 3)
    assert rep3.lookup_hull is not None and 4 * rep3.lookup_hull.shape[0] > 256
    assert " conditional(" in lowered(rep3, "cpu")


@pytest.mark.parametrize("dim", [pytest.param(1, marks=pytest.mark.slow), 2, pytest.param(3, marks=pytest.mark.slow)])
def test_cvt_lookup_is_exact_far_outside_the_box_and_with_centroids_outside(dim: int) -> None:
    """The lookup grid's search against exact float64 distances: points far outside the box,
    at its corners and on ties; centroids outside the box."""
    from qdrl.qd.repertoires.lookup import brute_nearest

    key = jax.random.PRNGKey(dim)
    inner = cvt_centroids(key, 200, 4_000, (0.0,) * dim, (1.0,) * dim)
    # three centroids outside the box, which points inside it may also be nearest to
    centroids = jnp.concatenate([inner, jnp.asarray([[-0.2] * dim, [1.5] * dim, [0.5] * (dim - 1) + [-3.0]])])
    rep = cvt_repertoire(None, centroids, (0.0,) * dim, (1.0,) * dim)
    assert rep.lookup is not None
    k1, k2 = jax.random.split(key)
    near = jax.random.uniform(k1, (3_000, dim), minval=-0.5, maxval=1.5)
    far = jax.random.normal(k2, (1_000, dim)) * 50.0
    corners = jnp.asarray(np.stack(np.meshgrid(*[[-1e3, 0.0, 1.0, 1e3]] * dim), -1).reshape(-1, dim), jnp.float32)
    # exact ties: midpoints of pairs of centroids, on both sides of the box's boundary
    ties = 0.5 * (centroids[:50] + centroids[50:100]) * 3.0 - 1.0
    points = jnp.concatenate([near, far, corners, ties])
    got = np.asarray(jax.jit(rep.cell_index)(points))
    want = np.asarray(brute_nearest(points, centroids))
    p, c = np.asarray(points, np.float64), np.asarray(centroids, np.float64)
    d_got, d_want = ((p - c[got]) ** 2).sum(-1), ((p - c[want]) ** 2).sum(-1)
    np.testing.assert_allclose(d_got, d_want, rtol=1e-5, atol=1e-9)
    # the brute force's expansion |c|^2 - 2 p.c rounds differently far away: compare exactly in float64
    exact = np.argmin(((p[:, None, :] - c[None]) ** 2).sum(-1), axis=1)
    assert np.mean(got == exact) > 0.995
