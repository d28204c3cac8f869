"""Multi-task MAP-Elites against solving each task apart, on the parameterised arm (Mouret & Maguire 2020).

The paper's comparison: the same evaluations spent by Multi-task MAP-Elites on all tasks at
once, or split evenly between the tasks, each solved by its own CMA-ES (the authors'
benchmark_cma.py: pycma's defaults in 10-D, lambda = 10, sigma0 = 0.5 from x0 = 0.5, bounds
[0, 1], every task one generation in turn). Methods, all on the one set of tasks of the spec
(task.task_seed):

- mt_me: the spec (agents/mt_me_arm.toml), tournament sizes chosen by UCB1;
- mt_me_random_task: the same with tournament_sizes = [1], each child on a random task (the
  paper's "no distance" ablation);
- cma_es_per_task: one CMA-ES per task (qdrl's `CMAES`, Hansen's tutorial equations, vmapped
  over the tasks), budget / num_tasks evaluations each; out-of-bounds samples are ranked by
  the fitness of their clipped copy minus the squared distance to it (a fixed-weight
  stand-in for pycma's BoundPenalty) and scored as the clipped copy;
- random_search_per_task: budget / num_tasks uniform solutions per task;
- cma_es_per_task_x10 (by --methods only): the CMA-ES of each task with ten times the budget,
  an estimate of how good each task can get (the reference the others fall short of).

Prints JSON lines (method, seed, evaluations, mean fitness over the tasks that have a
solution, coverage, wall seconds) and writes them to benchmarks/results/mt_me_arm.jsonl;
the last lines summarise the final mean fitness of each method over the seeds.

    python benchmarks/mt_me_arm.py --seeds 3   # the paper's setting: about 2 min a run, 13 min in all on 2 cores
    python benchmarks/mt_me_arm.py --seeds 1 --methods cma_es_per_task_x10 --append   # the reference, 40 s
    python benchmarks/mt_me_arm.py --spec agents/mt_me_arm_cpu.toml --out /tmp/mt.jsonl

benchmarks/results/mt_me_arm.jsonl holds the first two commands' lines (CPU, 2 shared cores).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import pandas as pd

from qdrl.experiment import run_spec
from qdrl.qd.cma_es import CMAES
from qdrl.specs import load_spec
from qdrl.tasks.multi_task import multi_task_arm_fitness, multi_task_family

ROOT = Path(__file__).resolve().parents[1]
POINTS = 20  # rows per run written, evenly spaced in evaluations (and the last)


def _emit(row: dict[str, Any], rows: list[dict[str, Any]]) -> None:
    print(json.dumps(row), flush=True)
    rows.append(row)


def _thin(evaluations: list[int], budget: int) -> set[int]:
    """The indices of the rows closest after each of POINTS even fractions of the budget."""
    keep = {len(evaluations) - 1}
    for i in range(1, POINTS + 1):
        target = budget * i / POINTS
        keep.add(next((j for j, e in enumerate(evaluations) if e >= target), len(evaluations) - 1))
    return keep


def run_mt_me(spec: Path, seed: int, method: str, overrides: list[str], rows: list[dict[str, Any]]) -> None:
    """One run of the spec through the driver; its metrics.csv thinned to rows."""
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        summary = run_spec(
            spec, [f"experiment.seed={seed}", "log.progress=false", "log.plots=false", *overrides], out,
            overwrite=True,
        )
        wall = time.perf_counter() - start
        table = pd.read_csv(Path(out) / "metrics.csv")
    evaluations = [int(e) for e in table["evaluations"]]
    for i in sorted(_thin(evaluations, evaluations[-1])):
        r = table.iloc[i]
        _emit({
            "method": method, "seed": seed, "evaluations": int(r["evaluations"]),
            "mean_fitness": float(r["mean_fitness"]), "coverage": float(r["coverage"]),
            "tournament_size": int(r["tournament_size"]),
        }, rows)
    rows[-1].update(wall_s=round(wall, 1), compile_s=round(float(summary["compile_s"]), 1))
    print(json.dumps({"method": method, "seed": seed, "wall_s": rows[-1]["wall_s"]}), flush=True)


def _per_task_search(
    spec: dict[str, Any], seed: int, method: str, rows: list[dict[str, Any]], budget_factor: int = 1
) -> None:
    """One CMA-ES, or random search, per task with budget_factor x budget / num_tasks evaluations each."""
    task = spec["task"]
    family = multi_task_family(int(task["num_tasks"]), int(task.get("task_seed", 0)),
                               int(task["cvt_samples"]), int(task.get("kmeans_iters", 50)))
    params = jnp.asarray(family.parameters())
    num_tasks, dims = params.shape[0], int(task["num_dofs"])
    budget = int(spec["qd"]["init_batch_size"]) + int(spec["qd"]["num_iterations"]) * int(spec["mt_me"]["batch_size"])
    budget *= budget_factor
    cma = CMAES(dims, sigma0=0.5, update_rule="tutorial")
    lam = cma.lam
    generations = budget // num_tasks // lam
    score = jax.vmap(jax.vmap(multi_task_arm_fitness, in_axes=(0, None)))  # (T, lam, d), (T, P) -> (T, lam)

    def cma_generation(carry: Any, key: jax.Array) -> tuple[Any, jax.Array]:
        states, best = carry
        xs = jax.vmap(cma.sample)(states, jax.random.split(key, num_tasks))  # (T, lam, d)
        clipped = jnp.clip(xs, 0.0, 1.0)
        fitness = score(clipped, params)
        penalised = fitness - jnp.sum(jnp.square(xs - clipped), axis=-1)
        order = jnp.argsort(-penalised, axis=1)
        ranked = jnp.take_along_axis(xs, order[..., None], axis=1)
        states = jax.vmap(cma.update, in_axes=(0, 0, None))(states, ranked, lam // 2)
        best = jnp.maximum(best, jnp.max(fitness, axis=1))
        return (states, best), jnp.mean(best)

    def random_generation(best: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        xs = jax.random.uniform(key, (num_tasks, lam, dims))
        best = jnp.maximum(best, jnp.max(score(xs, params), axis=1))
        return best, jnp.mean(best)

    @jax.jit
    def search(key: jax.Array) -> jax.Array:
        keys = jax.random.split(key, generations)
        best = jnp.full((num_tasks,), -jnp.inf)
        if method.startswith("cma_es_per_task"):
            states = jax.vmap(lambda _: cma.init(jnp.full((dims,), 0.5)))(jnp.arange(num_tasks))
            _, means = jax.lax.scan(cma_generation, (states, best), keys)
        else:
            _, means = jax.lax.scan(random_generation, best, keys)
        return means

    start = time.perf_counter()
    means = jax.device_get(search(jax.random.PRNGKey(seed)))
    wall = time.perf_counter() - start
    evaluations = [(g + 1) * lam * num_tasks for g in range(generations)]
    for i in sorted(_thin(evaluations, evaluations[-1])):
        _emit({"method": method, "seed": seed, "evaluations": evaluations[i],
               "mean_fitness": float(means[i]), "coverage": 1.0}, rows)
    rows[-1].update(wall_s=round(wall, 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=Path, default=ROOT / "agents" / "mt_me_arm.toml")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "mt_me_arm.jsonl")
    parser.add_argument("--methods", default="mt_me,mt_me_random_task,cma_es_per_task,random_search_per_task")
    parser.add_argument("--plot", type=Path, default=None, help="also draw mean fitness against evaluations here")
    parser.add_argument("--replot", action="store_true", help="only draw --plot from the rows of --out")
    parser.add_argument("--append", action="store_true", help="add the rows to --out instead of replacing it")
    args = parser.parse_args()
    if args.replot:
        plot([json.loads(line) for line in args.out.read_text().splitlines()], args.plot)
        return
    spec = load_spec(args.spec)
    rows: list[dict[str, Any]] = []
    for method in args.methods.split(","):
        for seed in range(args.seeds):
            if method == "mt_me":
                run_mt_me(args.spec, seed, method, [], rows)
            elif method == "mt_me_random_task":
                run_mt_me(args.spec, seed, method, ["mt_me.tournament_sizes=[1]"], rows)
            elif method == "cma_es_per_task_x10":  # ten times the budget: near each task's optimum
                _per_task_search(spec, seed, method, rows, budget_factor=10)
            else:
                _per_task_search(spec, seed, method, rows)
    runs = list(rows)
    for method in dict.fromkeys(r["method"] for r in runs):
        last = max(r["evaluations"] for r in runs if r["method"] == method)
        finals = [r["mean_fitness"] for r in runs if r["method"] == method and r["evaluations"] == last]
        _emit({
            "summary": method, "spec": args.spec.name, "evaluations": last, "seeds": len(finals),
            "mean_fitness": statistics.fmean(finals),
            "std": statistics.stdev(finals) if len(finals) > 1 else 0.0,
            "device": jax.devices()[0].device_kind,
        }, rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    before = args.out.read_text() if args.append and args.out.exists() else ""
    args.out.write_text(before + "".join(json.dumps(r) + "\n" for r in rows))
    if args.plot is not None:
        plot([json.loads(line) for line in args.out.read_text().splitlines()], args.plot)


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Mean fitness over the tasks against evaluations: each method's median over seeds, and its range."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    runs = [r for r in rows if "method" in r]
    for method in dict.fromkeys(r["method"] for r in runs):
        points = sorted({r["evaluations"] for r in runs if r["method"] == method})
        values = [[r["mean_fitness"] for r in runs if r["method"] == method and r["evaluations"] == e] for e in points]
        if method.endswith("_x10"):  # a reference level, not a curve over this budget
            ax.axhline(statistics.median(values[-1]), color="grey", linestyle="--", label=f"{method} (final)")
            continue
        ax.plot(points, [statistics.median(v) for v in values], label=method)
        ax.fill_between(points, [min(v) for v in values], [max(v) for v in values], alpha=0.2)
    ax.set_xlabel("evaluations")
    ax.set_ylabel("mean fitness over the tasks")
    ax.set_title("parameterised arm: 10 joints, one elite per task")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
