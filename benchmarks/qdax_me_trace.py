"""QDax 0.5.0's MAP-Elites on halfcheetah_uni with every offspring recorded (the QDax side of
`me_swaps_vs_qdax.py`).

Runs in QDax's own virtual environment (see `qdax_pga_me.py` for its recipe):

    QDAX_VENV/bin/python benchmarks/qdax_me_trace.py --seed 0 --out /tmp/trace_0.npz

The run is `qdax_map_elites_brax.py`'s, same keys and settings (spring, episodes of 100
steps, 64x64 tanh MLP, lecun-uniform, deterministic start, batch 128, iso-line 0.005 /
0.05, CVT 1024 from 50,000 samples, 50 iterations), with the scan's body written out as
`MAPElites.scan_update` and `update` do it (one key split per iteration, then one for `ask`,
one for scoring, then `tell`), so that
it returns per iteration the offspring, their fitnesses and descriptors, and the
repertoire's fitnesses after insertion. The file also holds the centroids, the initial
population with its scores, the key of the start state and QDax's QD score per iteration.
`--check` also runs `MAPElites.scan_update` itself from the same state and asserts that its
final QD score is the traced run's (the trace is QDax's own run, not a re-implementation).
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np
from qdax_map_elites_brax import qdax_map_elites

EPISODE = 100
TASK = "halfcheetah_uni"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--iterations", type=int, default=50)
    p.add_argument("--cells", type=int, default=1024)
    p.add_argument("--cvt-samples", type=int, default=50_000)
    p.add_argument("--init", default=None,
                   help="npz of an initial population (w0..b2 with a leading batch axis) to start from "
                        "instead of QDax's own draw")
    p.add_argument("--check", action="store_true", help="also run QDax's scan_update and compare")
    p.add_argument("--rescore", metavar="TRACE", default=None,
                   help="instead of a run: score the offspring of `--iteration` of TRACE (a trace of this "
                        "seed) again, as one batch outside the run's scan and one policy at a time, and "
                        "write the scores to --out")
    p.add_argument("--iteration", type=int, default=-1, help="(with --rescore)")
    p.add_argument("--out", required=True)
    args = p.parse_args()

    from qdax.core.neuroevolution.networks.networks import MLP
    from qdax.tasks.brax import v2 as environments
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn

    # The keys of qdax_map_elites_brax.py, in the same order.
    key = jax.random.key(args.seed)
    key, env_key, init_key, cvt_key, me_key = jax.random.split(key, 5)
    env = environments.create(TASK, episode_length=EPISODE)
    net = MLP(layer_sizes=(64, 64, env.action_size), activation=jnp.tanh,
              kernel_init=jax.nn.initializers.lecun_uniform(), final_activation=jnp.tanh)
    scoring_fn = create_brax_scoring_fn(env, net, environments.descriptor_extractor[TASK], env_key,
                                        episode_length=EPISODE, deterministic=True)
    params = jax.vmap(net.init)(jax.random.split(init_key, args.batch), jnp.zeros((args.batch, env.observation_size)))
    if args.init is not None:
        d = np.load(args.init)
        params = {"params": {f"Dense_{j}": {"kernel": jnp.asarray(d[f"w{j}"]), "bias": jnp.asarray(d[f"b{j}"])}
                             for j in range(3)}}
    me, centroids = qdax_map_elites(env, TASK, scoring_fn, args.batch, EPISODE, args.cells, args.cvt_samples, cvt_key)
    offset = environments.reward_offset[TASK] * EPISODE
    if args.rescore is not None:
        _rescore(args, scoring_fn)
        return
    init_fit, init_desc = jax.jit(scoring_fn)(params, jax.random.split(me_key)[1])[:2]
    repertoire, emitter_state, init_metrics = jax.jit(me.init)(params, centroids, me_key)

    def body(carry, _):  # type: ignore[no-untyped-def]
        # MAPElites.scan_update then update, written out so that the offspring come back.
        rep, es, k = carry
        k, sub = jax.random.split(k)
        sub, ask_key = jax.random.split(sub)
        genotypes, extra_info = me.ask(rep, es, ask_key)
        sub, score_key = jax.random.split(sub)
        fit, desc, extra = scoring_fn(genotypes, score_key)
        rep, es, metrics = me.tell(genotypes=genotypes, fitnesses=fit, descriptors=desc, repertoire=rep,
                                   emitter_state=es, extra_scores=extra, extra_info=extra_info)
        return (rep, es, k), (genotypes, fit, desc, rep.fitnesses.reshape(-1), metrics["qd_score"])

    run = jax.jit(lambda r, e, k: jax.lax.scan(body, (r, e, k), None, length=args.iterations))
    (final, _, _), (offspring, fit, desc, rep_fit, qd) = run(repertoire, emitter_state, key)
    jax.block_until_ready(final)
    record = {"seed": args.seed, "qd_score": float(qd[-1]), "init_qd_score": float(init_metrics["qd_score"]),
              "coverage": float(jnp.mean(final.fitnesses > -jnp.inf))}
    if args.check:
        scan = jax.jit(lambda r, e, k: jax.lax.scan(me.scan_update, (r, e, k), None, length=args.iterations))
        _, metrics = scan(repertoire, emitter_state, key)
        record["scan_update_qd_score"] = float(metrics["qd_score"][-1])
        assert record["scan_update_qd_score"] == record["qd_score"], record

    def leaves(tree, prefix: str) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
        layers = tree["params"]
        out = {f"{prefix}w{j}": np.asarray(layers[f"Dense_{j}"]["kernel"]) for j in range(3)}
        out.update({f"{prefix}b{j}": np.asarray(layers[f"Dense_{j}"]["bias"]) for j in range(3)})
        return out

    np.savez(
        args.out,
        seed=args.seed,
        centroids=np.asarray(centroids),
        start_key=np.asarray(jax.random.key_data(jax.random.split(env_key)[1])),  # QDax's reset key
        init_fitness=np.asarray(init_fit).reshape(-1),
        init_descriptors=np.asarray(init_desc),
        init_rep_fitness=np.asarray(repertoire.fitnesses).reshape(-1),
        fitness=np.asarray(fit).reshape(args.iterations, -1),
        descriptors=np.asarray(desc),
        rep_fitness=np.asarray(rep_fit),
        qd_score=np.asarray(qd),
        qd_offset=offset,
        **leaves(params, "init_"),
        **leaves(offspring, "off_"),
    )
    print(json.dumps(record))


def _rescore(args, scoring_fn) -> None:  # type: ignore[no-untyped-def]
    """The same policies scored by QDax twice more: batched in a program of their own, and one at a time."""
    d = np.load(args.rescore)
    t = args.iteration
    params = {"params": {f"Dense_{j}": {"kernel": jnp.asarray(d[f"off_w{j}"][t]), "bias": jnp.asarray(d[f"off_b{j}"][t])}
                         for j in range(3)}}
    key = jax.random.key(0)  # deterministic scoring: the key is not used
    fit, desc = jax.jit(scoring_fn)(params, key)[:2]
    one = jax.jit(scoring_fn)
    fits, descs = [], []
    for i in range(jax.tree.leaves(params)[0].shape[0]):
        f, ds = one(jax.tree.map(lambda x, i=i: x[i : i + 1], params), key)[:2]
        fits.append(float(f.reshape(-1)[0]))
        descs.append(np.asarray(ds)[0])
    np.savez(args.out, scan_fitness=d["fitness"][t], scan_descriptors=d["descriptors"][t],
             batch_fitness=np.asarray(fit).reshape(-1), batch_descriptors=np.asarray(desc),
             one_fitness=np.asarray(fits), one_descriptors=np.stack(descs))
    print(json.dumps({"wrote": args.out, "iteration": t}))


if __name__ == "__main__":
    main()
