"""Tests for qdrl.qd.metrics.cqd_score: tiny cases by hand, a NumPy reference of the formula
(pyribs' 0.12) on hypothesis-drawn elites and targets, and the target points' helper."""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.metrics import cqd_score, cqd_target_points
from qdrl.qd.repertoires import grid_repertoire

SETTINGS = settings(max_examples=30, deadline=None, database=None, derandomize=True)
C, T, DRAWS, P = 8, 5, 2, 3  # elites, targets per draw, draws, penalties (fixed: one compile per norm)
DIAGONAL = 2.0 * math.sqrt(2.0)  # of the box [-1, 1]^2


@functools.partial(jax.jit, static_argnames=("dist_ord",))
def score(
    descriptors: np.ndarray, fitnesses: np.ndarray, targets: np.ndarray, penalties: np.ndarray, dist_ord: float = 2
) -> jax.Array:
    return cqd_score(descriptors, fitnesses, targets, penalties, 0.0, 2.0, 3.0, dist_ord)


def test_one_elite_by_hand() -> None:
    # f = 1 on [0, 1] at the origin, target (1, 1): distance sqrt(2) = half the diagonal.
    # theta = 0: 1; theta = 1: 1 - 0.5; summed over the two penalties: 1.5.
    value = cqd_score(jnp.zeros((1, 2)), jnp.ones(1), jnp.ones((1, 2)), 2, 0.0, 1.0, DIAGONAL)
    assert float(value) == pytest.approx(1.5)


def test_the_best_elite_per_target_and_penalty_by_hand() -> None:
    descriptors = jnp.array([[0.0, 0.0], [1.0, 1.0], [5.0, 5.0]])
    fitnesses = jnp.array([0.25, 0.0, -jnp.inf])  # the third cell is empty: left out
    # Target (1, 1): theta = 0 -> max(0.25, 0) = 0.25; theta = 1 -> max(0.25 - 0.5, 0 - 0) = 0.
    # Target (0, 0): theta = 0 -> 0.25; theta = 1 -> max(0.25, 0 - 0.5) = 0.25. Sum: 0.75.
    targets = jnp.array([[1.0, 1.0], [0.0, 0.0]])
    assert float(cqd_score(descriptors, fitnesses, targets, 2, 0.0, 1.0, DIAGONAL)) == pytest.approx(0.75)


def test_terms_are_not_clipped_and_obj_min_only_scales_as_in_pyribs() -> None:
    # L1 distance |(0, 0) - (1, 1)| = 2 = dist_max; f = 0.5 / (2 - 1) = 0.5 (obj_min is not subtracted).
    value = cqd_score(jnp.zeros((1, 2)), jnp.array([0.5]), jnp.ones((1, 2)), [0.0, 1.0], 1.0, 2.0, 2.0, dist_ord=1)
    assert float(value) == pytest.approx(0.5 + (0.5 - 1.0))  # the theta = 1 term is -0.5


def test_draws_are_averaged_and_an_empty_archive_scores_minus_inf() -> None:
    descriptors, fitnesses = jnp.zeros((1, 2)), jnp.ones(1)
    draws = jnp.array([[[1.0, 1.0]], [[0.0, 0.0]]])  # half the diagonal away, then on the elite
    value = cqd_score(descriptors, fitnesses, draws, jnp.array([1.0]), 0.0, 1.0, DIAGONAL)
    assert float(value) == pytest.approx((0.5 + 1.0) / 2)
    empty = grid_repertoire(None, (2, 2), -1.0, 1.0)
    assert float(cqd_score(empty.descriptors, empty.fitnesses, draws, 3, 0.0, 1.0, DIAGONAL)) == -math.inf


def numpy_cqd(
    descriptors: np.ndarray, fitnesses: np.ndarray, targets: np.ndarray, penalties: np.ndarray, dist_ord: float
) -> float:
    """The formula in float64: per draw, sum over penalties and targets of the max over elites."""
    keep = np.isfinite(fitnesses)
    quality, points = fitnesses[keep] / (2.0 - 0.0), descriptors[keep]
    scores = []
    for draw in targets:
        distance = np.linalg.norm(points[:, None] - draw[None], ord=dist_ord, axis=2) / 3.0
        scores.append(sum(np.sum(np.max(quality[:, None] - theta * distance, axis=0)) for theta in penalties))
    return float(np.mean(scores))


coordinate = st.floats(-1.0, 1.0, width=32)
fitness = st.one_of(st.floats(0.0, 2.0, width=32), st.just(-math.inf))


@SETTINGS
@given(
    descriptors=st.lists(coordinate, min_size=2 * C, max_size=2 * C),
    fitnesses=st.lists(fitness, min_size=C, max_size=C).filter(lambda f: any(v > -math.inf for v in f)),
    targets=st.lists(coordinate, min_size=DRAWS * T * 2, max_size=DRAWS * T * 2),
    penalties=st.lists(st.floats(0.0, 1.0, width=32), min_size=P, max_size=P),
    dist_ord=st.sampled_from([1, 2, math.inf]),
)
def test_matches_a_numpy_reference(
    descriptors: list[float], fitnesses: list[float], targets: list[float], penalties: list[float], dist_ord: float
) -> None:
    d = np.array(descriptors, np.float32).reshape(C, 2)
    f = np.array(fitnesses, np.float32)
    t = np.array(targets, np.float32).reshape(DRAWS, T, 2)
    p = np.array(penalties, np.float32)
    got = float(score(d, f, t, p, dist_ord=dist_ord))
    want = numpy_cqd(d.astype(np.float64), f.astype(np.float64), t.astype(np.float64), p.astype(np.float64), dist_ord)
    assert got == pytest.approx(want, rel=1e-5, abs=1e-4)


def test_target_points_are_fixed_by_the_key_and_lie_in_the_box() -> None:
    key = jax.random.key(3)
    points = cqd_target_points(key, [0.0, -1.0], [1.0, 1.0], 100)
    assert points.shape == (100, 2)
    np.testing.assert_array_equal(points, cqd_target_points(key, [0.0, -1.0], [1.0, 1.0], 100))
    assert float(points[:, 0].min()) >= 0.0 and float(points[:, 1].min()) >= -1.0
    assert float(points.max()) <= 1.0
    assert cqd_target_points(key, [0.0], [1.0], 7, iterations=3).shape == (3, 7, 1)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((jnp.zeros((2, 2)), jnp.zeros(3), jnp.zeros((1, 2)), 2, 0.0, 1.0, 1.0), "descriptors"),
        ((jnp.zeros((2, 2)), jnp.zeros(2), jnp.zeros((1, 3)), 2, 0.0, 1.0, 1.0), "target_points"),
        ((jnp.zeros((2, 2)), jnp.zeros(2), jnp.zeros((1, 2)), 0, 0.0, 1.0, 1.0), "penalty"),
        ((jnp.zeros((2, 2)), jnp.zeros(2), jnp.zeros((1, 2)), jnp.zeros((2, 2)), 0.0, 1.0, 1.0), "1-D"),
        ((jnp.zeros((2, 2)), jnp.zeros(2), jnp.zeros((1, 2)), 2, 1.0, 1.0, 1.0), "obj_min < obj_max"),
        ((jnp.zeros((2, 2)), jnp.zeros(2), jnp.zeros((1, 2)), 2, 0.0, 1.0, 0.0), "dist_max"),
    ],
)
def test_bad_arguments_are_named(args: tuple[Any, ...], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        cqd_score(*args)
