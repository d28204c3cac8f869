"""Pareto utilities against brute-force NumPy references (hypothesis), ties and padding included."""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pareto_reference import crowding as _crowding
from pareto_reference import dominates as _dominates
from pareto_reference import hypervolume as _hypervolume
from pareto_reference import pruned as _pruned
from pareto_reference import ranks as _ranks

from qdrl.qd import pareto

# Small integer coordinates make ties and duplicates frequent. Sizes are fixed per
# compiled function (n = 8 rows, a random share of them masked out) so that each
# function compiles once per number of objectives.
N = 8


def _points(m: int) -> st.SearchStrategy[tuple[np.ndarray, np.ndarray]]:
    coords = st.lists(st.integers(0, 4), min_size=N * m, max_size=N * m)
    masks = st.lists(st.booleans(), min_size=N, max_size=N)
    return st.tuples(coords, masks).map(
        lambda t: (np.asarray(t[0], np.float32).reshape(N, m), np.asarray(t[1], bool))
    )


@pytest.fixture(scope="module")
def jitted() -> dict[str, object]:
    return {
        "dom": jax.jit(pareto.dominance_matrix),
        "nd": jax.jit(pareto.non_dominated),
        "ranks": jax.jit(pareto.front_ranks),
        "crowd": jax.jit(pareto.crowding_distance),
        "hv2": jax.jit(pareto.hypervolume_2d),
        "prune": jax.jit(pareto.prune_crowding),
    }


@settings(max_examples=60, deadline=None)
@given(data=st.integers(2, 3).flatmap(_points))
def test_dominance_fronts_and_crowding_match_brute_force(
    data: tuple[np.ndarray, np.ndarray], jitted: dict[str, object]
) -> None:
    p, mask = data
    n = len(p)
    dom = np.asarray(jitted["dom"](p, mask))  # type: ignore[operator]
    for i, j in itertools.product(range(n), range(n)):
        assert dom[i, j] == (mask[i] and mask[j] and _dominates(p[i], p[j]))
    assert not dom[np.arange(n), np.arange(n)].any()  # equal points never dominate
    ranks = _ranks(p, mask)
    np.testing.assert_array_equal(np.asarray(jitted["ranks"](p, mask)), ranks)  # type: ignore[operator]
    np.testing.assert_array_equal(np.asarray(jitted["nd"](p, mask)), mask & (ranks == 0))  # type: ignore[operator]
    crowd = np.asarray(jitted["crowd"](p, mask, jnp.asarray(ranks)))  # type: ignore[operator]
    np.testing.assert_allclose(crowd, _crowding(p, mask, ranks), rtol=1e-6)


@settings(max_examples=80, deadline=None)
@given(data=st.integers(2, 3).flatmap(_points), keep=st.integers(0, N))
def test_pruning_crowding_matches_brute_force(
    data: tuple[np.ndarray, np.ndarray], keep: int, jitted: dict[str, object]
) -> None:
    p, mask = data
    if not mask.any():
        return
    kept, dist = jitted["prune"](p, mask, keep)  # type: ignore[operator]
    ref_kept, ref_dist = _pruned(p, mask, keep)
    np.testing.assert_array_equal(np.asarray(kept), ref_kept)
    np.testing.assert_allclose(np.asarray(dist), ref_dist, rtol=1e-6)
    assert int(np.sum(kept)) >= min(keep, int(mask.sum()))


def test_pruning_keeps_one_of_a_close_pair_where_one_cut_drops_both() -> None:
    # Seven points on the line f2 = 1 - f1 (maximised as -f): the close pair at 0.40 / 0.43
    # has the two smallest crowding distances; one cut to 5 removes both, pruning only one
    # (then the point at 0.8, whose neighbours are nearer once 0.43 is gone).
    x = np.array([0.0, 0.15, 0.40, 0.43, 0.62, 0.8, 1.0], np.float32)
    p = -np.stack([x, 1.0 - x], axis=1)
    mask = np.ones(7, bool)
    one_cut = np.argsort(-np.asarray(pareto.crowding_distance(p, mask)), kind="stable")[:5]
    assert sorted(one_cut.tolist()) == [0, 1, 4, 5, 6]
    kept, dist = pareto.prune_crowding(p, mask, 5)
    assert np.flatnonzero(np.asarray(kept)).tolist() == [0, 1, 2, 4, 6]
    # Two objectives, each adding the gap between the neighbours left.
    np.testing.assert_allclose(np.asarray(dist)[[1, 2, 4]], [0.80, 0.94, 1.2], rtol=1e-5)
    assert np.isinf(np.asarray(dist)[[0, 6]]).all() and np.isneginf(np.asarray(dist)[[3, 5]]).all()


@settings(max_examples=60, deadline=None)
@given(data=_points(2))
def test_hypervolume_2d_matches_brute_force_and_moocore(
    data: tuple[np.ndarray, np.ndarray], jitted: dict[str, object]
) -> None:
    p, mask = data
    ref = np.array([0.5, -0.5], np.float32)
    expected = _hypervolume(p[mask], ref)
    got = float(jitted["hv2"](p, ref, mask))  # type: ignore[operator]
    assert got == pytest.approx(expected, abs=1e-5)
    assert pareto.hypervolume_exact(p, ref, mask) == pytest.approx(expected, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(data=st.integers(3, 4).flatmap(_points))
def test_exact_hypervolume_of_three_and_four_objectives_matches_brute_force(
    data: tuple[np.ndarray, np.ndarray],
) -> None:
    p, mask = data
    ref = np.full(p.shape[1], -0.5)
    assert pareto.hypervolume_exact(p, ref, mask) == pytest.approx(_hypervolume(p[mask], ref), abs=1e-9)


def test_monte_carlo_hypervolume_is_within_its_standard_error() -> None:
    p = np.random.default_rng(0).uniform(0, 1, (20, 3)).astype(np.float32)
    ref = np.zeros(3, np.float32)
    exact = pareto.hypervolume_exact(p, ref)
    est = float(jax.jit(pareto.hypervolume_mc, static_argnames="num_samples")(
        p, ref, jax.random.PRNGKey(0), num_samples=200_000))
    assert abs(est - exact) < 4 * math.sqrt(0.25 / 200_000) + 1e-3


def test_padding_and_edge_cases() -> None:
    p = jnp.array([[1.0, 1.0], [1.0, 1.0], [2.0, 0.0], [5.0, 5.0]])
    mask = jnp.array([True, True, True, False])  # the padded row would dominate all
    assert pareto.non_dominated(p, mask).tolist() == [True, True, True, False]
    assert pareto.front_ranks(p, mask).tolist() == [0, 0, 0, 4]
    assert float(pareto.hypervolume_2d(p, jnp.zeros(2), mask)) == 1.0  # (2, 0) is on the border
    assert float(pareto.hypervolume_2d(p, jnp.zeros(2), jnp.zeros(4, bool))) == 0.0
    assert pareto.hypervolume_exact(np.zeros((0, 3)), [0, 0, 0]) == 0.0
    with pytest.raises(ValueError, match="reference of M values"):
        pareto.hypervolume_exact(np.zeros((2, 3)), [0, 0])
