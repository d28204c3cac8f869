"""Corrected QD metrics (Flageat & Cully 2023): medians of re-evaluations, re-inserted."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.base import Evaluation
from qdrl.qd.reevaluate import corrected_repertoire, reevaluate, report
from qdrl.qd.repertoires import CellRepertoire, grid_repertoire
from qdrl.tasks import Task, arm, noisy_arm


def test_medians_move_elites_and_the_best_keeps_a_shared_cell() -> None:
    # A 2 x 2 grid on [0, 1]^2; cells 0 (x < .5, y < .5), 1 (x < .5, y >= .5), 2, 3.
    empty = grid_repertoire(jnp.zeros((1,)), (2, 2), 0.0, 1.0)
    genotypes = jnp.asarray([[10.0], [20.0], [30.0]])
    # 5 samples of 3 elites; each has outliers that a mean would follow and a median ignores.
    fit = jnp.asarray(
        [
            [1.0, 5.0, 2.0],
            [1.0, 5.0, 2.0],
            [1.0, 5.0, 2.0],
            [100.0, -100.0, 2.0],
            [100.0, -100.0, 2.0],
        ]
    )
    desc = jnp.zeros((5, 3, 2))
    desc = desc.at[:, 0].set(jnp.asarray([0.2, 0.2]))  # elite 0 stays in cell 0
    desc = desc.at[:, 1].set(jnp.asarray([0.7, 0.7]))  # elite 1 in cell 3 ...
    desc = desc.at[:3, 2].set(jnp.asarray([0.8, 0.6]))  # ... and elite 2 too (3 of 5 samples)
    desc = desc.at[3:, 2].set(jnp.asarray([0.1, 0.9]))
    corrected, median_fit, median_desc, cells = jax.jit(corrected_repertoire)(empty, genotypes, fit, desc)
    np.testing.assert_array_equal(median_fit, [1.0, 5.0, 2.0])
    np.testing.assert_allclose(median_desc, [[0.2, 0.2], [0.7, 0.7], [0.8, 0.6]])
    np.testing.assert_array_equal(cells, [0, 3, 3])
    # Cell 3 keeps elite 1 (median 5 beats 2); cells 1 and 2 stay empty.
    np.testing.assert_array_equal(corrected.fitnesses, [1.0, -np.inf, -np.inf, 5.0])
    np.testing.assert_array_equal(corrected.genotypes[:, 0], [10.0, 0.0, 0.0, 20.0])


def _filled_repertoire(task: Task, n: int, key: jax.Array) -> CellRepertoire:
    """An 8 x 8 grid filled with the best of n random genotypes, each evaluated once."""
    empty = grid_repertoire(task.example_genotype(), (8, 8), task.descriptor_low, task.descriptor_high)

    @jax.jit
    def fill(key: jax.Array) -> CellRepertoire:
        genotypes = task.init_genotypes(key, n)
        ev = task.scoring_fn(genotypes, jax.random.fold_in(key, 1))
        return empty.add(genotypes, ev.descriptors, ev.fitnesses)[0]

    return fill(key)


def test_deterministic_task_corrected_equals_stored() -> None:
    # The arm ignores its key: every sample is the stored evaluation. (Up to the last
    # bit: XLA vectorises the arm's sines differently for 64 and for 31 genotypes.)
    task = arm(num_dofs=4)
    rep = _filled_repertoire(task, 64, jax.random.PRNGKey(0))
    result = reevaluate(rep, task.scoring_fn, jax.random.PRNGKey(1), 3, task.qd_offset)
    assert result.fitness_samples.shape == (3, len(result.cells))
    assert result.stored_metrics["num_elites"] == len(result.cells) > 10
    np.testing.assert_array_equal(result.corrected_cells, result.cells)
    np.testing.assert_allclose(result.corrected.fitnesses, rep.fitnesses, rtol=1e-6)
    for key, value in result.stored_metrics.items():
        assert result.corrected_metrics[key] == pytest.approx(value, rel=1e-6), key
    summary = report(result, 3, 1)
    assert summary["elites_moved"] == 0
    assert summary["corrected"]["num_elites"] == summary["stored"]["num_elites"]


def test_on_a_feature_space_the_report_reads_the_repertoire_as_skills() -> None:
    """Given a feature space, the report adds the archive's distance to skill, stored and
    corrected, and the picked elites' replays; on a deterministic task all three agree."""
    from qdrl.envs.skills import SkillSpace
    from qdrl.qd.reevaluate import reevaluation_report
    from qdrl.skill_metrics import ARCHIVE_TARGETS, evaluation_targets, nearest_elites

    task = arm(num_dofs=4)
    rep = _filled_repertoire(task, 64, jax.random.PRNGKey(0))
    space = SkillSpace((0.0, 0.0), (1.0, 1.0))
    out = reevaluation_report(rep, task.scoring_fn, task.qd_offset, 2, 1, {}, False, space=space)
    skills = out["skills"]
    dist, ret = nearest_elites(rep.descriptors, rep.fitnesses, evaluation_targets(space, ARCHIVE_TARGETS))
    assert skills["stored"]["archive_distance_to_skill"] == pytest.approx(float(np.mean(dist)), rel=1e-5)
    assert skills["corrected"]["archive_distance_to_skill"] == pytest.approx(float(np.mean(dist)), rel=1e-5)
    assert skills["picked_distance_to_skill"] == pytest.approx(float(np.mean(dist)), rel=1e-5)
    assert skills["picked_return"] == pytest.approx(float(np.mean(ret)), rel=1e-5)
    assert "skills" not in reevaluation_report(rep, task.scoring_fn, task.qd_offset, 2, 1, {}, False)
    # an empty repertoire: no elite to read, every figure None (strict JSON), not NaN or inf
    empty = dataclasses.replace(rep, fitnesses=jnp.full_like(rep.fitnesses, -jnp.inf))
    none = reevaluation_report(empty, task.scoring_fn, task.qd_offset, 2, 1, {}, False, space=space)["skills"]
    assert none["stored"]["archive_distance_to_skill"] is None and none["picked_distance_to_skill"] is None


def test_noisy_fitness_is_corrected_to_the_true_one() -> None:
    # Fitness noise only (std 0.1): descriptors, hence cells, are exact; each stored
    # fitness is one noisy draw; the median of 64 draws is within 0.05 of the arm's
    # noise-free fitness (its standard error is 1.25 x 0.1 / 8 = 0.016).
    noisy = noisy_arm(num_dofs=4, fit_std=0.1, desc_std=0.0, params_std=0.0)
    rep = _filled_repertoire(noisy, 64, jax.random.PRNGKey(0))
    result = reevaluate(rep, noisy.scoring_fn, jax.random.PRNGKey(2), 64, noisy.qd_offset)
    genotypes = jnp.asarray(rep.genotypes)[result.cells]
    truth = arm(num_dofs=4).scoring_fn(genotypes, jax.random.PRNGKey(0)).fitnesses
    stored = np.asarray(rep.fitnesses)[result.cells]
    assert np.max(np.abs(result.median_fitness - truth)) < 0.05
    assert np.mean(np.abs(stored - truth)) > 0.05  # one draw is off by about 0.08 on average
    np.testing.assert_array_equal(result.corrected_cells, result.cells)
    assert result.corrected_metrics["num_elites"] == result.stored_metrics["num_elites"]
    expected_score = float(np.sum(result.median_fitness - noisy.qd_offset))
    assert abs(result.corrected_metrics["qd_score"] - expected_score) < 1e-3


def test_scores_are_sampled_with_independent_keys() -> None:
    def scoring_fn(genotypes: jax.Array, key: jax.Array) -> Evaluation:
        noise = jax.random.normal(key, (genotypes.shape[0],))
        return Evaluation(noise, jnp.zeros((genotypes.shape[0], 2)), {}, jnp.zeros((), jnp.int32))

    rep = grid_repertoire(jnp.zeros((1,)), (2, 2), 0.0, 1.0)
    rep = rep.add(jnp.ones((1, 1)), jnp.zeros((1, 2)), jnp.zeros((1,)))[0]
    result = reevaluate(rep, scoring_fn, jax.random.PRNGKey(0), 5, 0.0)
    assert len(np.unique(result.fitness_samples)) == 5
