"""SBX crossover and per-gene polynomial mutation: bounds, the SBX spread distribution, rates."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.emitters.ga import bernoulli_polynomial_mutation, sbx_crossover, sbx_emitter


def test_sbx_spread_follows_its_distribution_away_from_the_bounds() -> None:
    """Far from the bounds, beta = |child - mid| / (half gap) has P(beta <= b) = b^(eta+1) / 2 for b <= 1."""
    n, eta = 200_000, 2.0
    x1, x2 = jnp.full((n, 1), 0.4), jnp.full((n, 1), 0.6)
    child = np.asarray(
        jax.jit(sbx_crossover, static_argnums=(3, 4, 5, 6, 7))(x1, x2, jax.random.PRNGKey(0), eta, -100.0, 100.0, 1.0, 1.0)
    )[:, 0]
    beta = np.abs(child - 0.5) / 0.1
    for b in (0.5, 0.8, 1.0):
        assert np.mean(beta <= b) == pytest.approx(0.5 * b ** (eta + 1), abs=0.01)
    assert np.mean(child > 0.5) == pytest.approx(0.5, abs=0.01)  # either child at random


def test_sbx_stays_in_bounds_and_keeps_uncrossed_genes() -> None:
    key = jax.random.PRNGKey(1)
    x1 = jax.random.uniform(key, (500, 30))
    x2 = jax.random.uniform(jax.random.PRNGKey(2), (500, 30))
    child = np.asarray(sbx_crossover(x1, x2, jax.random.PRNGKey(3), 20.0, 0.0, 1.0, 0.9, 0.5))
    assert child.min() >= 0.0 and child.max() <= 1.0
    unchanged = np.all(child == np.asarray(x1), axis=1)
    assert np.mean(unchanged) == pytest.approx(0.1, abs=0.04)  # pairs that do not cross (0.1)
    changed = child != np.asarray(x1)
    assert changed[~unchanged].mean() == pytest.approx(0.5, abs=0.02)  # 0.5 per gene when crossing


def test_mutation_rate_and_emitter() -> None:
    x = jnp.full((2000, 30), 0.5)
    y = np.asarray(bernoulli_polynomial_mutation(x, jax.random.PRNGKey(0), 20.0, 1 / 30, 0.0, 1.0))
    assert np.mean(y != 0.5) == pytest.approx(1 / 30, abs=0.003)
    assert y.min() >= 0.0 and y.max() <= 1.0
    emitter = sbx_emitter(8, 20.0, 20.0, 0.1, 0.0, 1.0)
    assert emitter.num_variation == 8 and emitter.num_mutation == 0
    with pytest.raises(ValueError, match="mutation_prob must be in"):
        bernoulli_polynomial_mutation(x, jax.random.PRNGKey(0), 20.0, 1.5, 0.0, 1.0)
    with pytest.raises(ValueError, match="crossover_prob must be in"):
        sbx_crossover(x, x, jax.random.PRNGKey(0), 20.0, 0.0, 1.0, crossover_prob=2.0)


def test_children_that_copy_a_parent_are_drawn_again() -> None:
    # Equal parents never cross; each of 4 genes mutates with probability 0.2, so a draw copies
    # its parent with probability 0.8^4 = 0.41, and after 3 more draws with 0.41^4 = 0.028.
    n = 4000
    x = jnp.full((n, 4), 0.5)
    copies = {}
    for redraws in (0, 3):
        emitter = sbx_emitter(n, 20.0, 20.0, 0.2, 0.0, 1.0, redraws=redraws)
        assert emitter.variation_fn is not None
        child = emitter.variation_fn(x, x, jax.random.PRNGKey(0))
        assert child.shape == x.shape and bool(jnp.all((child >= 0.0) & (child <= 1.0)))
        copies[redraws] = float(jnp.mean(jnp.all(child == x, axis=1)))
    assert 0.38 < copies[0] < 0.44
    assert 0.018 < copies[3] < 0.040
    with pytest.raises(ValueError, match="redraws"):
        sbx_emitter(8, 20.0, 20.0, 0.2, 0.0, 1.0, redraws=-1)
