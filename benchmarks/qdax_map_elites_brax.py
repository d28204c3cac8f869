"""QDax 0.5.0's MAP-Elites on a brax v2 QD task, timed like `qdrl bench policy_map_elites`.

Runs in QDax's own virtual environment (today's jax/brax; `qdax.tasks.brax.v2`):

    /path/to/qdax-venv/bin/python benchmarks/qdax_map_elites_brax.py --task halfcheetah_uni --seed 0

Matched with qdrl: spring backend, episodes of `--episode-length` steps, policies
64x64 tanh, `--batch` offspring per iteration, iso-line variation (0.005, 0.05),
CVT archive of 1024 cells, `--iterations` iterations as ONE `lax.scan` compiled
ahead of time (compile and run timed apart). env steps/s = batch x iterations x
episode length / run time. `reset_s` is the time QDax spends resetting the
environment when it builds its scoring function (outside the timed compile). QD score = sum over cells of (fitness + reward
offset x episode length), QDax's own offset (the same as qdrl's `qd_offset`).
Both sides evaluate every policy from one fixed initial state.

`--hlo-dir DIR` also writes the timed program's HLO there (cpu_optimized.txt,
cpu_lowered.txt, cuda_lowered.txt), as `qdax_map_elites_arm.py` does.
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


def qdax_map_elites(env, task: str, scoring_fn, batch: int, episode_length: int, cells: int,  # type: ignore[no-untyped-def]
                    cvt_samples: int, cvt_key):
    """QDax's MAPElites with iso-line 0.005 / 0.05 and its CVT centroids, as this benchmark runs it."""
    from qdax.core.containers.mapelites_repertoire import compute_cvt_centroids
    from qdax.core.emitters.mutation_operators import isoline_variation
    from qdax.core.emitters.standard_emitters import MixingEmitter
    from qdax.core.map_elites import MAPElites
    from qdax.tasks.brax import v2 as environments
    from qdax.utils.metrics import default_qd_metrics

    low, high = env.descriptor_limits
    centroids = compute_cvt_centroids(env.descriptor_length, cvt_samples, cells, low, high, cvt_key)
    offset = environments.reward_offset[task] * episode_length
    emitter = MixingEmitter(
        mutation_fn=lambda x, k: x,
        variation_fn=functools.partial(isoline_variation, iso_sigma=0.005, line_sigma=0.05),
        variation_percentage=1.0,
        batch_size=batch,
    )
    return MAPElites(scoring_fn, emitter, functools.partial(default_qd_metrics, qd_offset=offset)), centroids


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--task", default="halfcheetah_uni")
    p.add_argument("--episode-length", type=int, default=100)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--iterations", type=int, default=50)
    p.add_argument("--cells", type=int, default=1024)
    p.add_argument("--cvt-samples", type=int, default=50_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--activation", choices=("tanh", "relu"), default="tanh",
                   help="hidden activation (QDax's default task uses relu)")
    p.add_argument("--hlo-dir", default=None, help="write the timed program's HLO texts here")
    args = p.parse_args()

    from qdax.core.neuroevolution.networks.networks import MLP
    from qdax.tasks.brax import v2 as environments
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn

    key = jax.random.key(args.seed)
    key, env_key, init_key, cvt_key, me_key = jax.random.split(key, 5)
    # QDax's `create_default_brax_task_components` builds a ReLU MLP; qdrl's policy
    # tasks use the literature's tanh MLP. Build QDax's task with a tanh MLP so both
    # sides search the same policy space (same layers, lecun-uniform init, tanh output).
    env = environments.create(args.task, episode_length=args.episode_length)
    policy_network = MLP(
        layer_sizes=(64, 64, env.action_size),
        activation=jnp.tanh if args.activation == "tanh" else jax.nn.relu,
        kernel_init=jax.nn.initializers.lecun_uniform(),
        final_activation=jnp.tanh,
    )
    # With deterministic=True QDax resets the environment HERE, eagerly, and bakes the
    # initial state into the scoring function: that reset is not part of the timed
    # compilation (nor is qdrl's, which computes its fixed start state in a program of its own).
    t0, c0 = time.perf_counter(), time.process_time()
    scoring_fn = create_brax_scoring_fn(
        env,
        policy_network,
        environments.descriptor_extractor[args.task],
        env_key,
        episode_length=args.episode_length,
        deterministic=True,
    )
    reset_s, reset_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    obs = jnp.zeros((args.batch, env.observation_size))
    params = jax.vmap(policy_network.init)(jax.random.split(init_key, args.batch), obs)
    me, centroids = qdax_map_elites(env, args.task, scoring_fn, args.batch, args.episode_length,
                                    args.cells, args.cvt_samples, cvt_key)
    repertoire, emitter_state, _ = jax.jit(me.init)(params, centroids, me_key)
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
    repertoire, metrics = compiled(repertoire, emitter_state, key)
    jax.block_until_ready(repertoire)
    run_s = time.perf_counter() - t0
    print(json.dumps({
        "library": "qdax",
        "task": args.task,
        "seed": args.seed,
        "episode_length": args.episode_length,
        "activation": args.activation,
        "batch": args.batch,
        "iterations": args.iterations,
        "cells": args.cells,
        "evaluations": args.batch * (args.iterations + 1),
        "compile_s": round(compile_s, 2),
        "compile_cpu_s": round(compile_cpu_s, 2),
        "reset_s": round(reset_s, 2),
        "reset_cpu_s": round(reset_cpu_s, 2),
        "run_s": round(run_s, 3),
        "env_steps_per_s": round(args.batch * args.iterations * args.episode_length / run_s, 1),
        "qd_score": float(metrics["qd_score"][-1]),
        "coverage": float(metrics["coverage"][-1]) / 100.0,
        "max_fitness": float(metrics["max_fitness"][-1]),
    }))


if __name__ == "__main__":
    main()
