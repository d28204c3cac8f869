"""The bandit scheduler: UCB1 choices on constructed reward histories, and a mixed CMA + GA pool."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.emitters.scheduler import (
    BanditScheduler,
    SchedulerConfig,
    StatelessInstances,
    choose,
    ucb1,
)
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire
from qdrl.tasks import make_task


def test_ucb1_by_hand() -> None:
    successes = jnp.array([10.0, 2.0, 0.0, 0.0])
    selections = jnp.array([20.0, 4.0, 16.0, 0.0])
    score = np.asarray(ucb1(successes, selections, zeta=0.5))
    total = np.log(40.0)
    np.testing.assert_allclose(score[:3], [0.5 + 0.5 * np.sqrt(total / 20), 0.5 + 0.5 * np.sqrt(total / 4), 0.5 * np.sqrt(total / 16)], rtol=1e-6)
    assert score[3] > 1e30  # never selected: first


def test_choice_on_a_constructed_reward_history() -> None:
    successes = jnp.array([10.0, 2.0, 0.0, 0.0, 30.0, 5.0])
    selections = jnp.array([20.0, 4.0, 16.0, 0.0, 36.0, 36.0])
    active = jnp.array([True, True, False, False, True, False])
    # instance 4 restarted: 0 and 1 keep their places; 3 (never tried) then the best UCB1 among 2, 4, 5
    reselect = jnp.array([False, False, False, False, True, False])
    chosen = choose(successes, selections, active, reselect, 4, zeta=0.05)
    # UCB1 with zeta 0.05: 4 -> 0.833 + ..., 5 -> 0.139 + ..., 2 -> 0 + ...
    np.testing.assert_array_equal(np.asarray(chosen), [0, 1, 3, 4])
    # "all": every active instance competes again; the untried one, then the best rates 4 (0.83), 0 (0.5), 1 (0.5, fewer tries: larger bonus)
    everyone = choose(successes, selections, active, active, 4, zeta=0.05)
    np.testing.assert_array_equal(np.asarray(everyone), [0, 1, 3, 4])
    everyone = choose(successes, selections, active, active, 2, zeta=0.05)
    np.testing.assert_array_equal(np.asarray(everyone), [3, 4])
    # with a large zeta exploration dominates: 1 (5.93, 4 tries) and 0 (2.93) beat 4 (2.64)
    np.testing.assert_array_equal(np.asarray(choose(successes, selections, active, active, 3, zeta=5.0)), [0, 1, 3])


def test_a_mixed_cma_and_ga_pool_runs_and_counts_rewards() -> None:
    task = make_task("lp_sphere", num_dims=8)
    rep = grid_repertoire(task.example_genotype(), (16, 16), task.descriptor_low, task.descriptor_high)
    cma = CMAEmitter(CMAEmitterConfig(num_instances=3, batch_size=8), task.example_genotype())
    ga = StatelessInstances(isoline_emitter(8, 0.5, 0.2), num_instances=2)
    scheduler = BanditScheduler((cma, ga), SchedulerConfig(num_active=2, reselect="all"))
    assert scheduler.batch_size == 16 and scheduler.num_instances == 5
    me = MapElites(task.scoring_fn, scheduler, rep, qd_offset=task.qd_offset)
    state = me.init(jnp.zeros((1, 8)), jax.random.PRNGKey(0))
    state, metrics = jax.jit(lambda s: me.run(s, 30))(state)
    es = state.emitter_state
    assert float(jnp.sum(es.selections)) == 30 * 16  # every emitted offspring counted once
    assert float(jnp.sum(es.successes)) <= float(jnp.sum(es.selections))
    assert int(jnp.sum(es.selections > 0)) == 5  # every arm was tried
    qd = np.asarray(metrics["qd_score"])
    assert qd[-1] > 3 * qd[0]
    # an instance that never emitted kept its CMA-ES untouched
    assert np.all(np.asarray(es.pool[0].es.generation) <= 30)


def test_bad_scheduler_options() -> None:
    task = make_task("lp_sphere", num_dims=8)
    cma = CMAEmitter(CMAEmitterConfig(num_instances=3, batch_size=8), task.example_genotype())
    with pytest.raises(ValueError, match=re.escape("scheduler.num_active: expected an integer in [1, 3]")):
        BanditScheduler((cma,), SchedulerConfig(num_active=4))
    with pytest.raises(ValueError, match=re.escape("scheduler.reselect: expected one of 'terminated', 'all', got 'some'")):
        BanditScheduler((cma,), SchedulerConfig(num_active=1, reselect="some"))
    with pytest.raises(ValueError, match="one number of offspring per instance"):
        BanditScheduler((cma, StatelessInstances(isoline_emitter(5, 0.5, 0.2), 2)), SchedulerConfig(num_active=1))
