"""Networks: shapes, bounds, and the tanh-Gaussian log-probability against distrax."""

from __future__ import annotations

import distrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import nets


def test_deterministic_policy_is_bounded_and_shaped() -> None:
    net = nets.deterministic_policy(3, hidden=(8, 8), act="tanh")
    obs = 100.0 * jax.random.normal(jax.random.PRNGKey(0), (5, 4))
    params = net.init(jax.random.PRNGKey(1), obs)
    a = net.apply(params, obs)
    assert a.shape == (5, 3)
    assert float(jnp.max(jnp.abs(a))) <= 1.0
    sizes = [p["w"].shape for p in params.values()]
    assert sizes == [(4, 8), (8, 8), (8, 3)]


def test_gaussian_policy_log_std_bounds() -> None:
    net = nets.gaussian_policy(2, hidden=(8,))
    obs = 1e3 * jax.random.normal(jax.random.PRNGKey(0), (64, 3))
    mean, log_std = net.apply(net.init(jax.random.PRNGKey(1), obs), obs)
    assert mean.shape == log_std.shape == (64, 2)
    assert float(log_std.min()) >= nets.LOG_STD_MIN and float(log_std.max()) <= nets.LOG_STD_MAX


def test_tanh_gaussian_log_prob_matches_distrax() -> None:
    mean = jnp.array([[0.3, -1.2], [2.0, 0.0]])
    log_std = jnp.array([[-0.5, 0.1], [0.0, -2.0]])
    action, log_prob = nets.sample_tanh_gaussian(mean, log_std, jax.random.PRNGKey(3))
    dist = distrax.Transformed(
        distrax.MultivariateNormalDiag(mean, jnp.exp(log_std)), distrax.Block(distrax.Tanh(), 1)
    )
    expected = dist.log_prob(action)
    np.testing.assert_allclose(log_prob, expected, rtol=1e-4, atol=1e-4)
    assert float(jnp.max(jnp.abs(action))) < 1.0


def test_twin_critic_heads_are_independent() -> None:
    net = nets.twin_q_critic(hidden=(8,), num_critics=2)
    obs, act = jnp.ones((3, 4)), jnp.zeros((3, 2))
    params = net.init(jax.random.PRNGKey(0), obs, act)
    q = net.apply(params, obs, act)
    assert q.shape == (3, 2)
    assert not np.allclose(q[:, 0], q[:, 1])
    assert set(params) == {"q0/~/linear_0", "q0/~/linear_1", "q1/~/linear_0", "q1/~/linear_1"}


def test_unknown_activation() -> None:
    with pytest.raises(ValueError, match="unknown activation 'sigmoidal'"):
        nets.activation("sigmoidal")
