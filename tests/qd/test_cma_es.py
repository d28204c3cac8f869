"""The one CMA-ES: weights; updates against Hansen's tutorial and pyribs' equations in NumPy;
the eigendecomposition schedule; convergence; stops."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.cma_es import CMAES, default_population_size, recombination_weights


def test_log_rank_weights_by_hand() -> None:
    w = np.asarray(recombination_weights(3, 6))
    # ln(3.5) - ln(i) = 1.25276, 0.55962, 0.15415 over their sum 1.96653
    np.testing.assert_allclose(w, [0.63704, 0.28457, 0.07839, 0.0, 0.0, 0.0], atol=2e-5)
    assert 1.0 / float(np.sum(w**2)) == pytest.approx(2.0286, abs=1e-3)  # mu_eff
    assert float(jnp.sum(recombination_weights(0, 6))) == 0.0
    assert default_population_size(100) == 17 and default_population_size(2) == 6


def _tutorial_update(mean, sigma, cov, ranked, k, generation=0):  # type: ignore[no-untyped-def]
    """Hansen 2016's equations, written out in NumPy for n = 2, from C = I (B = I, D = 1)."""
    n = 2
    raw = np.log(k + 0.5) - np.log(np.arange(1, k + 1))
    w = raw / raw.sum()
    mueff = 1.0 / np.sum(w**2)
    c_s = (mueff + 2) / (n + mueff + 5)
    d_s = 1 + 2 * max(0.0, math.sqrt((mueff - 1) / (n + 1)) - 1) + c_s
    c_c = (4 + mueff / n) / (n + 4 + 2 * mueff / n)
    c_1 = 2 / ((n + 1.3) ** 2 + mueff)
    c_mu = min(1 - c_1, 2 * (mueff - 2 + 1 / mueff) / ((n + 2) ** 2 + mueff))
    chi = math.sqrt(n) * (1 - 1 / (4 * n) + 1 / (21 * n * n))
    y = (ranked[:k] - mean) / sigma
    y_w = w @ y
    p_s = math.sqrt(c_s * (2 - c_s) * mueff) * y_w  # C^-1/2 = I at the start
    h = np.linalg.norm(p_s) / math.sqrt(1 - (1 - c_s) ** (2 * (generation + 1))) < (1.4 + 2 / (n + 1)) * chi
    p_c = h * math.sqrt(c_c * (2 - c_c) * mueff) * y_w
    delta = (1 - h) * c_c * (2 - c_c)
    rank_mu = sum(wi * np.outer(yi, yi) for wi, yi in zip(w, y, strict=True))
    new_cov = (1 + c_1 * delta - c_1 - c_mu) * cov + c_1 * np.outer(p_c, p_c) + c_mu * rank_mu
    new_sigma = sigma * math.exp(c_s / d_s * (np.linalg.norm(p_s) / chi - 1))
    return mean + sigma * y_w, new_sigma, new_cov, p_s, p_c


def test_one_update_on_a_2d_quadratic_matches_the_tutorial() -> None:
    es = CMAES(num_dims=2, population_size=6, sigma0=0.5, update_rule="tutorial")
    state = es.init(jnp.array([1.0, -1.0]))
    x = np.asarray(es.sample(state, jax.random.PRNGKey(3)))
    f = (x[:, 0] - 0.3) ** 2 + 10.0 * (x[:, 1] + 0.2) ** 2  # minimised: rank ascending
    ranked = x[np.argsort(f)]
    new = es.update(state, jnp.asarray(ranked), 3, decompose=True)
    mean, sigma, cov, p_s, p_c = _tutorial_update(np.array([1.0, -1.0]), 0.5, np.eye(2), ranked, 3)
    np.testing.assert_allclose(np.asarray(new.mean), mean, rtol=1e-5)
    np.testing.assert_allclose(float(new.sigma), sigma, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(new.cov), cov, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(new.p_sigma), p_s, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(new.p_c), p_c, rtol=1e-5, atol=1e-7)
    # the forced decomposition holds C's eigenvalues; samples now follow the new C
    np.testing.assert_allclose(np.sort(np.asarray(new.eigvals)), np.linalg.eigvalsh(cov), rtol=1e-5)
    assert int(new.generation) == 1 and int(new.decomposed_at) == 1
    # the new mean moved towards the optimum (0.3, -0.2)
    assert np.linalg.norm(mean - [0.3, -0.2]) < np.linalg.norm([0.7, -0.8])
    # no parents: nothing learnt, the generation still counts
    idle = es.update(state, jnp.asarray(ranked), 0)
    np.testing.assert_array_equal(np.asarray(idle.mean), [1.0, -1.0])
    assert float(idle.sigma) == 0.5 and int(idle.generation) == 1


def test_sep_cma_es_keeps_the_diagonal_of_the_full_update() -> None:
    full = CMAES(num_dims=2, population_size=6, sigma0=0.5, update_rule="tutorial")
    sep = CMAES(num_dims=2, population_size=6, sigma0=0.5, separable=True, update_rule="tutorial")
    ranked = jnp.array([[0.1, 0.2], [0.4, -0.3], [-0.2, 0.1], [0.9, 0.9], [1.0, -1.0], [2.0, 2.0]])
    f_state = full.update(full.init(jnp.zeros(2)), ranked, 3)
    s_state = sep.update(sep.init(jnp.zeros(2)), ranked, 3)
    np.testing.assert_allclose(np.asarray(s_state.mean), np.asarray(f_state.mean), rtol=1e-6)
    # sep-CMA-ES: the same rank-one and rank-mu terms on the diagonal, rates x (n + 2) / 3
    n, w = 2.0, np.asarray(recombination_weights(3, 6))
    mueff = 1.0 / np.sum(w**2)
    c_1 = 2 / ((n + 1.3) ** 2 + mueff)
    c_mu = min(1 - c_1, 2 * (mueff - 2 + 1 / mueff) / ((n + 2) ** 2 + mueff))
    s1, smu = c_1 * 4 / 3, min(1 - c_1 * 4 / 3, c_mu * 4 / 3)
    p_c = np.asarray(s_state.p_c)
    y = np.asarray(ranked[:3]) / 0.5
    expected = (1 - s1 - smu) + s1 * p_c**2 + smu * (w[:3] @ (y * y))
    np.testing.assert_allclose(np.asarray(s_state.cov), expected, rtol=1e-5)
    assert s_state.cov.shape == (2,) and s_state.eigvecs.shape == (0,)


def _pyribs_tell(st: dict, ranked: np.ndarray, k: int, lam: int) -> None:  # type: ignore[type-arg]
    """pyribs 0.12's `CMAEvolutionStrategy.tell` and its eigendecomposition, in float64 NumPy."""
    n = ranked.shape[1]
    st["evals"] += lam
    w = np.log(k + 0.5) - np.log(np.arange(1, k + 1))
    w = w / w.sum()
    mueff = w.sum() ** 2 / np.sum(w**2)
    cc = (4 + mueff / n) / (n + 4 + 2 * mueff / n)
    cs = (mueff + 2) / (n + mueff + 5)
    c1 = 2 / ((n + 1.3) ** 2 + mueff)
    cmu = min(1 - c1, 2 * (mueff - 2 + 1 / mueff) / ((n + 2) ** 2 + mueff))
    damps = 1 + 2 * max(0, math.sqrt((mueff - 1) / (n + 1)) - 1) + cs
    parents, old = ranked[:k], st["mean"]
    st["mean"] = np.sum(parents * w[:, None], axis=0)
    y = st["mean"] - old
    st["ps"] = (1 - cs) * st["ps"] + (math.sqrt(cs * (2 - cs) * mueff) / st["sigma"]) * (st["invsqrt"] @ y)
    left = np.sum(st["ps"] ** 2) / n / (1 - (1 - cs) ** (2 * st["evals"] / lam))
    hsig = 1.0 if left < 2 + 4.0 / (n + 1) else 0.0
    st["pc"] = (1 - cc) * st["pc"] + hsig * math.sqrt(cc * (2 - cc) * mueff) * y
    ys = parents - old
    rank_mu = np.einsum("ki,kj", ys * w[:, None], ys)
    c1a = c1 * (1 - (1 - hsig**2) * cc * (2 - cc))
    st["cov"] = st["cov"] * (1 - c1a - cmu * w.sum()) + c1 * np.outer(st["pc"], st["pc"]) * c1 + rank_mu * cmu / st["sigma"] ** 2
    st["sigma"] *= math.exp(min(1, cs / damps * (np.sum(st["ps"] ** 2) / n - 1) / 2))
    vals, vecs = np.linalg.eigh(np.maximum(st["cov"], st["cov"].T))
    st["invsqrt"] = (vecs * (1 / np.sqrt(np.abs(vals)))) @ vecs.T


def test_two_generations_match_pyribs_equations() -> None:
    """The default equations are pyribs' (rank-one path in solution units, c_1^2; squared-norm step)."""
    n, lam = 4, 8
    es = CMAES(num_dims=n, population_size=lam, sigma0=0.5)
    assert es.update_rule == "pyribs"
    state = es.init(jnp.array([1.0, -1.0, 0.5, 0.0]))
    ref = {"mean": np.array([1.0, -1.0, 0.5, 0.0]), "sigma": 0.5, "cov": np.eye(n), "invsqrt": np.eye(n),
           "ps": np.zeros(n), "pc": np.zeros(n), "evals": 0}
    rng = np.random.default_rng(0)
    for gen, k in enumerate((4, 3)):
        # skewed samples so that the covariance, both paths and sigma all move
        x = ref["mean"] + 0.5 * rng.normal(size=(lam, n)) * np.array([3.0, 1.0, 0.3, 1.0]) + 0.1
        ranked = x[np.argsort(np.sum((x - 2.0) ** 2, axis=1))]
        state = es.update(state, jnp.asarray(ranked, jnp.float32), k, decompose=True)
        _pyribs_tell(ref, ranked, k, lam)
        for name, ours in (("mean", state.mean), ("cov", state.cov), ("ps", state.p_sigma), ("pc", state.p_c)):
            np.testing.assert_allclose(np.asarray(ours), ref[name], rtol=2e-4, atol=1e-6, err_msg=f"{name} {gen}")
        assert float(state.sigma) == pytest.approx(ref["sigma"], rel=1e-5)
    assert float(np.linalg.norm(ref["pc"])) > 0.01  # the rank-one path took part
    # the same samples under the tutorial's equations move sigma by another rule
    tutorial = CMAES(num_dims=n, population_size=lam, sigma0=0.5, update_rule="tutorial")
    t_state = tutorial.update(tutorial.init(jnp.zeros(n)), jnp.asarray(ranked, jnp.float32), 4)
    p_state = es.update(es.init(jnp.zeros(n)), jnp.asarray(ranked, jnp.float32), 4)
    assert abs(float(t_state.sigma) - float(p_state.sigma)) > 0.01


def test_the_eigendecomposition_gap_counts_generations_unless_told_evaluations() -> None:
    # n = 100, lambda = 36: mu_eff = 10.24, c_1 = 1.94e-4, c_mu = 1.604e-3, so
    # 0.5 * 36 / (100 (c_1 + c_mu)) = 100.16: every 101 generations (QDax's comparison);
    # pyribs counts the same 100.16 in evaluations: every floor(100.16 / 36) + 1 = 3 generations.
    assert CMAES(num_dims=100, population_size=36).eigen_period == 101
    assert CMAES(num_dims=100, population_size=36, eigen_gap="evaluations").eigen_period == 3
    assert CMAES(num_dims=100, population_size=36, eigen_gap=106).eigen_period == 106
    assert CMAES(num_dims=3, population_size=35, eigen_gap="evaluations").eigen_period == 1
    # n = 3, lambda = 35: c_1 = 0.0709, c_mu = 0.4503, 0.5 * 35 / (3 (c_1 + c_mu)) = 11.19
    assert CMAES(num_dims=3, population_size=35).eigen_period == 12
    for rule, period in (("evaluations", 3), (5, 5)):
        es = CMAES(num_dims=100, population_size=36, eigen_gap=rule)
        state = es.init(jnp.zeros(100))
        x = es.sample(state, jax.random.PRNGKey(0))
        for gen in range(1, 12):
            state = es.update(state, x, 18)
            assert int(state.decomposed_at) == period * (gen // period), (rule, gen)


def _minimise_sphere(es: CMAES, mean0: jax.Array, generations: int, key: jax.Array):  # type: ignore[no-untyped-def]
    def step(state, k):  # type: ignore[no-untyped-def]
        x = es.sample(state, k)
        f = jnp.sum(x * x, axis=-1)
        order = jnp.argsort(f)
        return es.update(state, x[order], es.lam // 2), jnp.min(f)

    return jax.lax.scan(step, es.init(mean0), jax.random.split(key, generations))


def test_cma_es_reaches_1e_3_on_the_100d_sphere() -> None:
    """QDax's CMA-ES test: min fitness below 1e-3 on the 100-D sphere (lambda = 17)."""
    es = CMAES(num_dims=100, sigma0=1.0)
    state, best = jax.jit(lambda k: _minimise_sphere(es, jnp.full((100,), 3.0), 700, k))(
        jax.random.PRNGKey(0)
    )
    best = np.asarray(best)
    assert best[0] > 500.0 and best.min() < 1e-3
    assert es.eigen_period > 1 and int(state.decomposed_at) > 0


def test_sep_cma_es_descends_in_1000_dimensions() -> None:
    es = CMAES(num_dims=1000, population_size=24, sigma0=1.0, separable=True)
    _, best = jax.jit(lambda k: _minimise_sphere(es, jnp.full((1000,), 3.0), 300, k))(
        jax.random.PRNGKey(1)
    )
    best = np.asarray(best)
    assert best[-1] < 0.2 * best[0]


def test_stop_conditions() -> None:
    es = CMAES(num_dims=3, population_size=6, sigma0=0.5)
    state = es.init(jnp.zeros(3))
    assert not bool(es.stop(state))
    assert bool(es.stop(state._replace(mean=jnp.array([0.0, jnp.nan, 0.0]))))
    assert bool(es.stop(state._replace(sigma=jnp.asarray(1e-13))))  # collapsed
    assert bool(es.stop(state._replace(sigma=jnp.asarray(1e20))))  # diverged
    assert bool(es.stop(state._replace(eigvals=jnp.array([1.0, 1.0, 1e-15]))))  # condition > 1e14
    assert bool(es.stop(state._replace(eigvals=jnp.array([1.0, 1.0, -1e-3]))))
    assert bool(es.stop(state, jnp.full((6,), 2.5)))  # flat ranking
    assert not bool(es.stop(state, jnp.arange(6.0)))
    two_stage = jnp.stack([jnp.full((6,), 1.0), jnp.linspace(1.0, 0.0, 6)], axis=-1)
    assert not bool(es.stop(state, two_stage))
    # a restart is init from another mean
    again = es.init(jnp.ones(3))
    np.testing.assert_array_equal(np.asarray(again.mean), 1.0)
    assert int(again.generation) == 0 and float(again.sigma) == 0.5


def test_bad_hyperparameters_are_rejected() -> None:
    with pytest.raises(ValueError, match="sigma0: expected a finite number > 0"):
        CMAES(num_dims=3, sigma0=0.0)
    with pytest.raises(ValueError, match="population_size"):
        CMAES(num_dims=3, population_size=1)
    with pytest.raises(ValueError, match="eigen_gap"):
        CMAES(num_dims=3, eigen_gap=0)
    with pytest.raises(ValueError, match="update_rule: expected one of"):
        CMAES(num_dims=3, update_rule="hansen")
    with pytest.raises(ValueError, match="ranked: expected shape"):
        es = CMAES(num_dims=3, population_size=6)
        es.update(es.init(jnp.zeros(3)), jnp.zeros((5, 3)), 2)
