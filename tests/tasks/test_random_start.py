"""`random_start`: a `_uni` task whose own evaluations start from random states (noisy fitness)."""

from __future__ import annotations

import jax
import numpy as np

from qdrl.algorithms.task_spec import parse_task
from qdrl.tasks import make_task


def test_random_start_makes_the_task_noisy_and_fixed_start_scoring_stays_deterministic() -> None:
    task = make_task("halfcheetah_uni", episode_length=5, eval_batch=4, policy_hidden=(4,), random_start=True)
    genotypes = task.init_fn(jax.random.PRNGKey(0), 4)
    a = task.scoring_fn(genotypes, jax.random.PRNGKey(1)).fitnesses
    b = task.scoring_fn(genotypes, jax.random.PRNGKey(2)).fitnesses
    assert not np.allclose(a, b)  # another key, other start states, other returns
    fixed = task.scoring(fixed_start=True)
    np.testing.assert_array_equal(fixed(genotypes, jax.random.PRNGKey(1)).fitnesses,
                                  fixed(genotypes, jax.random.PRNGKey(2)).fitnesses)
    # a spec's [task] takes it, as a boolean
    assert parse_task({"name": "halfcheetah_uni", "random_start": True})["random_start"] is True
    assert parse_task({"name": "halfcheetah_uni"})["random_start"] is False
