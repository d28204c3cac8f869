"""QDax 0.5.0's PGA-ME on a brax v2 QD task, with the settings of agents/pga_me_<task>_cpu.toml.

With `--algorithm map_elites` it runs QDax's MAP-Elites instead (its MixingEmitter,
all 64 offspring iso-line), on the same task, archive and batch: QDax's own
baseline for `benchmarks/qdax_pga_me_vs_map_elites.py`.

QDax's Q-PG emitter imports `brax.v1`, which left brax in 0.12.4, so this runs only
in a virtual environment with QDax's old pins. The one used here was made with

    python3.11 -m venv /path/to/qdax-venv
    P=/path/to/qdax-venv/bin/pip
    $P install "jax[cpu]==0.4.28" "jaxlib==0.4.28" "flax==0.8.5" "optax==0.2.2" "chex==0.1.86" \
        "numpy==1.26.4" "scipy==1.13.1" "orbax-checkpoint==0.5.20" "ml-dtypes==0.4.0"
    $P install --no-deps "brax==0.10.4" "mujoco==3.1.6" "mujoco-mjx==3.1.6" "qdax==0.5.0"
    $P install --no-deps absl-py dm_env "etils[epath]" ml_collections trimesh "jaxopt==0.8.3" glfw \
        pyopengl tensorboardX flask flask_cors grpcio gym jinja2 pillow pytinyrenderer \
        "scikit-learn==1.5.2" joblib threadpoolctl cloudpickle typing_extensions "jumanji==1.0.0" \
        "tensorflow-probability==0.24.0" decorator gast dm-tree six   # QDax's DADS imports tfp

(resolving `qdax==0.5.0` with its dependencies instead makes pip backtrack for many
minutes over mujoco-mjx versions that need a newer jax). Run it as

    /path/to/qdax-venv/bin/python benchmarks/qdax_pga_me.py --task halfcheetah_uni --seed 0

Matched with qdrl (`agents/pga_me_halfcheetah_uni_cpu.toml`): spring backend,
episodes of 100 steps, every policy evaluated from one fixed initial state,
policies 64x64 tanh (lecun-uniform, tanh output), 64 offspring per iteration (32
iso-line 0.005 / 0.05, 31 PG + the greedy actor), CVT of 256 cells, TD3 with
twin 256x256 critics, 50 critic steps per iteration, 20 PG steps per offspring,
batches of 64, a buffer of 100k transitions, the other TD3 values QDax's
defaults (the same as qdrl's). `--iterations` iterations run as ONE `lax.scan`
compiled ahead of time (compile and run timed apart). env steps/s = batch x
iterations x episode length / run time (halfcheetah never terminates early).
QD score = sum over cells of (fitness + reward offset x episode length).
"""

from __future__ import annotations

import argparse
import functools
import json
import time

import jax
import jax.numpy as jnp


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--task", default="halfcheetah_uni")
    p.add_argument("--episode-length", type=int, default=100)
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--iterations", type=int, default=30)
    p.add_argument("--cells", type=int, default=256)
    p.add_argument("--cvt-samples", type=int, default=20_000)
    p.add_argument("--critic-steps", type=int, default=50)
    p.add_argument("--pg-steps", type=int, default=20)
    p.add_argument("--train-batch", type=int, default=64)
    p.add_argument("--buffer", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--algorithm", choices=("pga_me", "map_elites"), default="pga_me")
    p.add_argument("--hidden", default="64,64", help="the policies' hidden layers (the study's: 256,256)")
    p.add_argument("--activation", choices=("tanh", "relu"), default="tanh",
                   help="the policies' hidden activation (the study's, QDax's MLP default: relu)")
    p.add_argument("--log-every", type=int, default=0,
                   help="also print the metrics every N iterations (and at the last) as `rows`")
    args = p.parse_args()
    if args.iterations < 1 or args.log_every < 0:
        p.error(f"expected --iterations >= 1 and --log-every >= 0, got {args.iterations} and {args.log_every}")

    from qdax.core.containers.mapelites_repertoire import compute_cvt_centroids
    from qdax.core.emitters.mutation_operators import isoline_variation
    from qdax.core.emitters.pga_me_emitter import PGAMEConfig, PGAMEEmitter
    from qdax.core.emitters.standard_emitters import MixingEmitter
    from qdax.core.map_elites import MAPElites
    from qdax.core.neuroevolution.networks.networks import MLP
    from qdax.tasks.brax import v2 as environments
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn
    from qdax.utils.metrics import default_qd_metrics

    key = jax.random.key(args.seed)
    key, env_key, init_key, cvt_key, me_key = jax.random.split(key, 5)
    env = environments.create(args.task, episode_length=args.episode_length)
    hidden = tuple(int(h) for h in args.hidden.split(","))
    policy_network = MLP(
        layer_sizes=(*hidden, env.action_size),
        activation=jnp.tanh if args.activation == "tanh" else jax.nn.relu,
        kernel_init=jax.nn.initializers.lecun_uniform(),
        final_activation=jnp.tanh,
    )
    scoring_fn = create_brax_scoring_fn(
        env,
        policy_network,
        environments.descriptor_extractor[args.task],
        env_key,
        episode_length=args.episode_length,
        deterministic=True,
    )
    obs = jnp.zeros((args.batch, env.observation_size))
    params = jax.vmap(policy_network.init)(jax.random.split(init_key, args.batch), obs)
    low, high = env.descriptor_limits
    centroids = compute_cvt_centroids(env.descriptor_length, args.cvt_samples, args.cells, low, high, cvt_key)
    offset = environments.reward_offset[args.task] * args.episode_length
    variation = functools.partial(isoline_variation, iso_sigma=0.005, line_sigma=0.05)
    emitter: PGAMEEmitter | MixingEmitter
    if args.algorithm == "pga_me":
        config = PGAMEConfig(
            env_batch_size=args.batch,
            proportion_mutation_ga=0.5,
            num_critic_training_steps=args.critic_steps,
            num_pg_training_steps=args.pg_steps,
            replay_buffer_size=args.buffer,
            critic_hidden_layer_size=(256, 256),
            critic_learning_rate=3e-4,
            greedy_learning_rate=3e-4,
            policy_learning_rate=1e-3,
            noise_clip=0.5,
            policy_noise=0.2,
            discount=0.99,
            reward_scaling=1.0,
            batch_size=args.train_batch,
            soft_tau_update=0.005,
            policy_delay=2,
        )
        emitter = PGAMEEmitter(config=config, policy_network=policy_network, env=env, variation_fn=variation)
    else:
        emitter = MixingEmitter(
            mutation_fn=lambda x, k: x, variation_fn=variation, variation_percentage=1.0, batch_size=args.batch
        )
    me = MAPElites(scoring_fn, emitter, functools.partial(default_qd_metrics, qd_offset=offset))
    t0 = time.perf_counter()
    repertoire, emitter_state, _ = jax.jit(me.init)(params, centroids, me_key)
    jax.block_until_ready(repertoire)
    init_s = time.perf_counter() - t0

    def run(rep, es, k):  # type: ignore[no-untyped-def]
        (rep, es, k), metrics = jax.lax.scan(me.scan_update, (rep, es, k), None, length=args.iterations)
        return rep, metrics

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(repertoire, emitter_state, key).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    repertoire, metrics = compiled(repertoire, emitter_state, key)
    jax.block_until_ready(repertoire)
    run_s = time.perf_counter() - t0
    rows = [
        {
            "evaluations": args.batch * (i + 2),
            "env_steps": args.batch * (i + 2) * args.episode_length,
            "qd_score": float(metrics["qd_score"][i]),
            "coverage": float(metrics["coverage"][i]) / 100.0,
            "max_fitness": float(metrics["max_fitness"][i]),
        }
        for i in range(args.iterations)
        if args.log_every and ((i + 1) % args.log_every == 0 or i == args.iterations - 1)
    ]
    print(json.dumps({
        "library": "qdax",
        "algorithm": args.algorithm,
        "task": args.task,
        "seed": args.seed,
        "episode_length": args.episode_length,
        "batch": args.batch,
        "iterations": args.iterations,
        "cells": args.cells,
        "hidden": list(hidden),
        "activation": args.activation,
        "evaluations": args.batch * (args.iterations + 1),
        "init_s": round(init_s, 2),
        "compile_s": round(compile_s, 2),
        "run_s": round(run_s, 3),
        "env_steps_per_s": round(args.batch * args.iterations * args.episode_length / run_s, 1),
        "qd_score": float(metrics["qd_score"][-1]),
        "coverage": float(metrics["coverage"][-1]) / 100.0,
        "max_fitness": float(metrics["max_fitness"][-1]),
    } | ({"critic_steps": args.critic_steps, "pg_steps": args.pg_steps, "train_batch": args.train_batch,
          "buffer": args.buffer} if args.algorithm == "pga_me" else {}) | ({"rows": rows} if rows else {})))


if __name__ == "__main__":
    main()
