"""CMA-ME / CMA-MAE: rankers on constructed batches, restarts, MAE thresholds, alpha = 1 equivalence, runs."""

from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig, must_restart, num_parents
from qdrl.qd.emitters.rankers import Outcome, outcome, rank
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire
from qdrl.tasks import make_task

TASK = make_task("lp_sphere", num_dims=10)
GRID = (16, 16)


def _grid(learning_rate: float | None = None, threshold_min: float = -math.inf):  # type: ignore[no-untyped-def]
    rep = grid_repertoire(TASK.example_genotype(), GRID, TASK.descriptor_low, TASK.descriptor_high)
    return rep if learning_rate is None else rep.with_learning_rate(learning_rate, threshold_min)


def test_outcome_judges_every_candidate_against_the_archive_before_the_batch() -> None:
    rep = grid_repertoire(None, (4,), 0.0, 4.0)
    rep, _ = rep.add(None, jnp.array([[2.5]]), jnp.array([1.0]))  # cell 2 holds fitness 1
    desc = jnp.array([[0.5], [0.6], [2.2], [2.9], [3.5], [1.5]])
    fit = jnp.array([0.3, -0.2, 1.5, 0.5, jnp.nan, 2.0])
    rep, added = rep.add(None, desc, fit)
    out = outcome(rep, fit, desc, added)
    # two candidates find empty cell 0 (both new, one elite), one improves cell 2,
    # one is worse than cell 2's elite, one is NaN, one finds empty cell 1
    np.testing.assert_array_equal(np.asarray(out.status), [2, 2, 1, 0, 0, 2])
    np.testing.assert_allclose(np.asarray(out.value), [0.3, -0.2, 0.5, -0.5, -np.inf, 2.0])
    np.testing.assert_array_equal(np.asarray(added.added), [True, False, True, False, False, True])


def _constructed() -> Outcome:
    return Outcome(
        fitnesses=jnp.array([5.0, 1.0, 9.0, 3.0, jnp.nan]),
        descriptors=jnp.array([[0.0, 1.0], [2.0, 0.0], [1.0, 1.0], [-1.0, 3.0], [0.0, 0.0]]),
        status=jnp.array([1, 2, 0, 2, 0], jnp.int32),
        value=jnp.array([0.5, 1.0, -2.0, 3.0, -jnp.inf]),
    )


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("imp", [3, 1, 0, 2, 4]),  # by improvement
        ("2imp", [3, 1, 0, 2, 4]),  # new (3: 3.0, 1: 1.0), improved (0), rest (2, then 4's -inf)
        ("obj", [2, 0, 3, 1, 4]),  # by fitness, NaN last
        ("2obj", [3, 1, 0, 2, 4]),  # new by fitness (3.0 > 1.0), improved, rest
        ("rd", [1, 2, 0, 3, 4]),  # projections on (1, 0.5): 0.5, 2.0, 1.5, 0.5, 0.0; ties in batch order
        ("2rd", [1, 3, 0, 2, 4]),  # new by projection (2.0, 0.5), improved, rest (1.5, 0.0)
    ],
)
def test_rankers_on_a_constructed_batch(name: str, expected: list[int]) -> None:
    direction = jnp.array([1.0, 0.5]) if name.endswith("rd") else jnp.zeros(2)
    order, values = rank(name, _constructed(), direction)
    np.testing.assert_array_equal(np.asarray(order), expected)
    assert values.shape[0] == 5


def test_selection_and_restart_rules() -> None:
    status = jnp.array([0, 2, 1, 0])
    assert int(num_parents("filter", status, 4)) == 2 and int(num_parents("mu", status, 4)) == 2
    assert int(num_parents("filter", jnp.zeros(4, jnp.int32), 4)) == 0
    no = jnp.asarray(False)
    none_added = jnp.zeros(4, jnp.int32)
    assert bool(must_restart("no_improvement", no, none_added, jnp.asarray(1)))
    assert not bool(must_restart("no_improvement", no, status, jnp.asarray(1)))
    assert not bool(must_restart("basic", no, none_added, jnp.asarray(100)))
    assert bool(must_restart("basic", jnp.asarray(True), status, jnp.asarray(1)))
    assert bool(must_restart(5, no, status, jnp.asarray(5))) and not bool(must_restart(5, no, status, jnp.asarray(4)))


def _emitter(**kw):  # type: ignore[no-untyped-def]
    config = CMAEmitterConfig(**{"num_instances": 3, "batch_size": 8, "sigma0": 0.5, **kw})
    return CMAEmitter(config, TASK.example_genotype())


def test_an_instance_without_accepted_offspring_restarts_from_an_elite() -> None:
    elite = jnp.full((1, 10), 1.5)
    rep = _grid()
    rep, _ = rep.add(elite, TASK.scoring_fn(elite, None).descriptors, jnp.array([50.0]))
    for rule, restarts in (("no_improvement", True), ("basic", False), (1, True)):
        em = _emitter(restart_rule=rule, ranker="2rd")
        state = em.init(jax.random.PRNGKey(0), rep, None, elite)  # type: ignore[arg-type]
        genotypes = jax.jit(em.emit_instances)(state, rep, jax.random.PRNGKey(1))
        # instance 0 had one offspring accepted, instances 1 and 2 none; instance 2 inactive
        status = jnp.zeros((3, 8), jnp.int32).at[0, 3].set(2)
        spread = jax.random.normal(jax.random.PRNGKey(3), (3, 8, 2))  # no flat-ranking stop
        out = Outcome(spread[..., 0], spread, status, spread[..., 1])
        active = jnp.array([True, True, False])
        new = jax.jit(em.update_instances)(state, rep, genotypes, out, active, jax.random.PRNGKey(2))
        assert bool(new.restarted[1]) is restarts and not bool(new.restarted[2])
        assert bool(new.restarted[0]) is (rule == 1)
        if restarts:
            np.testing.assert_allclose(np.asarray(new.es.mean[1]), 1.5)  # the only elite
            assert int(new.es.generation[1]) == 0 and int(new.restarts[1]) == 1
            assert not np.allclose(np.asarray(new.direction[1]), np.asarray(state.direction[1]))
        else:
            assert int(new.es.generation[1]) == 1
        # the inactive instance kept its state
        np.testing.assert_array_equal(np.asarray(new.es.mean[2]), np.asarray(state.es.mean[2]))
        assert int(new.es.generation[2]) == 0 and int(new.clock) == 1


def test_thresholds_follow_the_batch_rule_and_elites_stay_elitist() -> None:
    rep = grid_repertoire(None, (2,), 0.0, 2.0).with_learning_rate(0.5, threshold_min=0.0)
    desc = jnp.array([[0.5], [0.7]])
    rep, r = rep.add(None, desc, jnp.array([4.0, 2.0]))
    # both beat t = 0: t = 0.25 * 0 + 0.75 * mean(4, 2) = 2.25; improvement over threshold_min
    assert float(rep.thresholds[0]) == pytest.approx(2.25)
    np.testing.assert_allclose(np.asarray(r.improvement), [4.0, 2.0])
    rep, r = rep.add(None, jnp.array([[0.5], [0.6]]), jnp.array([3.0, 1.0]))
    assert float(rep.thresholds[0]) == pytest.approx(0.5 * 2.25 + 0.5 * 3.0)
    np.testing.assert_allclose(np.asarray(r.improvement), [0.75, -1.25])
    # 3.0 beat the threshold but not the elite: the elite (4.0) stays
    assert float(rep.fitnesses[0]) == 4.0 and not bool(r.added[0])
    out = outcome(rep, jnp.array([3.0, 1.0]), jnp.array([[0.5], [0.6]]), r)
    np.testing.assert_array_equal(np.asarray(out.status), [1, 0])
    assert float(rep.thresholds[1]) == 0.0


def test_bad_archive_and_emitter_options_are_rejected() -> None:
    with pytest.raises(ValueError, match=r"repertoire.learning_rate: expected a number in \[0, 1\]"):
        _grid(1.5, 0.0)
    with pytest.raises(ValueError, match=r"repertoire\.threshold_min: expected a finite number"):
        _grid(0.01)
    for kw, message in (
        ({"sigma0": 0.0}, "emitter.sigma0: expected a number > 0, got 0.0"),
        ({"ranker": "best"}, "emitter.ranker: expected one of ['2imp', '2obj', '2rd', 'density', 'imp', 'nov', 'nslc', 'obj', 'rd'] or nothing"),
        ({"selection_rule": "all"}, "emitter.selection_rule: expected one of 'filter', 'mu', got 'all'"),
        ({"restart_rule": "never"}, "emitter.restart_rule: expected one of 'no_improvement', 'basic' or a positive integer"),
        ({"num_instances": 0}, "emitter.num_instances: expected a positive integer"),
        ({"update_rule": "hansen"}, "emitter.update_rule: expected one of 'pyribs', 'tutorial'"),
    ):
        with pytest.raises(ValueError, match=re.escape(message)):
            CMAEmitterConfig(**kw).check()  # type: ignore[arg-type]
    # each kind ranks by its own ranker unless told otherwise
    assert [CMAEmitterConfig(kind=k).ranker for k in ("cma_improvement", "cma_optimizing", "cma_random_direction")] == [
        "2imp", "obj", "2rd"]
    assert CMAEmitterConfig(kind="cma_improvement", ranker="imp").ranker == "imp"


def _run(emitter: CMAEmitter, rep, iterations: int):  # type: ignore[no-untyped-def]
    me = MapElites(TASK.scoring_fn, emitter, rep, qd_offset=TASK.qd_offset)
    state = me.init(jnp.zeros((1, 10)), jax.random.PRNGKey(0))
    return jax.jit(lambda s: me.run(s, iterations))(state)


def test_cma_mae_with_alpha_1_equals_cma_me_bit_for_bit() -> None:
    em = _emitter(ranker="2imp", selection_rule="filter", restart_rule="no_improvement")
    me_state, me_metrics = _run(em, _grid(), 25)
    mae_state, mae_metrics = _run(em, _grid(1.0), 25)
    np.testing.assert_array_equal(np.asarray(me_state.repertoire.fitnesses), np.asarray(mae_state.repertoire.fitnesses))
    np.testing.assert_array_equal(np.asarray(me_state.repertoire.genotypes), np.asarray(mae_state.repertoire.genotypes))
    for a, b in zip(jax.tree.leaves(me_state.emitter_state), jax.tree.leaves(mae_state.emitter_state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(me_metrics["qd_score"]), np.asarray(mae_metrics["qd_score"]))
    # the thresholds are the elites' fitnesses
    np.testing.assert_array_equal(np.asarray(mae_state.repertoire.thresholds), np.asarray(mae_state.repertoire.fitnesses))
    assert int(np.asarray(me_state.emitter_state.restarts).sum()) > 0


@pytest.mark.parametrize(
    ("ranker", "selection", "restart", "alpha"),
    [("imp", "mu", "basic", 0.01), ("2rd", "filter", "no_improvement", None), ("obj", "mu", "basic", None)],
)
def test_cma_emitters_improve_the_qd_score(ranker: str, selection: str, restart: str, alpha: float | None) -> None:
    em = _emitter(ranker=ranker, selection_rule=selection, restart_rule=restart)
    state, metrics = _run(em, _grid(alpha, 0.0) if alpha else _grid(), 40)
    qd = np.asarray(metrics["qd_score"])
    assert qd[-1] > 5 * qd[0] and np.all(np.diff(np.asarray(metrics["coverage"])) >= 0)
    assert float(metrics["normalised_qd_score"][-1]) == pytest.approx(qd[-1] / (16 * 16), rel=1e-6)
    assert int(state.evaluations) == 1 + 40 * 24
