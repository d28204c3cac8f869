"""CMA-ME on QDax 0.5.0's own test setting, QDax against qdrl, alternating fresh processes.

QDax's `tests/baselines_test/cmame_test.py`: the 20-D sphere shifted to 2.048 (QDax's
fitness -sum (x - 2.048)^2, scored after normalising to [0, 100] between x = -5.12 and
the optimum, i.e. qdrl's `lp_sphere`), descriptors the sums of the clipped halves,
a 50 x 50 grid over [-51.2, 51.2]^2, 36 zeros as the initial population, a pool of
3 CMA improvement emitters (sigma 0.5, batch 36) of which one emits each
iteration, 2000 iterations in one `lax.scan`. qdrl runs the same through its spec
layer: `cma_me` with a `[[emitters]]` pool of 3 `cma_improvement` instances
(ranker 2imp, mu selection, no_improvement restarts, as QDax's improvement
emitter) under the bandit scheduler with one active instance.

    python benchmarks/qdax_cma_me.py --qdax-python /path/to/qdax-venv/bin/python --seeds 3 \
        --out benchmarks/results/cma_me_vs_qdax.jsonl

Each side prints one JSON line: compile and run seconds, QD score (sum of the
normalised fitnesses, QDax's metric), coverage (%), max fitness.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DIMS, GRID, BATCH, POOL, SIGMA = 20, (50, 50), 36, 3, 0.5


def side_qdax(seed: int, iterations: int) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp
    from qdax.core.containers.mapelites_repertoire import compute_euclidean_centroids
    from qdax.core.emitters.cma_improvement_emitter import CMAImprovementEmitter
    from qdax.core.emitters.cma_pool_emitter import CMAPoolEmitter
    from qdax.core.map_elites import MAPElites

    minval, maxval = -5.12, 5.12
    bd = 5.12 * 0.5 * DIMS

    def fitness(x: Any) -> Any:
        return -jnp.sum((x + minval * 0.4) * (x + minval * 0.4), axis=-1)

    def clip(x: Any) -> Any:
        return jnp.where((x <= maxval) * (x >= minval), x, maxval / x)

    def scoring(x: Any) -> Any:
        desc = jnp.array([jnp.sum(clip(x[: DIMS // 2])), jnp.sum(clip(x[DIMS // 2 :]))])
        return fitness(x), desc, {}

    def scoring_fn(x: Any, key: Any) -> Any:
        f, d, e = jax.vmap(scoring)(x)
        return f, d, e

    worst = fitness(-jnp.ones(DIMS) * 5.12)
    best = fitness(jnp.ones(DIMS) * 5.12 * 0.4)

    def metrics_fn(rep: Any) -> dict[str, Any]:
        empty = rep.fitnesses == -jnp.inf
        adjusted = (rep.fitnesses - worst) * 100 / (best - worst)
        return {"qd_score": jnp.sum(adjusted, where=~empty), "coverage": 100 * jnp.mean(1.0 - empty),
                "max_fitness": jnp.max(adjusted)}

    key = jax.random.PRNGKey(seed)
    init = jnp.zeros((BATCH, DIMS))
    centroids = compute_euclidean_centroids(grid_shape=GRID, minval=-bd, maxval=bd)
    emitter = CMAImprovementEmitter(batch_size=BATCH, genotype_dim=DIMS, centroids=centroids, sigma_g=SIGMA,
                                    min_count=1, max_count=None)
    me = MAPElites(scoring_function=scoring_fn, emitter=CMAPoolEmitter(num_states=POOL, emitter=emitter),
                   metrics_function=metrics_fn)
    key, sub = jax.random.split(key)
    repertoire, emitter_state, _ = me.init(init, centroids, sub)

    def run(carry: Any) -> Any:
        return jax.lax.scan(me.scan_update, carry, (), length=iterations)

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower((repertoire, emitter_state, key)).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, metrics = jax.block_until_ready(compiled((repertoire, emitter_state, key)))
    run_s = time.perf_counter() - t0
    return {"compile_s": compile_s, "run_s": run_s, **{k: float(v[-1]) for k, v in metrics.items()}}


def side_qdrl(seed: int, iterations: int) -> dict[str, Any]:
    import jax

    from qdrl.experiment import build_run, compile_chunk, initial_state, run_chunk

    spec = {
        "experiment": {"algorithm": "cma_me", "seed": seed},
        "task": {"name": "lp_sphere", "num_dims": DIMS},
        "repertoire": {"kind": "grid", "grid_shape": list(GRID)},
        "emitters": [{"kind": "cma_improvement", "num_instances": POOL, "batch_size": BATCH, "sigma0": SIGMA,
                      "ranker": "2imp", "selection_rule": "mu", "restart_rule": "no_improvement"}],
        "scheduler": {"num_active": 1, "reselect": "all"},
        "qd": {"num_iterations": iterations, "log_every": iterations, "init_batch_size": BATCH,
               "initial_genotypes": "zeros"},
    }
    run, exp, _ = build_run(spec)
    state = initial_state(run, exp.seed)
    compiled = compile_chunk(run, state)
    compile_s = compiled.seconds
    t0 = time.perf_counter()
    state, metrics = run_chunk(run, compiled.fn, state)
    jax.block_until_ready(metrics)
    run_s = time.perf_counter() - t0
    # QDax's metrics: the sum of the (already 0-100 normalised) fitnesses, coverage in %
    return {"compile_s": compile_s, "run_s": run_s, "qd_score": float(metrics["qd_score"][-1]),
            "coverage": 100 * float(metrics["coverage"][-1]), "max_fitness": float(metrics["max_fitness"][-1])}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--side", choices=["qdax", "qdrl"], help="run one side in this process and print it")
    p.add_argument("--qdax-python", help="python of a virtual environment with QDax 0.5.0 (required unless --side qdrl)")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--seed", type=int, default=0, help="with --side: the seed of that run")
    p.add_argument("--iterations", type=int, default=2000)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cma_me_vs_qdax.jsonl")
    args = p.parse_args()
    if args.side:
        fn = side_qdax if args.side == "qdax" else side_qdrl
        print(json.dumps({"side": args.side, **fn(args.seed, args.iterations)}))
        return
    if args.qdax_python is None:
        p.error("--qdax-python is required (the python of QDax 0.5.0's virtual environment)")
    done = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    for seed in range(args.seeds):
        for side in (("qdrl", "qdax") if seed % 2 == 0 else ("qdax", "qdrl")):
            if any(r["seed"] == seed and r["side"] == side for r in done):
                continue
            python = sys.executable if side == "qdrl" else args.qdax_python
            load = os.getloadavg()[0]
            out = subprocess.run([python, __file__, "--side", side, "--seed", str(seed),
                                  "--iterations", str(args.iterations)],
                                 capture_output=True, text=True, check=True, env=env)
            rec = json.loads(out.stdout.strip().splitlines()[-1])
            rec.update(seed=seed, load_before=load, load_after=os.getloadavg()[0], iterations=args.iterations)
            done.append(rec)
            with args.out.open("a") as f:
                f.write(json.dumps(rec) + "\n")
            print(json.dumps(rec), flush=True)
    for side in ("qdrl", "qdax"):
        rs = [r for r in done if r["side"] == side]
        if rs:
            print(side, {k: round(statistics.mean(r[k] for r in rs), 3)
                         for k in ("compile_s", "run_s", "qd_score", "coverage", "max_fitness")})


if __name__ == "__main__":
    main()
