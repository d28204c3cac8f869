"""First replication point of CMA-ME / CMA-MAE against MAP-Elites (line) on the LP sphere.

The setting of Fontaine & Nikolaidis 2023 (CMA-MAE, Table 1) and pyribs'
`examples/sphere.py`: LP sphere in 100 dimensions, a 100 x 100 grid over
[-256, 256]^2, 540 solutions per iteration (15 emitters of 36), sigma0 = 0.5,
QD score with offset 0 divided by the 10,000 cells. Each run goes on, in jitted
chunks of `--chunk` iterations, until `--budget` seconds of wall time have passed
(the papers run 10,000 iterations) and writes one JSON line per run:

    python benchmarks/cma_lp_sphere.py --algo cma_mae --budget 600 \
        --out benchmarks/results/cma_lp_sphere.jsonl

Algorithms (`--algo`):
- `map_elites`: MAP-Elites with Iso+LineDD (iso 0.5, line 0.2), 100 N(0, I) initial solutions;
- `cma_me`: CMA-ME as the CMA-MAE paper's baseline: `2imp`, mu selection, basic restarts;
- `cma_me_filter`: CMA-ME as pyribs' default: `2imp`, filter selection, no-improvement restarts;
- `cma_mae`: CMA-MAE: `imp`, mu, basic, archive learning rate 0.01, threshold_min 0.
CMA runs start every emitter at x0 = 0 (one initial solution).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from qdrl.lapack_threads import single_threaded_lapack
from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire
from qdrl.tasks import make_task

PUBLISHED = {  # normalised QD score after 10,000 iterations (CMA-MAE paper, Table 1; pyribs)
    "map_elites": 49.07,  # MAP-Elites (line); plain MAP-Elites 41.64
    "cma_me": 36.50,
    "cma_me_filter": 45.7,
    "cma_mae": 64.86,
}


def build(algo: str, dims: int, grid: int, instances: int, lam: int, **cma: object):  # type: ignore[no-untyped-def]
    task = make_task("lp_sphere", num_dims=dims)
    rep = grid_repertoire(task.example_genotype(), (grid, grid), task.descriptor_low, task.descriptor_high)
    if algo == "map_elites":
        emitter = isoline_emitter(instances * lam, iso_sigma=0.5, line_sigma=0.2)
        init = lambda key: task.init_genotypes(key, 100)  # noqa: E731
    else:
        options = {
            "cma_me": {"ranker": "2imp", "selection_rule": "mu", "restart_rule": "basic"},
            "cma_me_filter": {"ranker": "2imp", "selection_rule": "filter", "restart_rule": "no_improvement"},
            "cma_mae": {"ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"},
        }[algo]
        config = CMAEmitterConfig(num_instances=instances, batch_size=lam, sigma0=0.5, **options, **cma)
        emitter = CMAEmitter(config, task.example_genotype())
        if algo == "cma_mae":
            rep = rep.with_learning_rate(0.01, threshold_min=0.0)
        init = lambda key: jnp.zeros((1, dims), jnp.float32)  # noqa: E731
    return MapElites(task.scoring_fn, emitter, rep, qd_offset=task.qd_offset), init


def main() -> None:
    with single_threaded_lapack():
        _main()


def _main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", required=True, choices=sorted(PUBLISHED))
    parser.add_argument("--budget", type=float, default=600.0, help="wall seconds of running (compile excluded)")
    parser.add_argument("--max-iterations", type=int, default=10_000)
    parser.add_argument("--chunk", type=int, default=250)
    parser.add_argument("--dims", type=int, default=100)
    parser.add_argument("--grid", type=int, default=100)
    parser.add_argument("--instances", type=int, default=15)
    parser.add_argument("--lam", type=int, default=36)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--update-rule", default="pyribs", choices=["pyribs", "tutorial"])
    parser.add_argument("--eigen-gap", type=int, default=None, help="generations (default: pyribs' gap)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    cma = {"update_rule": args.update_rule, "eigen_gap": args.eigen_gap}
    me, init = build(args.algo, args.dims, args.grid, args.instances, args.lam, **cma)
    init_key, run_key = jax.random.split(jax.random.PRNGKey(args.seed))
    state = jax.jit(me.init)(init(init_key), run_key)
    run = jax.jit(lambda s: me.run(s, args.chunk))
    t0 = time.perf_counter()
    run = run.lower(state).compile()
    compile_s = time.perf_counter() - t0
    curve = []
    running = 0.0
    while running < args.budget and int(state.iteration) < args.max_iterations:
        t0 = time.perf_counter()
        state, metrics = run(state)
        jax.block_until_ready(metrics)
        running += time.perf_counter() - t0
        point = {
            "iteration": int(state.iteration),
            "evaluations": int(state.evaluations),
            "wall_s": round(running, 2),
            "normalised_qd_score": float(metrics["normalised_qd_score"][-1]),
            "qd_score": float(metrics["qd_score"][-1]),
            "coverage": float(metrics["coverage"][-1]),
            "max_fitness": float(metrics["max_fitness"][-1]),
        }
        curve.append(point)
        print(json.dumps(point), flush=True)
    result = {
        "algo": args.algo,
        "seed": args.seed,
        **({} if args.algo == "map_elites" else cma),
        "dims": args.dims,
        "grid": [args.grid, args.grid],
        "emitters": f"{args.instances} x {args.lam}",
        "iterations": int(state.iteration),
        "compile_s": round(compile_s, 2),
        "s_per_iteration": running / max(int(state.iteration), 1),
        "final": curve[-1] if curve else None,
        "published_normalised_qd_score_10k": PUBLISHED[args.algo],
        "device": str(jax.devices()[0]),
        "curve": curve,
    }
    if args.algo != "map_elites":
        result["restarts"] = int(jnp.sum(state.emitter_state.restarts))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("a") as f:
            f.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
