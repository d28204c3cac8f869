"""LP benchmarks (CMA-ME / DQD / CMA-MAE): values at known points, and gradients against finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.dqd import DESCRIPTOR_GRADIENTS, FITNESS_GRADIENT
from qdrl.tasks import make_task


def test_lp_sphere_definition() -> None:
    task = make_task("lp_sphere", num_dims=4)
    x = jnp.array([[2.048] * 4, [-5.12] * 4, [0.0, 1.0, 6.0, -10.24]])
    ev = task.scoring_fn(x, jax.random.PRNGKey(0))
    f = np.asarray(ev.fitnesses)
    assert f[0] == pytest.approx(100.0) and f[1] == pytest.approx(0.0, abs=1e-4)
    raw = np.sum((np.asarray(x[2]) - 2.048) ** 2)
    assert f[2] == pytest.approx(100.0 * (1.0 - raw / (4 * 7.168**2)), rel=1e-5)
    # halves: (0 + 1), (5.12 / 6 + 5.12 / -10.24)
    np.testing.assert_allclose(np.asarray(ev.descriptors[2]), [1.0, 5.12 / 6 - 0.5], rtol=1e-5)
    assert task.descriptor_low == (-10.24, -10.24) and task.descriptor_high == (10.24, 10.24)
    assert task.qd_offset == 0.0 and task.max_fitness == 100.0 and ev.extras == {}


def test_lp_rastrigin_and_plateau_definitions() -> None:
    ras = make_task("lp_rastrigin", num_dims=6)
    f = np.asarray(ras.scoring_fn(jnp.array([[2.048] * 6, [-5.12] * 6]), None).fitnesses)
    assert f[0] == pytest.approx(100.0) and f[1] == pytest.approx(0.0, abs=1e-4)
    plat = make_task("lp_plateau", num_dims=4)
    f = np.asarray(plat.scoring_fn(jnp.array([[5.0, -5.0, 0.0, 1.0], [7.12, 0.0, 0.0, -6.12]]), None).fitnesses)
    # flat inside the box; outside, 100 - mean of the squared excess: (4 + 1) / 4
    assert f[0] == 100.0 and f[1] == pytest.approx(100.0 - 5.0 / 4)
    with pytest.raises(ValueError, match="num_dims must be an integer >= 2"):
        make_task("lp_sphere", num_dims=1)


@pytest.mark.parametrize("name", ["lp_sphere", "lp_rastrigin", "lp_plateau", "arm"])
def test_gradients_match_finite_differences(name: str) -> None:
    n = 6
    kw = {"num_dofs": n} if name == "arm" else {"num_dims": n}
    task = make_task(name, **kw)
    assert task.gradient_scoring_fn is not None
    key = jax.random.PRNGKey(1)
    if name == "arm":
        x = jax.random.uniform(key, (3, n), minval=0.1, maxval=0.9)
    else:  # genes inside and outside the box, none at its edge
        x = jnp.array([[0.3, -1.2, 6.5, 2.0, -7.0, 4.1]] * 3) + 0.1 * jax.random.normal(key, (3, n))
    ev = task.gradient_scoring_fn(x, key)
    np.testing.assert_array_equal(np.asarray(ev.fitnesses), np.asarray(task.scoring_fn(x, key).fitnesses))
    grad = np.asarray(ev.extras[FITNESS_GRADIENT])
    jac = np.asarray(ev.extras[DESCRIPTOR_GRADIENTS])
    assert grad.shape == (3, n) and jac.shape == (3, 2, n)
    eps = 1e-2
    x64 = np.asarray(x, np.float64)
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        up = task.scoring_fn(jnp.asarray(x64 + e, jnp.float32), key)
        down = task.scoring_fn(jnp.asarray(x64 - e, jnp.float32), key)
        fd = (np.asarray(up.fitnesses, np.float64) - np.asarray(down.fitnesses, np.float64)) / (2 * eps)
        fd_desc = (np.asarray(up.descriptors, np.float64) - np.asarray(down.descriptors, np.float64)) / (2 * eps)
        np.testing.assert_allclose(grad[:, i], fd, rtol=2e-2, atol=2e-2 * max(1.0, np.abs(fd).max()))
        np.testing.assert_allclose(jac[:, :, i], fd_desc, rtol=2e-2, atol=2e-3)
