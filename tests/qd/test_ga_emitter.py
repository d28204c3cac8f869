"""Tests for qdrl.qd.emitters.ga: variation operators by hand, bounds, and the GA emitter's batch."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.emitters import (
    GAEmitter,
    gaussian_mutation,
    isoline_emitter,
    isoline_variation,
    polynomial_crossover,
    polynomial_emitter,
    polynomial_mutation,
)


class FakeRepertoire(NamedTuple):
    """Just enough repertoire: genotypes (C, ...), fitnesses (C,) with -inf where empty."""

    genotypes: Any
    fitnesses: jax.Array

    def sample(self, key: jax.Array, num_samples: int) -> Any:
        logits = jnp.where(jnp.isfinite(self.fitnesses), 0.0, -jnp.inf)
        idx = jax.random.categorical(key, logits, shape=(num_samples,))
        return jax.tree.map(lambda x: x[idx], self.genotypes)


def make_repertoire(genotypes: Any, filled: np.ndarray) -> FakeRepertoire:
    return FakeRepertoire(genotypes, jnp.where(jnp.asarray(filled), 1.0, -jnp.inf))


# --- isoline ------------------------------------------------------------------


def test_isoline_matches_the_formula_with_the_same_keys() -> None:
    x1 = jax.random.uniform(jax.random.PRNGKey(1), (3, 4))
    x2 = jax.random.uniform(jax.random.PRNGKey(2), (3, 4))
    key = jax.random.PRNGKey(3)
    child = isoline_variation(x1, x2, key, iso_sigma=0.1, line_sigma=0.3)
    noise = np.asarray(jax.random.normal(key, (15,)))  # 3 line coefficients, then 3 x 4 genes' noise
    line, iso = noise[:3], noise[3:].reshape(3, 4)
    expected = np.asarray(x1) + 0.1 * iso + 0.3 * line[:, None] * np.asarray(x2 - x1)
    np.testing.assert_allclose(np.asarray(child), expected, rtol=1e-6, atol=1e-6)


def test_isoline_line_component_is_along_the_parents_on_every_leaf() -> None:
    keys = jax.random.split(jax.random.PRNGKey(4), 4)
    x1 = {"w": jax.random.normal(keys[0], (5, 3)), "b": jax.random.normal(keys[1], (5, 2, 2))}
    x2 = {"w": jax.random.normal(keys[2], (5, 3)), "b": jax.random.normal(keys[3], (5, 2, 2))}
    child = jax.jit(lambda a, b, k: isoline_variation(a, b, k, iso_sigma=0.0, line_sigma=0.5))(
        x1, x2, jax.random.PRNGKey(5)
    )
    assert jax.tree.structure(child) == jax.tree.structure(x1)
    ratios = []
    for name in ("w", "b"):
        step = np.asarray(child[name] - x1[name]).reshape(5, -1)
        direction = np.asarray(x2[name] - x1[name]).reshape(5, -1)
        t = np.sum(step * direction, axis=1) / np.sum(direction * direction, axis=1)
        np.testing.assert_allclose(step, t[:, None] * direction, atol=1e-5)
        ratios.append(t)
    np.testing.assert_allclose(ratios[0], ratios[1], rtol=1e-5)  # one line scalar per individual
    assert np.std(ratios[0]) > 0  # ... but different across individuals


def test_isoline_noise_of_a_pytree_is_one_draw_split_over_the_leaves() -> None:
    # Leaves flatten in key order ("b" then "w"): 6 line coefficients, then b's 6 x 4 entries, then w's 6 x 3.
    x1 = {"w": jnp.zeros((6, 3)), "b": jnp.zeros((6, 2, 2))}
    x2 = {"w": jnp.ones((6, 3)), "b": jnp.ones((6, 2, 2))}
    key = jax.random.PRNGKey(11)
    child = isoline_variation(x1, x2, key, iso_sigma=0.5, line_sigma=2.0)
    noise = np.asarray(jax.random.normal(key, (6 * 8,)))
    line = 2.0 * noise[:6, None]
    b_noise, w_noise = noise[6:30].reshape(6, 4), noise[30:].reshape(6, 3)
    np.testing.assert_allclose(np.asarray(child["b"]).reshape(6, 4), line + 0.5 * b_noise, atol=1e-6)
    np.testing.assert_allclose(np.asarray(child["w"]), line + 0.5 * w_noise, atol=1e-6)
    # Independent noise per entry: no two columns equal.
    iso = np.concatenate([np.asarray(child["b"]).reshape(6, 4), np.asarray(child["w"])], 1) - line
    assert len({tuple(np.round(c, 6)) for c in iso.T}) == 7


def test_isoline_clips_and_is_identity_with_zero_sigmas() -> None:
    x1 = jnp.full((64, 3), 0.5)
    x2 = jnp.full((64, 3), 0.9)
    child = isoline_variation(x1, x2, jax.random.PRNGKey(6), 1.0, 1.0, minval=0.0, maxval=1.0)
    assert float(child.min()) >= 0.0 and float(child.max()) <= 1.0
    assert float(child.min()) == 0.0 and float(child.max()) == 1.0  # the clip was active
    same = isoline_variation(x1, x2, jax.random.PRNGKey(6), 0.0, 0.0)
    np.testing.assert_array_equal(same, x1)


# --- polynomial mutation and crossover -------------------------------------------


def test_polynomial_mutation_stays_in_bounds_and_changes_the_requested_genes() -> None:
    x = jax.random.uniform(jax.random.PRNGKey(7), (256, 10), minval=-1.0, maxval=1.0)
    x = x.at[:8].set(-1.0).at[8:16].set(1.0)  # genes sitting on the bounds
    mutate = jax.jit(
        lambda x, k: polynomial_mutation(
            x, k, eta=1.0, proportion_to_mutate=0.3, minval=-1.0, maxval=1.0
        )
    )
    child = np.asarray(mutate(x, jax.random.PRNGKey(8)))
    assert child.min() >= -1.0 and child.max() <= 1.0
    changed = np.sum(child != np.asarray(x), axis=1)
    assert changed.max() == 3 and np.mean(changed == 3) > 0.9  # floor(0.3 * 10) genes each
    # mutation is unbiased in the middle of the range
    mid = polynomial_mutation(jnp.zeros((4000, 1)), jax.random.PRNGKey(9), 5.0, 1.0, -1.0, 1.0)
    assert abs(float(jnp.mean(mid))) < 0.01


def test_polynomial_mutation_matches_debs_formula() -> None:
    x = jnp.array([[0.3]])
    key = jax.random.PRNGKey(10)
    eta = 20.0
    child = polynomial_mutation(x, key, eta, 1.0, minval=0.0, maxval=2.0)
    # the keys as documented: per leaf, then (mask, rand)
    _, rand_key = jax.random.split(jax.random.split(key, 1)[0])
    u = float(jax.random.uniform(rand_key, (1, 1))[0, 0])
    delta_1, delta_2 = 0.3 / 2.0, 1.7 / 2.0
    if u < 0.5:
        delta_q = (2 * u + (1 - 2 * u) * (1 - delta_1) ** (eta + 1)) ** (1 / (eta + 1)) - 1
    else:
        delta_q = 1 - (2 * (1 - u) + 2 * (u - 0.5) * (1 - delta_2) ** (eta + 1)) ** (1 / (eta + 1))
    assert float(child[0, 0]) == pytest.approx(0.3 + 2.0 * delta_q, rel=1e-5)


def test_polynomial_mutation_with_proportion_zero_is_identity_and_larger_eta_is_smaller() -> None:
    x = {"a": jax.random.uniform(jax.random.PRNGKey(11), (32, 6)), "b": jnp.full((32, 2, 3), 0.5)}
    same = polynomial_mutation(x, jax.random.PRNGKey(12), 10.0, 0.0, 0.0, 1.0)
    for name in x:
        np.testing.assert_array_equal(same[name], x[name])
    steps = {}
    for eta in (1.0, 100.0):
        child = polynomial_mutation(x, jax.random.PRNGKey(13), eta, 1.0, 0.0, 1.0)
        assert child["b"].shape == (32, 2, 3)
        steps[eta] = float(jnp.mean(jnp.abs(child["a"] - x["a"])))
    assert steps[100.0] < steps[1.0] / 5


def test_polynomial_crossover_takes_exactly_the_proportion_from_the_second_parent() -> None:
    x1 = {"a": jnp.zeros((20, 8)), "b": jnp.zeros((20, 2, 5))}
    x2 = {"a": jnp.ones((20, 8)), "b": jnp.ones((20, 2, 5))}
    child = jax.jit(lambda a, b, k: polynomial_crossover(a, b, k, 0.5))(
        x1, x2, jax.random.PRNGKey(14)
    )
    np.testing.assert_array_equal(np.asarray(child["a"]).sum(axis=1), 4)
    np.testing.assert_array_equal(np.asarray(child["b"]).reshape(20, -1).sum(axis=1), 5)
    assert len({tuple(row) for row in np.asarray(child["a"])}) > 1  # positions differ
    none = polynomial_crossover(x1, x2, jax.random.PRNGKey(14), 0.0)
    np.testing.assert_array_equal(none["a"], 0.0)


# --- the GA emitter ----------------------------------------------------------------


def marked_emitter(batch_size: int, variation_percentage: float) -> GAEmitter:
    return GAEmitter(
        batch_size,
        variation_fn=lambda a, b, k: jnp.ones_like(a),
        mutation_fn=lambda a, k: jnp.full_like(a, 2.0),
        variation_percentage=variation_percentage,
    )


@pytest.mark.parametrize(
    ("batch_size", "percentage", "num_variation"),
    [(10, 0.3, 3), (100, 0.29, 29), (7, 0.5, 3), (8, 0.0, 0), (8, 1.0, 8), (3, 0.99, 2)],
)
def test_variation_share_is_exact(batch_size: int, percentage: float, num_variation: int) -> None:
    emitter = marked_emitter(batch_size, percentage)
    assert (emitter.num_variation, emitter.num_mutation) == (
        num_variation,
        batch_size - num_variation,
    )


@pytest.mark.parametrize(("batch_size", "percentage"), [(10, 0.3), (4, 0.0), (4, 1.0)])
def test_variations_come_first_then_mutations(batch_size: int, percentage: float) -> None:
    emitter = marked_emitter(batch_size, percentage)
    repertoire = make_repertoire(jnp.zeros((4, 2)), np.array([True, True, False, True]))
    offspring = np.asarray(jax.jit(emitter.emit)(None, repertoire, jax.random.PRNGKey(0)))
    assert offspring.shape == (batch_size, 2)
    np.testing.assert_array_equal(offspring[: emitter.num_variation], 1.0)
    np.testing.assert_array_equal(offspring[emitter.num_variation :], 2.0)


def test_zero_sigma_offspring_equal_a_single_member() -> None:
    member = {"w": jnp.arange(6.0).reshape(1, 2, 3), "b": jnp.array([[7.0, 8.0]])}
    genotypes = jax.tree.map(lambda x: jnp.concatenate([x, jnp.full_like(x, 99.0)]), member)
    repertoire = make_repertoire(genotypes, np.array([True, False]))
    emitter = GAEmitter(
        6,
        variation_fn=lambda a, b, k: isoline_variation(a, b, k, 0.0, 0.0),
        mutation_fn=lambda a, k: polynomial_mutation(a, k, 20.0, 0.0, 0.0, 100.0),
        variation_percentage=0.5,
    )
    offspring = jax.jit(emitter.emit)(None, repertoire, jax.random.PRNGKey(1))
    for name in member:
        assert offspring[name].shape == (6, *member[name].shape[1:])
        np.testing.assert_array_equal(offspring[name], jnp.repeat(member[name], 6, axis=0))


def test_offspring_are_variations_of_filled_cells_only() -> None:
    genotypes = jnp.array([[0.1, 0.1], [0.9, 0.9], [0.5, 0.5], [-50.0, -50.0]])
    repertoire = make_repertoire(genotypes, np.array([True, True, True, False]))
    emitter = polynomial_emitter(
        64,
        eta=20.0,
        proportion_to_mutate=0.5,
        minval=-100.0,
        maxval=100.0,
        variation_percentage=0.5,
    )
    offspring = np.asarray(jax.jit(emitter.emit)(None, repertoire, jax.random.PRNGKey(2)))
    assert offspring.shape == (64, 2)
    # crossover of filled members keeps every gene in {0.1, 0.5, 0.9}
    members = np.float32([0.1, 0.5, 0.9])
    np.testing.assert_array_equal(np.isin(offspring[:32], members), True)
    # mutations move one gene of a filled member, never from the empty cell's -50
    assert np.all(np.abs(offspring[32:]) < 40.0)
    assert np.all(np.sum(np.isin(offspring[32:], members), axis=1) >= 1)


def test_isoline_emitter_builder_and_stateless_protocol() -> None:
    emitter = isoline_emitter(16, iso_sigma=0.05, line_sigma=0.1, minval=0.0, maxval=1.0)
    assert emitter.num_variation == 16
    genotypes = jax.random.uniform(jax.random.PRNGKey(3), (10, 4))
    repertoire = make_repertoire(genotypes, np.ones(10, bool))
    state = emitter.init(jax.random.PRNGKey(0), repertoire, None, genotypes)  # type: ignore[arg-type]
    assert state is None
    emit = jax.jit(emitter.emit)
    offspring = emit(state, repertoire, jax.random.PRNGKey(4))
    assert offspring.shape == (16, 4)
    assert float(offspring.min()) >= 0.0 and float(offspring.max()) <= 1.0
    np.testing.assert_array_equal(offspring, emit(state, repertoire, jax.random.PRNGKey(4)))
    assert not np.allclose(offspring, emit(state, repertoire, jax.random.PRNGKey(5)))
    assert emitter.update(state, repertoire, offspring, None, None, jax.random.PRNGKey(5)) is None  # type: ignore[arg-type]


def test_isoline_emitter_mutation_share_is_gaussian() -> None:
    emitter = isoline_emitter(200, iso_sigma=0.1, line_sigma=0.5, variation_percentage=0.25)
    assert (emitter.num_variation, emitter.num_mutation) == (50, 150)
    member = jnp.array([[0.3, -0.2, 0.0]])
    repertoire = make_repertoire(member, np.ones(1, bool))
    offspring = np.asarray(jax.jit(emitter.emit)(None, repertoire, jax.random.PRNGKey(6)))
    noise = offspring[50:] - np.asarray(member)
    assert noise.std() == pytest.approx(0.1, rel=0.1)
    np.testing.assert_allclose(noise.mean(axis=0), 0.0, atol=0.03)
    clipped = gaussian_mutation(jnp.zeros((64, 2)), jax.random.PRNGKey(7), 5.0, -1.0, 1.0)
    assert float(jnp.abs(clipped).max()) == 1.0


def test_invalid_configurations_are_reported() -> None:
    with pytest.raises(ValueError, match="variation_fn is None"):
        GAEmitter(4, None, lambda a, k: a, variation_percentage=0.5)
    with pytest.raises(ValueError, match="mutation_fn is None"):
        GAEmitter(4, lambda a, b, k: a, None, variation_percentage=0.5)
    with pytest.raises(ValueError, match="variation_percentage"):
        GAEmitter(4, lambda a, b, k: a, lambda a, k: a, variation_percentage=1.5)
    with pytest.raises(ValueError, match="proportion_to_mutate"):
        polynomial_mutation(jnp.zeros((1, 2)), jax.random.PRNGKey(0), 1.0, 2.0, 0.0, 1.0)
