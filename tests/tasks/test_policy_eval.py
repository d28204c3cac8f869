"""A policy's fitness and descriptor do not depend on the batch it is evaluated in.

halfcheetah's contact dynamics are chaotic (a relative change of 1e-7 in the
parameters moves a 100-step return by several units) and XLA compiles the batched
physics differently for different batch sizes, so without the fixed evaluation
width of `qdrl.tasks.policy.policy_scoring_fn` a policy scored alone got another
fitness than in its batch (issue: every one of 112 stored elites differed).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from qdrl.tasks import brax_qd

EPISODE = 40
WIDTH = 4
# The numerics of optimised code, which runs use (the test suite asks XLA for quick,
# unoptimised compiles, whose numerics happen not to depend on the batch here).
OPTIMISED = {"xla_backend_optimization_level": 3, "xla_llvm_disable_expensive_passes": False}


def take(tree: Any, idx: list[int]) -> Any:
    return jax.tree.map(lambda x: x[np.asarray(idx)], tree)


def test_scores_do_not_depend_on_the_batch() -> None:
    # Two compiled shapes: 5 policies (two blocks, the second padded) and 1 (one padded block).
    task = brax_qd.halfcheetah_uni(episode_length=EPISODE, eval_batch=WIDTH)
    key = jax.random.PRNGKey(1)
    policies = task.init_genotypes(jax.random.PRNGKey(3), 5)
    compiled: dict[int, Any] = {}

    def score(genotypes: Any, key: jax.Array) -> Any:
        n = jax.tree.leaves(genotypes)[0].shape[0]
        if n not in compiled:
            compiled[n] = jax.jit(task.scoring_fn).lower(genotypes, key).compile(OPTIMISED)
        return compiled[n](genotypes, key)

    together = score(policies, key)
    fit, desc = np.asarray(together.fitnesses), np.asarray(together.descriptors)
    assert fit.shape == (5,) and desc.shape == (5, 2)
    assert np.all(np.isfinite(fit)) and len(np.unique(fit)) == 5
    assert np.asarray(together.extras["transitions"].obs).shape[:2] == (EPISODE, 5)
    assert int(together.env_steps) == 5 * EPISODE

    for i in (0, 4):  # one by one
        alone = score(take(policies, [i]), key)
        np.testing.assert_array_equal(np.asarray(alone.fitnesses), fit[i : i + 1])
        np.testing.assert_array_equal(np.asarray(alone.descriptors), desc[i : i + 1])

    # Another order: every policy at another place in another block.
    order = [4, 2, 0, 3, 1]
    shuffled = score(take(policies, order), key)
    np.testing.assert_array_equal(np.asarray(shuffled.fitnesses), fit[order])
    np.testing.assert_array_equal(np.asarray(shuffled.descriptors), desc[order])
    # The trajectory handed back for a policy is the same in both batches.
    np.testing.assert_array_equal(
        np.asarray(shuffled.extras["transitions"].obs)[:, 0],
        np.asarray(together.extras["transitions"].obs)[:, 4],
    )
