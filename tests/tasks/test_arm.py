"""Tests for qdrl.tasks.arm: forward kinematics by hand, bounds, noise statistics, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.tasks import arm, noisy_arm

DOFS = 8


def evaluate(task, genotypes, seed: int = 0):
    key = jax.random.PRNGKey(seed)
    evaluation = jax.jit(task.scoring_fn)(jnp.asarray(genotypes, jnp.float32), key)
    return np.asarray(evaluation.fitnesses), np.asarray(evaluation.descriptors)


def test_shapes_and_types() -> None:
    task = arm(DOFS)
    genotypes = task.init_genotypes(jax.random.PRNGKey(1), 5)
    evaluation = jax.jit(task.scoring_fn)(genotypes, jax.random.PRNGKey(2))
    assert genotypes.shape == (5, DOFS)
    assert evaluation.fitnesses.shape == (5,) and evaluation.fitnesses.dtype == jnp.float32
    assert evaluation.descriptors.shape == (5, 2)
    assert evaluation.extras == {} and int(evaluation.env_steps) == 0
    assert (task.descriptor_low, task.descriptor_high) == ((0.0, 0.0), (1.0, 1.0))


def test_hand_examples() -> None:
    genotypes = np.zeros((4, 2))
    genotypes[0] = (0.5, 0.5)  # all angles 0: stretched along +x, no variance
    genotypes[1] = (0.5, 0.75)  # angles (0, pi/2): end at (1/2, 1/2) in [-1, 1]^2
    genotypes[2] = (0.0, 0.0)  # angles (-pi, -pi): folded back on itself, at the origin
    genotypes[3] = (0.0, 1.0)  # the largest spread: std 0.5
    fitnesses, descriptors = evaluate(arm(2), genotypes)
    np.testing.assert_allclose(fitnesses, [0.0, -0.125, 0.0, -0.5], atol=1e-6)
    np.testing.assert_allclose(
        descriptors, [[1.0, 0.5], [0.75, 0.75], [0.5, 0.5], [0.5, 0.5]], atol=1e-6
    )


def test_straight_arm_is_the_best_and_reaches_the_right_edge() -> None:
    task = arm(DOFS)
    genotypes = np.concatenate(
        [np.full((1, DOFS), 0.5), np.asarray(task.init_genotypes(jax.random.PRNGKey(3), 99))]
    )
    fitnesses, descriptors = evaluate(task, genotypes)
    assert fitnesses[0] == pytest.approx(0.0, abs=1e-6) and task.max_fitness == 0.0
    assert np.all(fitnesses[1:] < 0.0)
    np.testing.assert_allclose(descriptors[0], [1.0, 0.5], atol=1e-6)


def test_bounds_for_random_and_extreme_genotypes() -> None:
    task = arm(DOFS)
    rng = np.random.default_rng(0)
    extremes = rng.integers(0, 2, size=(128, DOFS)).astype(np.float32)
    outside = rng.normal(0.5, 3.0, size=(128, DOFS))  # clipped to [0, 1]
    random = np.asarray(task.init_genotypes(jax.random.PRNGKey(4), 128))
    for genotypes in (random, extremes, outside):
        fitnesses, descriptors = evaluate(task, genotypes)
        assert np.all((descriptors >= 0.0) & (descriptors <= 1.0))
        assert np.all((fitnesses >= task.qd_offset) & (fitnesses <= 0.0))
    np.testing.assert_allclose(
        evaluate(task, outside)[1], evaluate(task, np.clip(outside, 0, 1))[1]
    )


def test_gradients_match_finite_differences() -> None:
    task = arm(DOFS)
    x = 0.2 + 0.6 * task.init_genotypes(jax.random.PRNGKey(5), 1)[0]
    key = jax.random.PRNGKey(0)

    def outputs(g):
        evaluation = task.scoring_fn(g[None], key)
        return jnp.concatenate([evaluation.fitnesses, evaluation.descriptors[0]])

    jac = np.asarray(jax.jit(jax.jacrev(outputs))(x))
    assert np.all(np.isfinite(jac))
    eps = 1e-3
    steps = eps * np.eye(DOFS)
    f, d = evaluate(task, np.concatenate([x + steps, x - steps]))
    out = np.concatenate([f[:, None], d], axis=1)
    numeric = (out[:DOFS] - out[DOFS:]) / (2 * eps)  # (gene, output)
    np.testing.assert_allclose(numeric.T, jac, atol=5e-3)
    # all genes equal: std is 0, its gradient is taken as 0 rather than NaN
    grad_flat = jax.jit(jax.jacrev(outputs))(jnp.full(DOFS, 0.5))
    assert np.all(np.isfinite(np.asarray(grad_flat)))


def test_noisy_arm_noise_has_the_requested_std() -> None:
    fit_std, desc_std = 0.1, 0.05
    noiseless = arm(DOFS)
    noisy = noisy_arm(DOFS, fit_std=fit_std, desc_std=desc_std, params_std=0.0)
    genotype = np.asarray(noiseless.init_genotypes(jax.random.PRNGKey(6), 1))
    copies = np.repeat(genotype, 4000, axis=0)
    f0, d0 = evaluate(noiseless, genotype)
    f, d = evaluate(noisy, copies, seed=7)
    fit_noise, desc_noise = f - f0[0], d - d0[0]
    assert abs(fit_noise.mean()) < 4 * fit_std / np.sqrt(4000)
    assert fit_noise.std() == pytest.approx(fit_std, rel=0.05)
    np.testing.assert_allclose(desc_noise.mean(axis=0), 0.0, atol=4 * desc_std / np.sqrt(4000))
    np.testing.assert_allclose(desc_noise.std(axis=0), desc_std, rtol=0.05)
    assert abs(np.corrcoef(desc_noise[:, 0], desc_noise[:, 1])[0, 1]) < 0.1


def test_noisy_arm_uses_the_key_and_params_noise() -> None:
    task = noisy_arm(DOFS)  # QDax defaults: fit 0.1, desc 0.1, params 0.05
    assert task.qd_offset == pytest.approx(-0.5 - 5 * 0.1)
    genotypes = np.asarray(task.init_genotypes(jax.random.PRNGKey(8), 16))
    a = evaluate(task, genotypes, seed=1)
    b = evaluate(task, genotypes, seed=1)
    c = evaluate(task, genotypes, seed=2)
    np.testing.assert_array_equal(a[0], b[0])
    assert not np.allclose(a[0], c[0]) and not np.allclose(a[1], c[1])
    # with only parameter noise, the fitness moves too (it is computed after the noise)
    params_only = noisy_arm(DOFS, fit_std=0.0, desc_std=0.0, params_std=0.05)
    f, _ = evaluate(params_only, genotypes)
    assert not np.allclose(f, evaluate(arm(DOFS), genotypes)[0])
