"""Multi-objective tasks: values at known points, true fronts and their hypervolumes, brax objectives."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.pareto import hypervolume_exact
from qdrl.tasks import TASKS
from qdrl.tasks.mo import MO_TASKS, TRUE_HYPERVOLUME, true_front


def _rastrigin(x: np.ndarray) -> float:
    return float(10 * len(x) + np.sum(x**2 - 10 * np.cos(2 * np.pi * x)))


def test_function_tasks_at_known_points() -> None:
    x = np.zeros((3, 30), np.float32)
    x[:, 0] = [0.0, 0.25, 1.0]
    x[2, 1:] = 1.0  # g = 10
    for name, f2 in (("zdt1", [1, 0.5, 10 * (1 - math.sqrt(0.1))]), ("zdt2", [1, 1 - 0.0625, 10 * (1 - 0.01)])):
        e = TASKS[name]().scoring_fn(jnp.asarray(x), jax.random.PRNGKey(0))
        np.testing.assert_allclose(np.asarray(e.fitnesses), -np.stack([x[:, 0], f2], 1), rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(np.asarray(e.descriptors), x[:, :2])
    z3 = TASKS["zdt3"]().scoring_fn(jnp.asarray(x[:2]), None).fitnesses
    np.testing.assert_allclose(np.asarray(z3)[1], [-0.25, -(1 - 0.5 - 0.25 * math.sin(2.5 * math.pi))], rtol=1e-5)
    d = np.full((2, 12), 0.5, np.float32)
    d[:, :2] = [[0.5, 0.0], [0.0, 1.0]]  # g = 0: on the sphere
    f = -np.asarray(TASKS["dtlz2"]().scoring_fn(jnp.asarray(d), None).fitnesses)
    np.testing.assert_allclose(f[0], [math.sqrt(0.5), 0, math.sqrt(0.5)], atol=1e-6)
    np.testing.assert_allclose(np.sum(f**2, axis=1), 1.0, rtol=1e-5)
    # An angle at its upper bound zeroes the objectives it multiplies by its cosine,
    # exactly: float32's cos(pi/2) = -4.4e-8 would put such points beyond the true front
    # (objectives below 0 that nothing dominates), where they would hold population slots.
    edge = np.full((3, 12), 0.7, np.float32)
    edge[:, :2] = [[1.0, 0.3], [0.4, 1.0], [1.0, 1.0]]
    fe = -np.asarray(TASKS["dtlz2"]().scoring_fn(jnp.asarray(edge), None).fitnesses)
    assert np.all(fe >= 0.0)
    assert fe[0, 0] == 0.0 and fe[0, 1] == 0.0 and fe[1, 0] == 0.0 and fe[2, 0] == fe[2, 1] == 0.0
    g = np.linspace(-2, 4, 100 * 4).reshape(4, 100).astype(np.float32)
    r = np.asarray(TASKS["mo_rastrigin"]().scoring_fn(jnp.asarray(g), None).fitnesses)
    expected = [[-_rastrigin(row), -_rastrigin(row - 2.2)] for row in g.astype(np.float64)]
    np.testing.assert_allclose(r, expected, rtol=1e-4)


@pytest.mark.parametrize("name", sorted(TRUE_HYPERVOLUME))
def test_true_fronts_reach_the_known_hypervolumes(name: str) -> None:
    front = true_front(name, 40_000 if name == "dtlz2" else 4000)
    hv = hypervolume_exact(front, [-1.0] * front.shape[1])
    assert hv == pytest.approx(TRUE_HYPERVOLUME[name], rel=2e-2 if name == "dtlz2" else 2e-3)
    assert hv < TRUE_HYPERVOLUME[name]  # a finite sample of the front covers less


def test_objectives_are_known_before_building_and_reference_points_are_checked() -> None:
    assert MO_TASKS["dtlz2"].num_objectives({"name": "dtlz2", "num_objectives": 4}) == 4
    assert MO_TASKS["halfcheetah_multi"].num_objectives({"name": "halfcheetah_multi"}) == 2
    assert TASKS["arm"].num_objectives({"name": "arm"}) == 1
    assert TASKS["halfcheetah_multi"].policy and TASKS["point_maze"].policy and not TASKS["zdt1"].policy
    assert TASKS["dtlz2"](num_dims=7, num_objectives=4).num_objectives == 4
    with pytest.raises(ValueError, match=r"task.reference_point: expected 2 numbers"):
        TASKS["zdt1"](reference_point=(1.0,))
    with pytest.raises(ValueError, match=r"task\.num_dims: expected at least task\.num_objectives=5"):
        TASKS["dtlz2"](num_dims=4, num_objectives=5)


def test_halfcheetah_multi_objectives_sum_to_the_return_of_the_same_rollout() -> None:
    """Forward reward + energy (control reward) is halfcheetah's reward; one rollout gives both."""
    multi = TASKS["halfcheetah_multi"](episode_length=20, eval_batch=4)
    assert multi.policy_scoring is not None
    scoring = multi.policy_scoring(None, fixed_start=True, record=lambda state: state.reward)
    genotypes = multi.init_genotypes(jax.random.PRNGKey(0), 4)
    e = jax.jit(scoring)(genotypes, jax.random.PRNGKey(1))
    f = np.asarray(e.fitnesses)
    assert f.shape == (4, 2) and multi.num_objectives == 2
    returns = np.sum(np.asarray(e.extras["recorded"]) * np.asarray(e.extras["mask"]), axis=0)
    np.testing.assert_allclose(f.sum(axis=1), returns, rtol=1e-4, atol=1e-3)
    assert np.all(f[:, 1] <= 0) and np.all(f[:, 1] >= -0.1 * 6 * 20)  # -0.1 |a|^2 per step, |a| <= 1
    assert multi.reference_point == pytest.approx((-9.231 * 20, -0.6 * 20))
