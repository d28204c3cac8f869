"""The same halfcheetah_uni policies scored by QDax 0.5.0 and by qdrl, batched and one at a time.

Two steps, each in its own environment (QDax is never a dependency of qdrl):

    QDAX_VENV/bin/python benchmarks/qdax_same_policies.py qdax --seed 1 --out /tmp/same.npz
    python benchmarks/qdax_same_policies.py qdrl --qdax /tmp/same.npz

The QDax step builds the task as `qdax_map_elites_brax.py` does (spring, episodes of
100 steps, tanh 64x64 MLP, lecun-uniform, deterministic start), draws the initial
population of 128 policies of `--seed`, scores it with QDax's scoring function (one
batch) and rolls the first `--loop` policies out one at a time (jitted reset and step
in a Python loop, from QDax's start state). The qdrl step loads those parameters into
qdrl's policy network, rolls the same policies out one at a time through qdrl's brax
environment from the same start state, and scores all 128 with qdrl's halfcheetah_uni
task started from that state. Prints one JSON line: per policy, the return of each
path, and the largest differences.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

EPISODE = 100
BATCH = 128


def _loop(reset: Any, step: Any, act: Any, key: Any, obs_of: Any, reward_of: Any) -> float:
    state = reset(key)
    total = 0.0
    for _ in range(EPISODE):
        state = step(state, act(obs_of(state)))
        total += float(reward_of(state))
    return total


def qdax_side(seed: int, loops: int, out: str) -> None:
    from qdax.core.neuroevolution.networks.networks import MLP
    from qdax.tasks.brax import v2 as environments
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn

    key = jax.random.key(seed)
    key, env_key, init_key, _cvt_key, _me_key = jax.random.split(key, 5)
    env = environments.create("halfcheetah_uni", episode_length=EPISODE)
    net = MLP(layer_sizes=(64, 64, env.action_size), activation=jnp.tanh,
              kernel_init=jax.nn.initializers.lecun_uniform(), final_activation=jnp.tanh)
    scoring_fn = create_brax_scoring_fn(env, net, environments.descriptor_extractor["halfcheetah_uni"],
                                        env_key, episode_length=EPISODE, deterministic=True)
    params = jax.vmap(net.init)(jax.random.split(init_key, BATCH), jnp.zeros((BATCH, env.observation_size)))
    fitness, descriptors = jax.jit(scoring_fn)(params, key)[:2]
    start_key = jax.random.split(env_key)[1]  # the key QDax's deterministic scoring resets with
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    loop = [
        _loop(reset, step, jax.jit(lambda o, i=i: net.apply(jax.tree.map(lambda x: x[i], params), o)),
              start_key, lambda s: s.obs, lambda s: s.reward)
        for i in range(loops)
    ]
    layers = params["params"]
    arrays = {f"w{j}": np.asarray(layers[f"Dense_{j}"]["kernel"]) for j in range(3)}
    arrays.update({f"b{j}": np.asarray(layers[f"Dense_{j}"]["bias"]) for j in range(3)})
    np.savez(out, fitness=np.asarray(fitness), descriptors=np.asarray(descriptors), loop=np.asarray(loop),
             start_key=np.asarray(jax.random.key_data(start_key)), seed=seed, **arrays)
    print(json.dumps({"wrote": out, "policies": BATCH, "one_at_a_time": loops}))


def qdrl_side(path: str) -> None:
    from qdrl.tasks import make_task
    from qdrl.tasks import policy as policy_module
    from qdrl.tasks.policy import policy_network

    d = np.load(path)
    start_key = jnp.asarray(d["start_key"], jnp.uint32)
    genotypes = {
        f"policy/~/linear_{j}": {"w": jnp.asarray(d[f"w{j}"]), "b": jnp.asarray(d[f"b{j}"])} for j in range(3)
    }
    # qdrl's tasks start every episode from the state of a fixed key; start from QDax's.
    fixed = policy_module.fixed_start_state
    policy_module.fixed_start_state = lambda env, _key: fixed(env, start_key)
    try:
        task = make_task("halfcheetah_uni", episode_length=EPISODE, eval_batch=BATCH)
        evaluation = jax.jit(task.scoring_fn)(genotypes, jax.random.PRNGKey(0))
    finally:
        policy_module.fixed_start_state = fixed
    env = task.env  # the task's own brax environment, stepped one policy at a time
    reset, step = jax.jit(env._reset), jax.jit(env._step)

    network = policy_network(env.action_size)  # qdrl's policy: the network the task evaluates

    def act_of(i: int) -> Any:
        params = jax.tree.map(lambda x: x[i], genotypes)
        return jax.jit(lambda obs: network.apply(params, obs))

    loops = len(d["loop"])
    qdrl_loop = [
        _loop(reset, lambda st, a: step(st[0], a), act_of(i), start_key, lambda st: st[1], lambda st: st[2])
        for i in range(loops)
    ]
    batched = np.asarray(evaluation.fitnesses)
    record = {
        "seed": int(d["seed"]),
        "policies": [
            {"policy": i, "qdax_batched": round(float(d["fitness"][i]), 4), "qdax_one": round(float(d["loop"][i]), 4),
             "qdrl_one": round(qdrl_loop[i], 4), "qdrl_batched": round(float(batched[i]), 4)}
            for i in range(loops)
        ],
        "max_abs_diff": {
            "qdrl_one_vs_qdax_one": float(np.max(np.abs(np.asarray(qdrl_loop) - d["loop"]))),
            "qdax_batched_vs_qdax_one": float(np.max(np.abs(d["fitness"][:loops] - d["loop"]))),
            "qdrl_batched_vs_qdax_batched_all": float(np.max(np.abs(batched - d["fitness"]))),
        },
        "mean_fitness": {"qdax_batched": float(d["fitness"].mean()), "qdrl_batched": float(batched.mean())},
    }
    print(json.dumps(record))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("side", choices=["qdax", "qdrl"])
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--loop", type=int, default=4, help="policies rolled out one at a time")
    p.add_argument("--out", default="same_policies.npz", help="(qdax) where to write")
    p.add_argument("--qdax", default="same_policies.npz", help="(qdrl) what the qdax step wrote")
    args = p.parse_args()
    if args.side == "qdax":
        qdax_side(args.seed, args.loop, args.out)
    else:
        qdrl_side(args.qdax)


if __name__ == "__main__":
    main()
