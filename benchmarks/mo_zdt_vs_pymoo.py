"""NSGA-II and SPEA2 on ZDT1 (or DTLZ2): qdrl against pymoo 0.6, same settings, alternating runs.

Settings (Deb et al. 2002): population 100, 25,000 evaluations (the first population
and 249 generations), SBX (crossover probability 0.9, eta 20, 0.5 per gene),
polynomial mutation (probability 1 / n per gene, eta 20). Each run writes one JSON
line as it finishes: the final population's front (objectives, minimisation as
pymoo states them) and its hypervolume, computed for both libraries by the same
code (`qdrl.qd.pareto.hypervolume_exact`, moocore) w.r.t. (1, 1) (ZDT1) or
(1, 1, 1) (DTLZ2), and the wall times.

qdrl: `qdrl.experiment.run` of an nsga2/spea2 spec in this process; `run_s` is the
compiled loop alone, `wall_s` includes building and compiling (with jax's
persistent compilation cache warm after the first run of a spec, as for a user's
second run), `process_s` includes importing jax and qdrl.
pymoo: `minimize(problem, NSGA2(...) / SPEA2(...), ("n_evals", 25000), seed)` in
pymoo's own virtual environment (`--pymoo-python`); `run_s` is `minimize` alone.
Its mutation is `PM(prob=1.0, eta=20)`: pymoo's default `prob=0.9` leaves 10% of the
children unmutated, below the papers' 1 / n per gene. `--crowding pruning` runs
NSGA-II with qdrl's `population.crowding = "pruning"` against pymoo's
`RankAndCrowding(crowding_func="pcd")`.

    python benchmarks/mo_zdt_vs_pymoo.py --pymoo-python /path/to/pymoo-venv/bin/python --seeds 5 \
        --out benchmarks/results/mo_zdt1_vs_pymoo.jsonl
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
PYMOO_PYTHON = "python3"  # --pymoo-python
POP, EVALS = 100, 25_000


def run_qdrl(algorithm: str, task: str, seed: int, redraws: int = 1, crowding: str = "distance") -> dict[str, object]:
    t_process = time.perf_counter()
    from qdrl.experiment import run

    generations = EVALS // POP - 1
    spec = {
        "experiment": {"algorithm": algorithm, "seed": seed, "name": f"{algorithm}_{task}"},
        "task": {"name": task},
        "population": {"size": POP, "crossover_eta": 20.0, "mutation_eta": 20.0, "crossover_prob": 0.9,
                       "redraws": redraws, **({"crowding": crowding} if algorithm == "nsga2" else {})},
        "qd": {"num_iterations": generations, "log_every": generations},
        "log": {"progress": False, "plots": False},
    }
    with tempfile.TemporaryDirectory() as tmp:
        summary = run(spec, Path(tmp) / "run", overwrite=True)
        front = -_read_front(Path(tmp) / "run" / "front.csv")  # back to minimisation
    return {
        "evaluations": summary["evaluations"],
        "front": front.tolist(),
        "run_s": summary["run_s"],
        "wall_s": summary["wall_s"],
        "compile_s": summary["compile_s"],
        "process_s": time.perf_counter() - t_process,
    }


def _read_front(path: Path):  # type: ignore[no-untyped-def]
    import numpy as np

    return np.atleast_2d(np.loadtxt(path, delimiter=",", skiprows=1))


PYMOO_CODE = r"""
import json, sys, time
t_process = time.perf_counter()
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.algorithms.moo.spea2 import SPEA2
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.pm import PM
from pymoo.optimize import minimize
from pymoo.problems import get_problem
algorithm, task, seed, pop, evals = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
crowding = sys.argv[6]
problem = get_problem(task) if task != "dtlz2" else get_problem("dtlz2", n_var=12, n_obj=3)
cls = NSGA2 if algorithm == "nsga2" else SPEA2
# PM(prob=1.0): pymoo mutates only 90% of the children by default (each gene then with
# probability 1/n); the papers and qdrl mutate every gene of every child with probability 1/n.
kw = {}
if algorithm == "nsga2" and crowding == "pruning":
    from pymoo.operators.survival.rank_and_crowding import RankAndCrowding
    kw["survival"] = RankAndCrowding(crowding_func="pcd")
algo = cls(pop_size=pop, crossover=SBX(prob=0.9, eta=20), mutation=PM(prob=1.0, eta=20), **kw)
t0 = time.perf_counter()
res = minimize(problem, algo, ("n_evals", evals), seed=seed, verbose=False)
run_s = time.perf_counter() - t0
import pymoo
pop_f = res.pop.get("F")
print(json.dumps({"evaluations": int(res.algorithm.evaluator.n_eval), "front": res.F.tolist(),
                  "population": pop_f.tolist(), "run_s": run_s, "wall_s": run_s,
                  "process_s": time.perf_counter() - t_process, "pymoo": pymoo.__version__}))
"""


def run_pymoo(algorithm: str, task: str, seed: int, crowding: str = "distance") -> dict[str, object]:
    out = subprocess.run(
        [PYMOO_PYTHON, "-c", PYMOO_CODE, algorithm, task, str(seed), str(POP), str(EVALS), crowding],
        capture_output=True, text=True, check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    global PYMOO_PYTHON, EVALS
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--task", default="zdt1")
    parser.add_argument("--algorithms", nargs="+", default=["nsga2", "spea2"])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--pymoo-python", default="python3", help="python of a virtual environment with pymoo 0.6")
    parser.add_argument("--evaluations", type=int, default=EVALS, help="evaluations per run (the papers': 25,000)")
    parser.add_argument("--redraws", type=int, default=1,
                        help="qdrl's population.redraws (children copying a parent; 1 is the default)")
    parser.add_argument("--crowding", choices=["distance", "pruning"], default="distance",
                        help="NSGA-II's cut of its last front: qdrl's population.crowding and pymoo's "
                        "RankAndCrowding(crowding_func='cd' or 'pcd')")
    parser.add_argument("--one", nargs=3, help=argparse.SUPPRESS)  # internal: qdrl ALGORITHM TASK SEED
    args = parser.parse_args()
    PYMOO_PYTHON, EVALS = args.pymoo_python, args.evaluations
    if args.one:
        algorithm, task, seed = args.one
        print(json.dumps(run_qdrl(algorithm, task, int(seed), args.redraws, args.crowding)))
        return
    import numpy as np

    from qdrl.qd.pareto import hypervolume_exact

    ref = [1.0, 1.0] if args.task != "dtlz2" else [1.0, 1.0, 1.0]
    env = {**os.environ, "PYTHONPATH": f"{REPO}:{os.environ.get('PYTHONPATH', '')}"}
    for seed in range(args.seeds):
        for algorithm in args.algorithms:
            for impl in ("qdrl", "pymoo"):  # alternating, one after the other
                if impl == "qdrl":
                    out = subprocess.run(
                        [sys.executable, __file__, "--out", str(args.out), "--evaluations", str(EVALS),
                         "--redraws", str(args.redraws), "--crowding", args.crowding,
                         "--one", algorithm, args.task, str(seed)],
                        capture_output=True, text=True, check=True, env=env,
                    )
                    result = json.loads(out.stdout.strip().splitlines()[-1])
                else:
                    result = run_pymoo(algorithm, args.task, seed, args.crowding)
                front = -np.asarray(result.pop("front"), np.float64)  # maximisation for qdrl's helper
                result.pop("population", None)
                row = {
                    "impl": impl, "algorithm": algorithm, "task": args.task, "seed": seed,
                    "hypervolume": hypervolume_exact(front, [-r for r in ref]),
                    "front_size": len(front), **result,
                    **({"redraws": args.redraws} if impl == "qdrl" else {}),
                    **({"crowding": args.crowding} if algorithm == "nsga2" else {}),
                }
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
                print(json.dumps({k: v for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
