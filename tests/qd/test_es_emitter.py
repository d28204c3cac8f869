"""ME-ES's OpenAI-ES emitter: the gradient estimate by hand, ascent on a quadratic, restarts, a run."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.experiment import run_spec
from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.emitters.es import ESEmitter, centred_ranks, es_gradient


class FixedRepertoire:
    def __init__(self, genotypes: jax.Array) -> None:
        self.genotypes = genotypes

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        del key
        return self.genotypes[:n]


def evaluate(genotypes: jax.Array, target: jax.Array) -> Evaluation:
    return Evaluation(
        fitnesses=-jnp.sum((genotypes - target) ** 2, axis=-1),
        descriptors=genotypes[:, :2],
        extras={},
        env_steps=jnp.zeros((), jnp.int32),
    )


def no_add(n: int) -> AddResult:
    z = jnp.zeros((n,), bool)
    return AddResult(z, z, jnp.zeros((n,)), jnp.zeros((n,), jnp.int32))


def test_es_gradient_matches_a_hand_computed_example() -> None:
    noise = jnp.array([[1.0, 0.0], [0.0, 2.0]])
    # rows: +eps1, +eps2, -eps1, -eps2 -> centred ranks [1/2, -1/6, -1/2, 1/6]
    scores = jnp.array([3.0, 1.0, 0.0, 2.0])
    np.testing.assert_allclose(np.asarray(centred_ranks(scores)), [0.5, -1 / 6, -0.5, 1 / 6], rtol=1e-6)
    # g = (1 * eps1 - 1/3 * eps2) / (2 * 2 * 0.5)
    np.testing.assert_allclose(np.asarray(es_gradient(noise, scores, 0.5)), [0.5, -1 / 3], rtol=1e-6)


def test_es_emitter_climbs_a_quadratic_and_emits_its_centre_last() -> None:
    target = jnp.array([1.0, -1.0, 0.5])
    em = ESEmitter(16, jnp.zeros(3), sigma=0.1, learning_rate=0.05, l2_coefficient=0.0,
                   num_optimizer_steps=1000, objective="fitness", descriptor_size=2, archive_size=64)
    repertoire = FixedRepertoire(jnp.zeros((4, 3)))
    key = jax.random.PRNGKey(0)
    state = em.init(key, repertoire, evaluate(jnp.zeros((4, 3)), target), jnp.zeros((4, 3)))  # type: ignore[arg-type]

    @jax.jit
    def generation(state, key):  # type: ignore[no-untyped-def]
        offspring = em.emit(state, repertoire, key)  # type: ignore[arg-type]
        return em.update(state, repertoire, offspring, evaluate(offspring, target), no_add(17), key), offspring  # type: ignore[arg-type]

    start = float(jnp.sum((state.centre - target) ** 2))
    for k in jax.random.split(key, 40):
        before = state.centre
        state, offspring = generation(state, k)
        np.testing.assert_array_equal(np.asarray(offspring[-1]), np.asarray(before))
        np.testing.assert_allclose(np.asarray(offspring[0] + offspring[8]) / 2, np.asarray(before), atol=1e-6)
    assert float(jnp.sum((state.centre - target) ** 2)) < 0.1 * start


def test_es_restarts_from_an_elite_and_explore_exploit_alternates() -> None:
    em = ESEmitter(4, jnp.zeros(3), num_optimizer_steps=2, objective="explore_exploit",
                   descriptor_size=2, archive_size=64)
    elites = jnp.full((4, 3), 7.0)
    repertoire = FixedRepertoire(elites)
    key = jax.random.PRNGKey(1)
    state = em.init(key, repertoire, evaluate(elites, jnp.zeros(3)), elites)  # type: ignore[arg-type]
    assert not bool(em.use_novelty(state))
    modes = []
    for k in jax.random.split(key, 4):
        offspring = em.emit(state, repertoire, k)  # type: ignore[arg-type]
        state = em.update(state, repertoire, offspring, evaluate(offspring, jnp.zeros(3)), no_add(5), k)  # type: ignore[arg-type]
        modes.append((int(state.generation), int(state.restarts), bool(em.use_novelty(state))))
    assert modes == [(1, 0, False), (0, 1, True), (1, 1, True), (0, 2, False)]
    np.testing.assert_array_equal(np.asarray(state.centre), np.full(3, 7.0))  # restarted from an elite
    assert int(state.archive.size) > 0


def test_es_emitter_rejects_an_odd_population() -> None:
    with pytest.raises(ValueError, match="population_size"):
        ESEmitter(5, jnp.zeros(3))


SPEC = """
[experiment]
algorithm = "me_es"
seed = 0

[task]
name = "point_maze"
episode_length = 20
policy_hidden = [8, 8]

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[es]
population_size = 8
num_optimizer_steps = 2
objective = "{objective}"
archive_size = 100

[qd]
num_iterations = 4
log_every = 2
init_batch_size = 8

[log]
progress = false
plots = false
"""


@pytest.mark.parametrize("objective", ["explore_exploit"])
def test_me_es_runs_through_qdrl_run(tmp_path: Path, objective: str) -> None:
    spec = tmp_path / "me_es.toml"
    spec.write_text(SPEC.format(objective=objective))
    summary = run_spec(spec, [], tmp_path / "out")
    assert summary["evaluations"] == 8 + 4 * 9
    assert summary["qd_score"] > 0
