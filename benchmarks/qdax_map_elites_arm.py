"""QDax 0.5.0's MAP-Elites on the arm task, timed the way `qdrl bench map_elites` times qdrl.

Runs in its own virtual environment (QDax is never a dependency of qdrl):

    python3.11 -m venv /tmp/qdax-venv && /tmp/qdax-venv/bin/pip install qdax==0.5.0
    /tmp/qdax-venv/bin/python benchmarks/qdax_map_elites_arm.py --container cvt --seed 0

Matched with qdrl: arm with `--dof` joints, an initial population of `--batch`
uniform genotypes in [0, 1], iso-line variation only (variation_percentage 1.0,
iso_sigma 0.05, line_sigma 0.1, clipped to [0, 1]), `--batch` offspring per
iteration, `--iterations` iterations as ONE `jax.lax.scan` compiled ahead of time.
Compile time and run time are measured apart; evaluations/s = batch x iterations
/ run time. The QD score is computed as qdrl computes it for the arm: the sum over
filled cells of (fitness + 0.5) (arm fitnesses lie in [-0.5, 0]; qdrl's arm
`qd_offset` is -0.5); coverage is the filled fraction in [0, 1].
CVT centroids: QDax computes them with scikit-learn's k-means (not timed, like
qdrl's JAX k-means which is also left out). Grid: QDax's Euclidean centroids,
which its repertoire indexes by nearest-centroid search.

`--hlo-dir DIR` also writes the timed program's HLO there, as `qdrl.hlo_profile.module_texts`
names them (cpu_optimized.txt, cpu_lowered.txt, cuda_lowered.txt; on a GPU
gpu_optimized.txt and gpu_lowered.txt), for
`compare_qdax_map_elites.py` to profile with `qdrl.hlo_profile.hlo_profile`.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--container", choices=["cvt", "grid"], default="cvt")
    p.add_argument("--num-centroids", type=int, default=1024)
    p.add_argument("--grid-shape", type=int, nargs=2, default=[32, 32])
    p.add_argument("--cvt-samples", type=int, default=50_000)
    p.add_argument("--dof", type=int, default=100)
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--iterations", type=int, default=200)
    p.add_argument("--iso-sigma", type=float, default=0.05)
    p.add_argument("--line-sigma", type=float, default=0.1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hlo-dir", default=None, help="write the timed program's HLO texts here")
    args = p.parse_args()

    import qdax
    from qdax.core.containers.mapelites_repertoire import (
        compute_cvt_centroids,
        compute_euclidean_centroids,
    )
    from qdax.core.emitters.mutation_operators import isoline_variation
    from qdax.core.emitters.standard_emitters import MixingEmitter
    from qdax.core.map_elites import MAPElites
    from qdax.tasks.arm import arm_scoring_function
    from qdax.utils.metrics import default_qd_metrics

    key = jax.random.key(args.seed)
    key, init_key, cvt_key, me_key = jax.random.split(key, 4)
    genotypes = jax.random.uniform(init_key, (args.batch, args.dof))
    if args.container == "cvt":
        centroids = compute_cvt_centroids(2, args.cvt_samples, args.num_centroids, 0.0, 1.0, cvt_key)
        cells = args.num_centroids
    else:
        centroids = compute_euclidean_centroids(tuple(args.grid_shape), 0.0, 1.0)
        cells = args.grid_shape[0] * args.grid_shape[1]
    variation = functools.partial(
        isoline_variation, iso_sigma=args.iso_sigma, line_sigma=args.line_sigma, minval=0.0, maxval=1.0
    )
    emitter = MixingEmitter(
        mutation_fn=lambda x, k: x, variation_fn=variation, variation_percentage=1.0, batch_size=args.batch
    )
    me = MAPElites(
        scoring_function=arm_scoring_function,
        emitter=emitter,
        metrics_function=functools.partial(default_qd_metrics, qd_offset=1.0),
    )
    repertoire, emitter_state, _ = jax.jit(me.init)(genotypes, centroids, me_key)
    jax.block_until_ready(repertoire)

    def run(rep, es, k):  # type: ignore[no-untyped-def]
        (rep, es, k), metrics = jax.lax.scan(me.scan_update, (rep, es, k), None, length=args.iterations)
        return rep, metrics

    t0, c0 = time.perf_counter(), time.process_time()
    traced = jax.jit(run).trace(repertoire, emitter_state, key)
    compiled = traced.lower().compile()
    compile_s, compile_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    if args.hlo_dir is not None:
        # qdrl.hlo_profile imports only jax: it loads from the source tree in QDax's environment too.
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
        from qdrl.hlo_profile import write_module_texts

        write_module_texts(args.hlo_dir, traced, compiled)
    t0 = time.perf_counter()
    repertoire, _metrics = compiled(repertoire, emitter_state, key)
    jax.block_until_ready(repertoire)
    run_s = time.perf_counter() - t0
    filled = repertoire.fitnesses != -jnp.inf
    record = {
        "library": "qdax",
        "version": qdax.__version__ if hasattr(qdax, "__version__") else "0.5.0",
        "jax": jax.__version__,
        "container": args.container,
        "cells": cells,
        "seed": args.seed,
        "dof": args.dof,
        "batch": args.batch,
        "iterations": args.iterations,
        "compile_s": round(compile_s, 3),
        "compile_cpu_s": round(compile_cpu_s, 3),
        "run_s": round(run_s, 4),
        "evals_per_s": round(args.batch * args.iterations / run_s, 1),
        "qd_score": float(jnp.sum(jnp.where(filled, repertoire.fitnesses + 0.5, 0.0))),
        "coverage": float(jnp.mean(filled)),
        "max_fitness": float(jnp.max(repertoire.fitnesses)),
    }
    print(json.dumps(record))


if __name__ == "__main__":
    main()
