"""Does a policy's score depend on the batch it is scored in, on this machine's device?

    python benchmarks/batch_reproduce.py --task halfcheetah_uni --policies 12 --eval-batch 8

Scores `--policies` random policies of a brax QD task together (blocks of
`--eval-batch`, as `qdrl run` evaluates), then a few of them one by one and all
of them in a shuffled order, each shape compiled as runs compile it, and prints
JSON with the largest differences of fitness and descriptor (0.0 when every
policy reproduces exactly). `tests/tasks/test_policy_eval.py` checks the same on
the CPU; this script is for accelerators, which the test suite never uses.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import jax
import numpy as np

from qdrl.tasks import make_task


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--task", default="halfcheetah_uni")
    p.add_argument("--policies", type=int, default=12)
    p.add_argument("--eval-batch", type=int, default=8)
    p.add_argument("--episode-length", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    task = make_task(args.task, episode_length=args.episode_length, eval_batch=args.eval_batch)
    key, init_key = jax.random.split(jax.random.PRNGKey(args.seed))
    policies = task.init_genotypes(init_key, args.policies)
    score = jax.jit(task.scoring_fn)

    def take(tree: Any, idx: list[int]) -> Any:
        return jax.tree.map(lambda x: x[np.asarray(idx)], tree)

    together = score(policies, key)
    fit, desc = np.asarray(together.fitnesses), np.asarray(together.descriptors)
    alone_idx = [0, args.policies // 2, args.policies - 1]
    alone = [score(take(policies, [i]), key) for i in alone_idx]
    order = list(np.random.default_rng(args.seed).permutation(args.policies))
    shuffled = score(take(policies, order), key)
    record = {
        "task": args.task,
        "device": str(jax.devices()[0]),
        "policies": args.policies,
        "eval_batch": args.eval_batch,
        "fitness_range": [float(fit.min()), float(fit.max())],
        "alone_max_abs_diff_fitness": max(float(np.max(np.abs(np.asarray(a.fitnesses) - fit[i])))
                                          for a, i in zip(alone, alone_idx, strict=True)),
        "alone_max_abs_diff_descriptor": max(float(np.max(np.abs(np.asarray(a.descriptors) - desc[i])))
                                             for a, i in zip(alone, alone_idx, strict=True)),
        "shuffled_max_abs_diff_fitness": float(np.max(np.abs(np.asarray(shuffled.fitnesses) - fit[order]))),
        "shuffled_max_abs_diff_descriptor": float(np.max(np.abs(np.asarray(shuffled.descriptors) - desc[order]))),
    }
    print(json.dumps(record))


if __name__ == "__main__":
    main()
