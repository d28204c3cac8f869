"""Tests for qdrl.tasks.deceptive (QD-suite): spiral geometry, deceptive peaks, SSF staircase."""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.tasks import Task, archimedean_spiral, deceptive_evolvability, ssf
from qdrl.tasks.deceptive import spiral_arc_length, ssf_radii

SPIRALS = {
    (p, d): archimedean_spiral(parameterization=p, descriptor=d)
    for p, d in itertools.product(("angle", "arc_length"), ("euclidean", "geodesic"))
}


def evaluate(task: Task, genotypes) -> tuple[np.ndarray, np.ndarray]:
    evaluation = jax.jit(task.scoring_fn)(
        jnp.asarray(genotypes, jnp.float32), jax.random.PRNGKey(0)
    )
    assert evaluation.extras == {} and int(evaluation.env_steps) == 0
    return np.asarray(evaluation.fitnesses), np.asarray(evaluation.descriptors)


def assert_in_bounds(task: Task, descriptors: np.ndarray, tol: float = 1e-5) -> None:
    low, high = np.asarray(task.descriptor_low), np.asarray(task.descriptor_high)
    span = np.maximum(high - low, 1e-12)
    assert np.all(descriptors >= low - tol * span)
    assert np.all(descriptors <= high + tol * span)


def bound_and_random_genotypes(task: Task, n: int = 128) -> np.ndarray:
    random = jax.random.uniform(
        jax.random.PRNGKey(1),
        (n, task.genotype_size),
        minval=task.genotype_low,
        maxval=task.genotype_high,
    )
    corners = np.array(list(itertools.product((0, 1), repeat=task.genotype_size)), np.float32)
    corners = task.genotype_low + corners * (task.genotype_high - task.genotype_low)
    return np.concatenate([np.asarray(random), corners])


@pytest.mark.parametrize("key", list(SPIRALS), ids=lambda k: "-".join(k))
def test_spiral_shapes_bounds_and_constant_fitness(key: tuple[str, str]) -> None:
    task = SPIRALS[key]
    d = 2 if key[1] == "euclidean" else 1
    assert task.descriptor_size == d and task.genotype_size == 1
    genotypes = bound_and_random_genotypes(task)
    beyond = np.array([[task.genotype_low - 5.0], [task.genotype_high + 5.0]])
    fitnesses, descriptors = evaluate(task, np.concatenate([genotypes, beyond]))
    assert descriptors.shape == (genotypes.shape[0] + 2, d)
    np.testing.assert_array_equal(fitnesses, 1.0)
    assert (task.qd_offset, task.max_fitness) == (0.0, 1.0)
    assert_in_bounds(task, descriptors)
    # genotypes beyond the bounds are clipped
    np.testing.assert_allclose(descriptors[-2:], evaluate(task, genotypes[-2:])[1], rtol=1e-5)


def test_spiral_geometry() -> None:
    a, alpha = 0.01, 40.0
    angles = np.array([0.0, 2 * np.pi, 2.5 * np.pi, 10.0, alpha * np.pi], np.float32)
    _, points = evaluate(SPIRALS["angle", "euclidean"], angles[:, None])
    expected = a * angles[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    np.testing.assert_allclose(points, expected, atol=1e-5)
    _, arcs = evaluate(SPIRALS["angle", "geodesic"], angles[:, None])
    exact = a / 2 * (angles * np.sqrt(1 + angles**2) + np.arcsinh(angles))
    np.testing.assert_allclose(arcs[:, 0], exact, rtol=1e-5)
    # arc length of the whole spiral, against numerical integration of |gamma'| = a sqrt(1 + t^2)
    t = np.linspace(0.0, alpha * np.pi, 200_001)
    integral = np.trapezoid(a * np.sqrt(1 + t**2), t)
    assert SPIRALS["angle", "geodesic"].descriptor_high[0] == pytest.approx(integral, rel=1e-6)
    # same points whichever the genotype: the arc-length genotype is inverted by bisection
    _, from_arcs = evaluate(SPIRALS["arc_length", "euclidean"], exact[:, None])
    np.testing.assert_allclose(from_arcs, expected, atol=2e-5)
    _, identity = evaluate(SPIRALS["arc_length", "geodesic"], exact[:, None])
    np.testing.assert_allclose(identity[:, 0], exact, rtol=1e-6)


def test_spiral_initial_point_and_arc_length_speed() -> None:
    task = SPIRALS["angle", "euclidean"]
    start = np.asarray(task.init_genotypes(jax.random.PRNGKey(0), 4))
    np.testing.assert_allclose(start, 22 * np.pi, rtol=1e-6)  # 2 pi (1 + floor(20 pi / 2 pi))
    arc_task = SPIRALS["arc_length", "euclidean"]
    arc_start = np.asarray(arc_task.init_genotypes(jax.random.PRNGKey(0), 4))
    np.testing.assert_allclose(arc_start, float(spiral_arc_length(22 * np.pi, 0.01)), rtol=1e-6)
    np.testing.assert_allclose(
        evaluate(arc_task, arc_start)[1], evaluate(task, start)[1], atol=1e-5
    )

    # parameterised by arc length the spiral moves at unit speed: |d gamma / d s| = 1
    def point(s: jax.Array) -> jax.Array:
        return arc_task.scoring_fn(s[None, None], jax.random.PRNGKey(0)).descriptors[0]

    speeds = jax.jit(jax.vmap(lambda s: jnp.linalg.norm(jax.jacfwd(point)(s))))(
        jnp.array([0.5, 3.0, 20.0, 70.0])
    )
    np.testing.assert_allclose(np.asarray(speeds), 1.0, rtol=1e-3)
    rev = jax.jit(jax.jacrev(point))(jnp.float32(3.0))
    np.testing.assert_allclose(float(jnp.linalg.norm(rev)), 1.0, rtol=1e-3)


@pytest.mark.parametrize("key", [("angle", "euclidean"), ("angle", "geodesic")], ids="-".join)
def test_spiral_gradients_match_finite_differences(key: tuple[str, str]) -> None:
    task = SPIRALS[key]
    x = jnp.array([7.3], jnp.float32)

    def descriptors(g: jax.Array) -> jax.Array:
        return task.scoring_fn(g[None], jax.random.PRNGKey(0)).descriptors[0]

    jac = np.asarray(jax.jit(jax.jacrev(descriptors))(x))[:, 0]
    eps = 1e-2
    _, d = evaluate(task, np.array([[7.3 + eps], [7.3 - eps]]))
    np.testing.assert_allclose((d[0] - d[1]) / (2 * eps), jac, rtol=2e-3, atol=1e-4)


def test_deceptive_evolvability_bounds_values_and_start() -> None:
    task = deceptive_evolvability()
    assert task.genotype_size == 2 and task.descriptor_size == 1
    sigma_1, sigma_2 = math.sqrt(70.0), math.sqrt(1e3)
    assert task.genotype_low == pytest.approx(50.0 - 3 * sigma_1)
    assert task.genotype_high == pytest.approx(150.0 + 3 * sigma_2)
    peak_2 = 20.0 / (2 * np.pi * 1e3)  # the wide peak dominates; the narrow one adds ~e^-71
    assert task.descriptor_high[0] == pytest.approx(peak_2, rel=1e-6)

    mus = np.array([[50.0, 125.0], [150.0, 125.0]])
    _, at_mus = evaluate(task, mus)
    expected_1 = 1 / (2 * np.pi * 70) + 20 * np.exp(-0.5 * 100.0**2 / 1e3) / (2 * np.pi * 1e3)
    np.testing.assert_allclose(at_mus[:, 0], [expected_1, peak_2], rtol=1e-5)

    fitnesses, descriptors = evaluate(task, bound_and_random_genotypes(task, 512))
    np.testing.assert_array_equal(fitnesses, 1.0)
    assert_in_bounds(task, descriptors)

    start = np.asarray(task.init_genotypes(jax.random.PRNGKey(0), 3))
    assert np.all(start == start[0])
    assert start[0, 1] == pytest.approx(125.0) and 50.0 < start[0, 0] < 150.0
    _, d_start = evaluate(task, start[:1])
    segment = np.stack([np.linspace(50, 150, 101), np.full(101, 125.0)], axis=1)
    _, d_segment = evaluate(task, segment)
    assert d_start[0, 0] <= d_segment.min() * (1 + 1e-4)  # the saddle: lowest on the segment
    assert d_start[0, 0] < min(at_mus[:, 0])


def test_deceptive_evolvability_gradient() -> None:
    task = deceptive_evolvability()
    x = jnp.array([80.0, 130.0])

    def descriptor(g: jax.Array) -> jax.Array:
        return task.scoring_fn(g[None], jax.random.PRNGKey(0)).descriptors[0, 0]

    grad = np.asarray(jax.jit(jax.grad(descriptor))(x))
    eps = 0.05
    _, d = evaluate(
        task, np.array([[80 + eps, 130], [80 - eps, 130], [80, 130 + eps], [80, 130 - eps]])
    )
    numeric = np.array([d[0, 0] - d[1, 0], d[2, 0] - d[3, 0]]) / (2 * eps)
    np.testing.assert_allclose(numeric, grad, rtol=2e-2)


def test_ssf_staircase() -> None:
    np.testing.assert_array_equal(ssf_radii(100.0)[:4], [[1, 2], [5, 8], [25, 42], [97, 152]])
    task = ssf(num_dims=2)
    norms = np.array([0.0, 0.5, 1.5, 2.0, 3.0, 6.0, 8.0, 10.0, 30.0, 50.0, 120.0])
    expected = np.array([0.0, 0.5, 1.0, 1.0, 3.0, 5.0, 5.0, 10.0, 25.0, 50.0, 97.0])
    direction = np.array([0.6, -0.8])
    fitnesses, descriptors = evaluate(task, norms[:, None] * direction)
    np.testing.assert_allclose(descriptors[:, 0], expected, rtol=1e-5)
    np.testing.assert_array_equal(fitnesses, 1.0)
    np.testing.assert_array_equal(task.init_genotypes(jax.random.PRNGKey(0), 2), 0.0)
    _, bounded = evaluate(task, bound_and_random_genotypes(task))
    assert_in_bounds(task, bounded)
    assert task.descriptor_high == (1000.0,)

    def descriptor(g: jax.Array) -> jax.Array:
        return task.scoring_fn(g[None], jax.random.PRNGKey(0)).descriptors[0, 0]

    grads = jax.jit(jax.vmap(jax.grad(descriptor)))(jnp.array([[0.0, 0.0], [3.0, 4.0], [0.3, 0.4]]))
    grads = np.asarray(grads)
    assert np.all(np.isfinite(grads))
    np.testing.assert_allclose(grads[1], 0.0)  # norm 5: on a flat step
    np.testing.assert_allclose(grads[2], [0.6, 0.8], rtol=1e-5)  # norm 0.5: descriptor = |x|
