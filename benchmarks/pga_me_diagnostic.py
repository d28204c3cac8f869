"""PGA-ME diagnostic: do the policy-gradient offspring improve on their parents as training goes?

    python benchmarks/pga_me_diagnostic.py --chunks 10
    python benchmarks/pga_me_diagnostic.py --chunks 10 --set pg.num_critic_training_steps=300 \\
        pg.num_pg_training_steps=100 pg.training_batch_size=256

Runs `agents/pga_me_halfcheetah_uni_cpu.toml` (or `--spec`) chunk by chunk. After each
chunk it draws 32 parents from the repertoire, applies the Q-PG emitter's own
`pg_variation` to them with the current critic, and evaluates parents, offspring
and the greedy actor on one key. It prints one JSON line per chunk: coverage, the
mean fitness of parents and offspring, the share of offspring fitter than their
parent, the greedy actor's fitness, and the critic steps so far.
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--spec", default=str(ROOT / "agents" / "pga_me_halfcheetah_uni_cpu.toml"))
    p.add_argument("--chunks", type=int, default=10)
    p.add_argument("--set", nargs="*", default=[], metavar="SECTION.KEY=VALUE")
    args = p.parse_args()

    from qdrl.experiment import build_run, compile_chunk, initial_state, run_chunk
    from qdrl.qd.emitters.qd_rl import make_pga_me

    spec = tomllib.loads(Path(args.spec).read_text())
    for item in args.set:
        key, _, value = item.partition("=")
        section, _, field = key.partition(".")
        spec.setdefault(section, {})[field] = tomllib.loads(f"v = {value}")["v"]
    run, _, _ = build_run(spec)
    assert run.qd is not None
    state = initial_state(run, 0)
    chunk = compile_chunk(run, state).fn
    task = run.qd.task
    pg = make_pga_me(task, run.sections["pg"]).emitter.emitters[1]  # the run's Q-PG emitter, rebuilt
    score = jax.jit(task.scoring_fn)
    vary = jax.jit(jax.vmap(pg.pg_variation, in_axes=(None, 0, 0)))
    start = time.perf_counter()
    for chunk in range(args.chunks):
        state, metrics = run_chunk(run, chunk, state)
        parent_key, vary_key, eval_key, greedy_key = jax.random.split(jax.random.PRNGKey(100 + chunk), 4)
        parents = state.repertoire.sample(parent_key, 32)
        offspring = vary(state.emitter_state[1], parents, jax.random.split(vary_key, 32))
        fp = np.asarray(score(parents, eval_key).fitnesses)
        fo = np.asarray(score(offspring, eval_key).fitnesses)
        greedy = jax.tree.map(lambda x: x[None], state.emitter_state[1].td3.policy_params)
        print(json.dumps({
            "wall_s": round(time.perf_counter() - start, 1),
            "iteration": int(state.iteration),
            "coverage": round(float(metrics["coverage"][-1]), 3),
            "parents": round(float(fp.mean()), 1),
            "offspring": round(float(fo.mean()), 1),
            "offspring_better": round(float(np.mean(fo > fp)), 2),
            "greedy": round(float(score(greedy, greedy_key).fitnesses[0]), 1),
            "critic_steps": int(state.emitter_state[1].td3.steps),
        }), flush=True)


if __name__ == "__main__":
    main()
