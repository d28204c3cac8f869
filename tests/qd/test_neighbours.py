"""The two-stage nearest-neighbour search against one brute-force top_k, ties included."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.neighbours import nearest_in_prefix, smallest_k, squared_distances

SETTINGS = settings(max_examples=30, deadline=None, database=None, derandomize=True)
_smallest = jax.jit(smallest_k, static_argnames=("k", "group"))
_nearest = jax.jit(nearest_in_prefix, static_argnames=("k", "block", "group"))


@st.composite
def rows(draw: st.DrawFn) -> tuple[np.ndarray, int, int]:
    """A (3, n) matrix of small integers (many ties), some +inf, with k and a group size."""
    n = draw(st.integers(1, 300))
    x = np.asarray(draw(st.lists(st.integers(0, 6), min_size=3 * n, max_size=3 * n)), np.float32).reshape(3, n)
    x[x == 6] = np.inf
    return x, draw(st.integers(1, min(n, 12))), draw(st.sampled_from([2, 4, 8, 32]))


@SETTINGS
@given(rows())
def test_smallest_k_is_top_k_of_the_negation_with_its_tie_order(case: tuple[np.ndarray, int, int]) -> None:
    x, k, group = case
    values, index = _smallest(jnp.asarray(x), k=k, group=group)
    neg, expected = jax.lax.top_k(-jnp.asarray(x), k)
    np.testing.assert_array_equal(np.asarray(values), -np.asarray(neg))
    np.testing.assert_array_equal(np.asarray(index), np.asarray(expected))


@pytest.mark.parametrize(("dim", "integer"), [(1, True), (2, True), (2, False), (3, False), (20, False)])
def test_nearest_in_prefix_reads_only_the_prefix_and_matches_brute_force(dim: int, integer: bool) -> None:
    rng = np.random.default_rng(dim)
    cap, n, k = 2_000, 37, 9
    draw = (lambda *s: rng.integers(0, 5, s)) if integer else (lambda *s: rng.normal(size=s))
    points, queries = draw(cap, dim).astype(np.float32), draw(n, dim).astype(np.float32)
    sq_all = np.sum((queries[:, None] - points[None]) ** 2, -1)
    for count in (0, 5, 700, cap):
        sq, slots = _nearest(jnp.asarray(queries), jnp.asarray(points), jnp.asarray(count), k=k, block=256, group=16)
        ref = np.where(np.arange(cap)[None] < count, sq_all, np.inf)
        order = np.lexsort((np.broadcast_to(np.arange(cap), ref.shape), ref), axis=-1)[:, :k]  # value, then slot
        expected = np.take_along_axis(ref, order, -1)
        np.testing.assert_allclose(np.asarray(sq), expected, rtol=1e-5, atol=1e-5)
        finite = np.isfinite(expected)
        assert np.all(np.asarray(slots) < cap) and np.array_equal(np.isfinite(np.asarray(sq)), finite)
        if integer:  # exact values: the slots too, lower slot first among equal distances
            np.testing.assert_array_equal(np.asarray(slots)[finite], order[finite])


def test_squared_distances_are_the_same_values_for_shared_and_per_row_candidates() -> None:
    rng = np.random.default_rng(0)
    for dim in (2, 20):
        p, o = rng.normal(size=(5, dim)).astype(np.float32), rng.normal(size=(7, dim)).astype(np.float32)
        shared = squared_distances(jnp.asarray(p), jnp.asarray(o))
        per_row = squared_distances(jnp.asarray(p), jnp.broadcast_to(jnp.asarray(o), (5, 7, dim)))
        np.testing.assert_allclose(shared, np.sum((p[:, None] - o[None]) ** 2, -1), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(shared, per_row, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match=r"expected 1 <= k <= 4"):
        smallest_k(jnp.zeros((2, 4)), 5)
    with pytest.raises(ValueError, match=r"expected 1 <= k <= 3"):
        nearest_in_prefix(jnp.zeros((2, 2)), jnp.zeros((3, 2)), jnp.asarray(3), 4)
