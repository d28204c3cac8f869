"""ME-ES's OpenAI-ES emitter: the gradient estimate by hand, ascent on a quadratic, restarts, a run."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.experiment import run_spec
from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.emitters.es import ESConfig, ESEmitter, centred_ranks, es_gradient


class FixedRepertoire:
    def __init__(self, genotypes: jax.Array, fitnesses: jax.Array | None = None) -> None:
        self.genotypes = genotypes
        self.fitnesses = jnp.zeros(genotypes.shape[0]) if fitnesses is None else fitnesses
        self.descriptors = genotypes[:, :2]

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
    config = ESConfig(population_size=16, sigma=0.1, learning_rate=0.05, l2_coefficient=0.0,
                      num_optimizer_steps=1000, objective="fitness", archive_size=64)
    em = ESEmitter(config, jnp.zeros(3), descriptor_size=2)
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
    config = ESConfig(population_size=4, num_optimizer_steps=2, objective="explore_exploit", archive_size=64)
    em = ESEmitter(config, jnp.zeros(3), descriptor_size=2)
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


def test_restart_draws_the_fittest_the_recent_or_the_most_novel_elites() -> None:
    """ME-ES's biased restart: top-2 fitness (whole repertoire or recent cells), top-5 novelty."""
    config = ESConfig(population_size=4, objective="fitness", archive_size=64, novelty_neighbours=1)
    em = ESEmitter(config, jnp.zeros(3), descriptor_size=2)
    # 8 cells; cell 7 empty. Fitness ranks: cells 3 and 5 best; descriptors along a line.
    genotypes = jnp.stack([jnp.array([float(i), 0.0, 0.0]) for i in range(8)])
    fitnesses = jnp.array([0.0, 1.0, 2.0, 9.0, 3.0, 8.0, 4.0, -jnp.inf])
    repertoire = FixedRepertoire(genotypes, fitnesses)
    # The archive has seen descriptors near cells 0..1: cells 2..6 are the most novel filled ones.
    archive = em.init(jax.random.PRNGKey(0), repertoire,  # type: ignore[arg-type]
                      evaluate(genotypes[:2], jnp.zeros(3)), genotypes[:2]).archive
    pick = jax.jit(lambda recent, phase, k: em.restart_cell(repertoire, archive, recent, phase, k))  # type: ignore[arg-type]
    no_recent = jnp.full((5,), -1, jnp.int32)
    keys = jax.random.split(jax.random.PRNGKey(1), 200)
    exploit = {int(pick(no_recent, jnp.asarray(False), k)) for k in keys}
    assert exploit == {3, 5}
    recent = jnp.array([1, 2, 6, -1, -1], jnp.int32)  # fittest recent cells: 6 and 2
    drawn = [int(pick(recent, jnp.asarray(False), k)) for k in keys]
    assert set(drawn) == {2, 3, 5, 6}
    assert 0.35 < np.mean([c in (2, 6) for c in drawn]) < 0.65  # half of the time from the recent pool
    explore = {int(pick(no_recent, jnp.asarray(True), k)) for k in keys}
    assert explore == {2, 3, 4, 5, 6}


def test_recent_cells_keep_the_last_improved_ones() -> None:
    from qdrl.qd.emitters.es import _last_improved

    recent = jnp.array([4, 9, -1], jnp.int32)
    out = _last_improved(recent, jnp.array([-1, 7, -1, 2], jnp.int32))
    assert sorted(np.asarray(out).tolist()) == [2, 7, 9]
    out = _last_improved(jnp.full((3,), -1, jnp.int32), jnp.array([5, -1], jnp.int32))
    assert sorted(np.asarray(out).tolist()) == [-1, -1, 5]


def test_es_emitter_rejects_an_odd_population() -> None:
    with pytest.raises(ValueError, match="population_size"):
        ESEmitter(ESConfig(population_size=5), jnp.zeros(3))


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
