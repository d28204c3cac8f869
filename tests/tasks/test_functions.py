"""Tests for qdrl.tasks.functions and the task registry: shapes, bounds, hand values, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.tasks import TASKS, Task, make_task, rastrigin, rastrigin_proj, sphere, sphere_proj

DIMS = 6
UNIT_TASKS = [sphere(DIMS), rastrigin(DIMS)]
PROJ_TASKS = [sphere_proj(DIMS), rastrigin_proj(DIMS)]
ALL_TASKS = UNIT_TASKS + PROJ_TASKS


def evaluate(task: Task, genotypes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    evaluation = jax.jit(task.scoring_fn)(
        jnp.asarray(genotypes, jnp.float32), jax.random.PRNGKey(0)
    )
    return np.asarray(evaluation.fitnesses), np.asarray(evaluation.descriptors)


def extreme_genotypes(task: Task, rng: np.random.Generator, n: int = 64) -> np.ndarray:
    """Every gene at one of the two search bounds."""
    corners = rng.integers(0, 2, size=(n, task.genotype_size))
    return np.where(corners == 1, task.genotype_high, task.genotype_low)


def assert_gradients_match_finite_differences(task: Task, x: jax.Array, eps: float = 1e-3) -> None:
    """The Jacobian of (fitness, descriptors) at x matches central differences along each gene."""
    key = jax.random.PRNGKey(0)

    def outputs(g: jax.Array) -> jax.Array:
        evaluation = task.scoring_fn(g[None], key)
        return jnp.concatenate([evaluation.fitnesses, evaluation.descriptors[0]])

    jac = np.asarray(jax.jit(jax.jacrev(outputs))(x))
    assert np.all(np.isfinite(jac))
    d = x.shape[0]
    steps = eps * np.eye(d)
    fitnesses, descriptors = evaluate(task, np.concatenate([x + steps, x - steps]))
    out = np.concatenate([fitnesses[:, None], descriptors], axis=1)
    numeric = ((out[:d] - out[d:]) / (2 * eps)).T
    scale = max(1.0, float(np.max(np.abs(jac))))
    np.testing.assert_allclose(numeric, jac, atol=1e-2 * scale)


@pytest.mark.parametrize("task", ALL_TASKS, ids=lambda t: t.name)
def test_evaluation_shapes_and_types(task: Task) -> None:
    genotypes = task.init_genotypes(jax.random.PRNGKey(1), 7)
    assert genotypes.shape == (7, DIMS)
    assert float(genotypes.min()) >= task.genotype_low
    assert float(genotypes.max()) <= task.genotype_high
    evaluation = jax.jit(task.scoring_fn)(genotypes, jax.random.PRNGKey(2))
    assert evaluation.fitnesses.shape == (7,) and evaluation.fitnesses.dtype == jnp.float32
    assert evaluation.descriptors.shape == (7, 2) and evaluation.descriptors.dtype == jnp.float32
    assert evaluation.extras == {}
    assert int(evaluation.env_steps) == 0
    assert task.descriptor_size == 2


@pytest.mark.parametrize("task", ALL_TASKS, ids=lambda t: t.name)
def test_descriptors_in_bounds_and_offset_below_fitness(task: Task) -> None:
    rng = np.random.default_rng(0)
    random = np.asarray(task.init_genotypes(jax.random.PRNGKey(3), 256))
    for genotypes in (random, extreme_genotypes(task, rng)):
        fitnesses, descriptors = evaluate(task, genotypes)
        assert np.all(descriptors >= np.asarray(task.descriptor_low) - 1e-6)
        assert np.all(descriptors <= np.asarray(task.descriptor_high) + 1e-6)
        assert np.all(fitnesses >= task.qd_offset)
        assert task.max_fitness is not None and np.all(fitnesses <= task.max_fitness + 1e-6)


@pytest.mark.parametrize("task", UNIT_TASKS, ids=lambda t: t.name)
def test_unit_cube_hand_values(task: Task) -> None:
    optimum = np.full((1, DIMS), 0.5)
    corner = np.zeros((1, DIMS))  # x = -5: sphere 25 per gene, rastrigin 10 + 25 - 10 per gene
    genotypes = np.concatenate([optimum, corner, np.full((1, DIMS), 0.7)])
    genotypes[2, :2] = (0.2, 0.9)
    fitnesses, descriptors = evaluate(task, genotypes)
    np.testing.assert_allclose(fitnesses[:2], [0.0, -25.0 * DIMS], atol=1e-4)
    assert fitnesses[0] > fitnesses[2] > fitnesses[1]
    np.testing.assert_allclose(descriptors, [[0.5, 0.5], [0.0, 0.0], [0.2, 0.9]], atol=1e-6)
    # out of the search bounds the genotype is clipped: same as the bound
    clipped = evaluate(task, np.concatenate([corner - 3.0, corner + 4.0]))
    at_bounds = evaluate(task, np.concatenate([corner, corner + 1.0]))
    np.testing.assert_allclose(clipped[0], at_bounds[0])
    np.testing.assert_allclose(clipped[1], at_bounds[1])


def test_rastrigin_value() -> None:
    g = np.random.default_rng(1).uniform(size=(5, DIMS))
    x = 10 * g - 5
    expected = -(10 * DIMS + np.sum(x**2 - 10 * np.cos(2 * np.pi * x), axis=1))
    np.testing.assert_allclose(evaluate(rastrigin(DIMS), g)[0], expected, rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize("task", PROJ_TASKS, ids=lambda t: t.name)
def test_projection_hand_values(task: Task) -> None:
    shift = 0.4 * 5.12
    genotypes = np.stack(
        [
            np.full(DIMS, shift),  # the optimum
            np.zeros(DIMS),  # the origin: inside the bounds, projection is the identity
            np.array([1.0, 2.0, 3.0, 6.0, -8.0, 10.24]),  # three genes outside the bounds
        ]
    )
    fitnesses, descriptors = evaluate(task, genotypes)
    if task.name == "sphere_proj":
        expected_origin = -DIMS * shift**2
    else:
        expected_origin = -(10 * DIMS + DIMS * (shift**2 - 10 * np.cos(2 * np.pi * shift)))
    np.testing.assert_allclose(fitnesses[:2], [0.0, expected_origin], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(descriptors[0], [shift, shift], rtol=1e-6)
    np.testing.assert_allclose(descriptors[1], [0.0, 0.0], atol=1e-7)
    # first half (1, 2, 3) -> mean 2; second half: 6 -> 5.12/6, -8 -> -0.64, 10.24 -> 0.5
    np.testing.assert_allclose(descriptors[2], [2.0, (5.12 / 6 - 0.64 + 0.5) / 3], rtol=1e-5)


def test_projection_keeps_far_genotypes_in_bounds() -> None:
    task = rastrigin_proj(DIMS)
    far = np.random.default_rng(2).normal(scale=100.0, size=(256, DIMS))
    _, descriptors = evaluate(task, far)
    assert np.all(np.abs(descriptors) <= 5.12)


def test_projection_rejects_asymmetric_bounds() -> None:
    with pytest.raises(ValueError, match="symmetric"):
        rastrigin_proj(DIMS, minval=0.0, maxval=1.0)


@pytest.mark.parametrize("task", ALL_TASKS, ids=lambda t: t.name)
def test_gradients_match_finite_differences(task: Task) -> None:
    # an interior point, away from the clip boundaries (and inside the projection's identity part)
    u = np.asarray(jax.random.uniform(jax.random.PRNGKey(4), (DIMS,), minval=0.1, maxval=0.9))
    x = jnp.asarray(task.genotype_low + u * (task.genotype_high - task.genotype_low), jnp.float32)
    assert_gradients_match_finite_differences(task, x)


def test_projection_gradient_finite_at_zero_and_outside() -> None:
    task = rastrigin_proj(DIMS)
    x = jnp.array([0.0, 1.0, -1.0, 7.0, -9.0, 0.0])
    jac = jax.jit(
        jax.jacrev(lambda g: task.scoring_fn(g[None], jax.random.PRNGKey(0)).descriptors[0])
    )(x)
    assert np.all(np.isfinite(np.asarray(jac)))
    # d/dx (5.12 / x) / 3 at x = 7 (second half, size 3)
    np.testing.assert_allclose(float(jac[1, 3]), -5.12 / 49 / 3, rtol=1e-5)


def test_wrong_genotype_shape_is_reported() -> None:
    with pytest.raises(ValueError, match=r"expected shape \(n, 6\)"):
        sphere(DIMS).scoring_fn(jnp.zeros((3, 5)), jax.random.PRNGKey(0))


def test_registry_builds_every_task() -> None:
    # Policy tasks (brax, jumanji, the maze) compile whole rollouts: their own test files cover them.
    for name, builder in TASKS.items():
        if builder.policy:
            continue
        task = builder()
        assert isinstance(task, Task)
        genotypes = task.init_genotypes(jax.random.PRNGKey(0), 3)
        evaluation = jax.jit(task.scoring_fn)(genotypes, jax.random.PRNGKey(1))
        assert evaluation.descriptors.shape == (3, task.descriptor_size), name
    assert make_task("sphere", num_dims=3).genotype_size == 3
    with pytest.raises(ValueError, match="unknown task 'nope'"):
        make_task("nope")
