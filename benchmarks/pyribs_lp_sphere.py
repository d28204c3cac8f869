"""The same LP-sphere runs with pyribs itself, to check qdrl's CMA-ME / CMA-MAE against the reference.

Runs in its own venv (pyribs is no qdrl dependency):

    python3.11 -m venv /work/venvs/ribs && /work/venvs/ribs/bin/pip install "ribs==0.12.*"
    /work/venvs/ribs/bin/python benchmarks/pyribs_lp_sphere.py --algo cma_me --budget 600 \
        --out benchmarks/results/cma_lp_sphere_pyribs.jsonl

Settings of `benchmarks/cma_lp_sphere.py` (and pyribs' `examples/sphere.py`): LP
sphere 100-D, 100 x 100 grid over [-256, 256]^2, 15 emitters of 36, sigma0 0.5, x0
= 0; `cma_me` is `2imp` / mu / basic, `cma_me_filter` `2imp` / filter /
no_improvement, `cma_mae` `imp` / mu / basic with learning rate 0.01 and
threshold_min 0 (and an elitist result archive for the metrics). One JSON line
per run, with the normalised QD score every `--log-every` iterations.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from ribs.archives import GridArchive
from ribs.emitters import EvolutionStrategyEmitter
from ribs.schedulers import Scheduler

OPTIONS = {
    "cma_me": {"ranker": "2imp", "selection_rule": "mu", "restart_rule": "basic"},
    "cma_me_filter": {"ranker": "2imp", "selection_rule": "filter", "restart_rule": "no_improvement"},
    "cma_mae": {"ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"},
}


def sphere(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """pyribs' LP sphere: objective in [0, 100] and the sums of the clipped halves."""
    dim = x.shape[1]
    shift = 0.4 * 5.12
    worst = (-5.12 - shift) ** 2 * dim
    objective = (np.sum(np.square(x - shift), axis=1) - worst) / (0.0 - worst) * 100
    clipped = x.copy()
    outside = (clipped < -5.12) | (clipped > 5.12)
    clipped[outside] = 5.12 / clipped[outside]
    measures = np.stack([clipped[:, : dim // 2].sum(1), clipped[:, dim // 2 :].sum(1)], axis=1)
    return objective, measures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", required=True, choices=sorted(OPTIONS))
    parser.add_argument("--budget", type=float, default=600.0)
    parser.add_argument("--max-iterations", type=int, default=10_000)
    parser.add_argument("--log-every", type=int, default=250)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    dim, bound = 100, 100 / 2 * 5.12
    ranges = [(-bound, bound)] * 2
    extra = {"learning_rate": 0.01, "threshold_min": 0.0} if args.algo == "cma_mae" else {}
    archive = GridArchive(solution_dim=dim, dims=(100, 100), ranges=ranges, seed=args.seed, **extra)
    result_archive = (
        GridArchive(solution_dim=dim, dims=(100, 100), ranges=ranges, seed=args.seed)
        if args.algo == "cma_mae" else None
    )
    seeds = np.random.SeedSequence(args.seed).spawn(15)
    emitters = [
        EvolutionStrategyEmitter(archive, x0=np.zeros(dim), sigma0=0.5, batch_size=36, seed=s,
                                 **OPTIONS[args.algo])
        for s in seeds
    ]
    scheduler = Scheduler(archive, emitters, result_archive=result_archive)
    metrics_archive = scheduler.result_archive
    curve = []
    running, itr = 0.0, 0
    while running < args.budget and itr < args.max_iterations:
        t0 = time.perf_counter()
        solutions = scheduler.ask()
        objective, measures = sphere(solutions)
        scheduler.tell(objective, measures)
        running += time.perf_counter() - t0
        itr += 1
        if itr % args.log_every == 0:
            stats = metrics_archive.stats
            point = {
                "iteration": itr,
                "wall_s": round(running, 2),
                "normalised_qd_score": float(stats.qd_score) / 10_000,
                "coverage": float(stats.coverage),
            }
            curve.append(point)
            print(json.dumps(point), flush=True)
    result = {
        "algo": args.algo,
        "library": "pyribs 0.12",
        "seed": args.seed,
        "iterations": itr,
        "s_per_iteration": running / max(itr, 1),
        "final": curve[-1] if curve else None,
        "curve": curve,
    }
    if args.out is not None:
        with args.out.open("a") as f:
            f.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
