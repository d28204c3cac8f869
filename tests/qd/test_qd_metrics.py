"""Tests for qdrl.qd.metrics.qd_metrics: hand-computed values, empty repertoires, jit."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.metrics import qd_metrics
from qdrl.qd.repertoires import grid_repertoire, unstructured_repertoire


def hand_built_grid():
    """A 2 x 2 grid holding fitnesses [1, empty, 3, 0.5]."""
    rep = grid_repertoire(None, (2, 2), 0.0, 1.0)
    return dataclasses.replace(rep, fitnesses=jnp.array([1.0, -jnp.inf, 3.0, 0.5]))


def test_metrics_on_hand_built_repertoire():
    metrics = qd_metrics(hand_built_grid(), qd_offset=-1.0)
    # qd_score = (1 + 1) + (3 + 1) + (0.5 + 1) = 7.5 over the three filled cells.
    assert float(metrics["qd_score"]) == 7.5
    assert float(metrics["normalised_qd_score"]) == 7.5 / 4  # per cell, empty ones included
    assert float(metrics["coverage"]) == 0.75
    assert float(metrics["max_fitness"]) == 3.0
    assert float(metrics["mean_fitness"]) == 1.5
    assert int(metrics["num_elites"]) == 3
    assert metrics["num_elites"].dtype == jnp.int32
    assert all(metrics[k].dtype == jnp.float32 for k in ("qd_score", "coverage", "max_fitness"))
    # The offset shifts the QD score by num_elites * offset and nothing else.
    shifted = qd_metrics(hand_built_grid(), qd_offset=0.0)
    assert float(shifted["qd_score"]) == 4.5
    assert float(shifted["max_fitness"]) == 3.0


def test_metrics_of_empty_repertoire():
    metrics = qd_metrics(grid_repertoire(None, (3, 3), 0.0, 1.0), qd_offset=0.0)
    assert float(metrics["qd_score"]) == 0.0
    assert float(metrics["coverage"]) == 0.0
    assert float(metrics["max_fitness"]) == -math.inf
    assert math.isnan(float(metrics["mean_fitness"]))
    assert int(metrics["num_elites"]) == 0


def test_unstructured_coverage_is_filled_over_capacity():
    rep = unstructured_repertoire(None, 8, 2, 0.1)
    rep, _ = jax.jit(lambda r, d, f: r.add(None, d, f))(
        rep, jnp.array([[0.0, 0.0], [1.0, 1.0]]), jnp.array([2.0, 4.0])
    )
    metrics = qd_metrics(rep, qd_offset=0.0)
    assert float(metrics["coverage"]) == 0.25
    assert float(metrics["qd_score"]) == 6.0 and float(metrics["mean_fitness"]) == 3.0


def test_metrics_are_jittable_and_match_eager():
    rep = hand_built_grid()
    eager = qd_metrics(rep, 2.0)
    jitted = jax.jit(qd_metrics)(rep, 2.0)  # the offset may also be traced
    for key, value in eager.items():
        np.testing.assert_array_equal(np.asarray(jitted[key]), np.asarray(value))
