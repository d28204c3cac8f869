"""Several seeds of MAP-Elites on the arm: one after the other, or vmapped in one compiled chunk.

`qdrl run SPEC --seeds 0-4` had to choose between the two. Both modes run in one
process with a warm persistent compilation cache: "seq" compiles each seed's chunk
(cache hits after the first) and runs the seeds one after the other; "vmap" stacks
the seeds' states and runs `jax.vmap(me.run)` once per log point. Prints one JSON
line (init, compile and run seconds; each seed's final QD score).

    python benchmarks/seeds_sequential_vs_vmap.py SEEDS ITERATIONS seq|vmap

Run the two modes alternately (the machine's load drifts); results in
benchmarks/results/seeds_sequential_vs_vmap.jsonl.
"""

from __future__ import annotations

import json
import sys
import time

import jax
import jax.numpy as jnp

from qdrl.experiment import build_run, compile_chunk, initial_state, load_spec, run_chunk


def main(num_seeds: int, iterations: int, mode: str, log_every: int = 50) -> dict[str, object]:
    spec = load_spec("agents/map_elites_arm.toml", [f"qd.num_iterations={iterations}", f"qd.log_every={log_every}"])
    t0 = time.perf_counter()
    runs = []
    for seed in range(num_seeds):
        spec["experiment"]["seed"] = seed
        runs.append(build_run(spec)[0])
    states = [initial_state(r, s) for s, r in enumerate(runs)]
    jax.block_until_ready(states)
    init_s = time.perf_counter() - t0
    chunks = iterations // log_every
    if mode == "vmap":
        stacked = jax.tree.map(lambda *x: jnp.stack(x), *states)
        t0 = time.perf_counter()
        chunk = jax.jit(jax.vmap(runs[0].chunk), donate_argnums=0).lower(stacked).compile()
        compile_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in range(chunks):
            stacked, metrics = chunk(stacked)
            jax.device_get(metrics)  # a log point reads its metrics
        run_s = time.perf_counter() - t0
        qd = [float(x) for x in metrics["qd_score"][:, -1]]
    else:
        compile_s, run_s, qd = 0.0, 0.0, []
        for r, state in zip(runs, states, strict=True):
            compiled = compile_chunk(r, state)
            compile_s += compiled.seconds
            t0 = time.perf_counter()
            for _ in range(chunks):
                state, metrics = run_chunk(r, compiled.fn, state)
                jax.device_get(metrics)
            run_s += time.perf_counter() - t0
            qd.append(float(metrics["qd_score"][-1]))
    return {"mode": mode, "seeds": num_seeds, "iterations": iterations, "init_s": round(init_s, 2),
            "compile_s": round(compile_s, 2), "run_s": round(run_s, 2), "qd_score": qd}


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3])))
