"""MOME on QDax's multi-objective rastrigin: qdrl against QDax 0.5.0's MOME, alternating runs.

QDax's example settings (its MOME notebook): 100 genes in [-2, 4], objectives
-rastrigin(x) and -rastrigin(x - 2.2), descriptors the first two genes, 64 CVT cells
(20,000 k-means samples), fronts of up to 50, 100 offspring per iteration all made by
polynomial crossover (half the genes), 1000 iterations after a first batch of 100:
100,100 evaluations each. Both loops compute their MOQD metrics every iteration (as
each library does by default) and log every 100 iterations.

qdrl runs `agents/mome_mo_rastrigin.toml` through `qdrl.experiment.run` (overflow
"crowding", its default, and "index", QDax's rule); QDax runs in its own virtual environment (`--qdax-python`).
The final repertoires' fitnesses (64, 50, 2) of both are scored by the same code
(`qdrl.qd.pareto.hypervolume_exact`, moocore): MOQD score (sum of the cells'
hypervolumes) and global hypervolume, w.r.t. QDax's reference (-150, -150), which no
solution of 100 genes reaches (so both are 0 for every run), and w.r.t. (-1500, -1500).
Each run writes one JSON line as it finishes and saves its final fitnesses (.npy
beside the results).

    python benchmarks/mome_rastrigin_vs_qdax.py --seeds 3 --out benchmarks/results/mome_rastrigin_vs_qdax.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# QDax's reference point, and one the runs reach: with 100 genes no solution gets above
# (-150, -150) (per gene, rastrigin(x) + rastrigin(x - 2.2) >= 6.24, so f1 + f2 <= -624), so
# every MOQD score and hypervolume w.r.t. it is 0; (-1500, -1500) is 15 below the optimum per gene.
REFERENCES = {"qdax": (-150.0, -150.0), "reachable": (-1500.0, -1500.0)}

QDAX_CODE = r"""
import functools, json, sys, time
t_process = time.perf_counter()
import jax, jax.numpy as jnp
from qdax.core.containers.mapelites_repertoire import compute_cvt_centroids
from qdax.core.emitters.mutation_operators import polynomial_crossover, polynomial_mutation
from qdax.core.emitters.standard_emitters import MixingEmitter
from qdax.core.mome import MOME
from qdax.utils.metrics import default_moqd_metrics

seed, iterations, log_every = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
num_variables, minval, maxval, batch_size, lag = 100, -2.0, 4.0, 100, 2.2

def rastrigin_scorer(genotypes, base_lag, lag):
    x = jnp.stack([genotypes - base_lag, genotypes - lag], axis=-1)
    return -(10 * x.shape[1] + jnp.sum(x**2 - 10 * jnp.cos(2 * jnp.pi * x), axis=1))

def scoring_function(genotypes, key):
    return rastrigin_scorer(genotypes, 0.0, lag), genotypes[:, :2], {}

crossover = functools.partial(polynomial_crossover, proportion_var_to_change=0.5)
mutation = functools.partial(polynomial_mutation, proportion_to_mutate=0.6, eta=1.0, minval=minval, maxval=maxval)
emitter = MixingEmitter(mutation_fn=mutation, variation_fn=crossover, variation_percentage=1.0, batch_size=batch_size)
metrics_fn = functools.partial(default_moqd_metrics, reference_point=jnp.array([-150.0, -150.0]))
mome = MOME(scoring_function=scoring_function, emitter=emitter, metrics_function=metrics_fn, pareto_front_max_length=50)

key = jax.random.key(seed)
key, k1, k2, k3 = jax.random.split(key, 4)
centroids = compute_cvt_centroids(num_descriptors=2, num_init_cvt_samples=20000, num_centroids=64, minval=minval, maxval=maxval, key=k1)
init = jax.random.uniform(k2, (batch_size, num_variables), minval=minval, maxval=maxval)
t0 = time.perf_counter()
repertoire, emitter_state, _ = jax.jit(mome.init)(init, centroids, k3)

def chunk(carry):
    return jax.lax.scan(mome.scan_update, carry, None, length=log_every)

run = jax.jit(chunk).lower((repertoire, emitter_state, key)).compile()
compile_s = time.perf_counter() - t0
carry = (repertoire, emitter_state, key)
t0 = time.perf_counter()
for _ in range(iterations // log_every):
    carry, metrics = run(carry)
    jax.block_until_ready(carry)
run_s = time.perf_counter() - t0
fit = jax.device_get(carry[0].fitnesses)
print(json.dumps({"fitnesses": fit.tolist(), "run_s": run_s, "compile_s": compile_s,
                  "wall_s": run_s + compile_s, "process_s": time.perf_counter() - t_process,
                  "evaluations": batch_size * (iterations + 1)}))
"""


def run_qdrl(seed: int, overflow: str) -> dict[str, object]:
    t_process = time.perf_counter()
    import numpy as np

    from qdrl.experiment import load_spec, run

    spec = load_spec(
        REPO / "agents" / "mome_mo_rastrigin.toml",
        [f"experiment.seed={seed}", f'mome.overflow="{overflow}"', "log.progress=false", "log.plots=false"],
    )
    with tempfile.TemporaryDirectory() as tmp:
        summary = run(spec, Path(tmp) / "run", overwrite=True)
        fit = np.load(Path(tmp) / "run" / "repertoire.npz")["fitnesses"]
    return {
        "fitnesses": fit.tolist(),
        "run_s": summary["run_s"],
        "compile_s": summary["compile_s"],
        "wall_s": summary["wall_s"],
        "process_s": time.perf_counter() - t_process,
        "evaluations": summary["evaluations"],
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--qdax-python", help="python of a virtual environment with QDax 0.5.0")
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)  # internal: SEED OVERFLOW
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_qdrl(int(args.one[0]), args.one[1])))
        return
    if args.qdax_python is None:
        parser.error("--qdax-python is required (the python of QDax 0.5.0's virtual environment)")
    import numpy as np

    from qdrl.qd.pareto import hypervolume_exact

    env = {**os.environ, "PYTHONPATH": f"{REPO}:{os.environ.get('PYTHONPATH', '')}"}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for impl in ("qdrl", "qdax", "qdrl_index"):  # alternating
            if impl == "qdax":
                cmd = [args.qdax_python, "-c", QDAX_CODE, str(seed), str(args.iterations), "100"]
                qdax_env = {k: v for k, v in env.items() if k != "PYTHONPATH"}
                out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=qdax_env)
            else:
                overflow = "index" if impl == "qdrl_index" else "crowding"
                cmd = [sys.executable, __file__, "--out", str(args.out), "--one", str(seed), overflow]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
            result = json.loads(out.stdout.strip().splitlines()[-1])
            fit = np.asarray(result.pop("fitnesses"), np.float64)  # (64, 50, 2), -inf where empty
            np.save(args.out.with_name(f"{args.out.stem}_{impl}_seed{seed}.npy"), fit.astype(np.float32))
            filled = np.any(np.all(np.isfinite(fit), axis=-1), axis=-1)
            scores = {}
            for name, ref in REFERENCES.items():
                cells = [hypervolume_exact(front, ref) for front in fit]
                scores[f"moqd_score_{name}"] = float(np.sum(cells))
                scores[f"global_hypervolume_{name}"] = hypervolume_exact(fit.reshape(-1, 2), ref)
            row = {
                "impl": impl, "seed": seed, **scores,
                "max_objective": np.max(fit.reshape(-1, 2), axis=0).tolist(),
                "coverage": float(filled.mean()),
                "num_solutions": int(np.all(np.isfinite(fit), axis=-1).sum()),
                **result,
            }
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
