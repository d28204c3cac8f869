"""The same LP-sphere runs with pyribs itself, to check qdrl's CMA family against the reference.

Runs in its own venv (pyribs is no qdrl dependency):

    python3.11 -m venv ribs-venv && ribs-venv/bin/pip install "ribs==0.12.*"
    ribs-venv/bin/python benchmarks/pyribs_lp_sphere.py --algo cma_me --budget 600 \
        --out benchmarks/results/cma_lp_sphere_pyribs.jsonl

Settings of `benchmarks/cma_lp_sphere.py` and the specs in agents/ (and pyribs'
`examples/sphere.py`): LP sphere, 100 x 100 grid over [-n/2 5.12, n/2 5.12]^2,
x0 = 0. `cma_me` is `2imp` / mu / basic, `cma_me_filter` `2imp` / filter /
no_improvement, `cma_mae` `imp` / mu / basic with learning rate 0.01 and
threshold_min 0 (and an elitist result archive for the metrics): 15 emitters of
36, sigma0 0.5, 100-D. `cma_mega`: the DQD paper's CMA-MEGA, one
GradientArborescenceEmitter of 35 + theta, sigma_g 10, gradient ascent at 1.0,
mu selection, 1000-D (`--dims`). One JSON line per run, with the normalised QD
score every `--log-every` iterations.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from ribs.archives import DensityArchive, DiscountArchive, DNSArchive, GridArchive, ProximityArchive
from ribs.emitters import EvolutionStrategyEmitter, GradientArborescenceEmitter, IsoLineEmitter
from ribs.schedulers import Scheduler

OPTIONS = {
    "cma_me": {"ranker": "2imp", "selection_rule": "mu", "restart_rule": "basic"},
    "cma_me_filter": {"ranker": "2imp", "selection_rule": "filter", "restart_rule": "no_improvement"},
    "cma_mae": {"ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"},
    "cma_mega": {"ranker": "2imp", "selection_rule": "mu", "restart_rule": "no_improvement"},
}
DEFAULT_DIMS = {"cma_mega": 1000}
# The novelty, density and discount-model family, as pyribs 0.12's examples/sphere.py configures
# it (ns_cma, nslc, nslc_cma_imp, dds, dms); dns: Dominated Novelty Search (a population of 1024,
# k = 3, QDax's example) with 15 iso-line emitters of 36 (pyribs' line_map_elites emitters).
SEARCH = {
    "ns_cma": {"ranker": "nov", "selection_rule": "mu", "restart_rule": "basic", "sigma0": 0.5},
    "nslc": {"ranker": "nslc", "selection_rule": "filter", "restart_rule": "no_improvement", "sigma0": 0.5},
    "nslc_cma_imp": {"ranker": "2imp", "selection_rule": "filter", "restart_rule": "no_improvement", "sigma0": 0.5},
    "dds": {"ranker": "density", "selection_rule": "mu", "restart_rule": "basic", "sigma0": 1.5},
    "dms": {"ranker": "imp", "selection_rule": "mu", "restart_rule": "basic", "sigma0": 0.5},
    "dns": {},
}


def search_archive(algo: str, dim: int, ranges: list[tuple[float, float]], result: GridArchive, seed: int):  # type: ignore[no-untyped-def]
    """pyribs' archive of a SEARCH algorithm, and whether emitters read the result archive."""
    if algo == "ns_cma":
        return ProximityArchive(solution_dim=dim, measure_dim=2, k_neighbors=15, novelty_threshold=0.037 * 512,
                                seed=seed), False
    if algo in ("nslc", "nslc_cma_imp"):
        return ProximityArchive(solution_dim=dim, measure_dim=2, k_neighbors=15, novelty_threshold=0.037 * 100,
                                local_competition=True, seed=seed), False
    if algo == "dds":
        return DensityArchive(measure_dim=2, buffer_size=10_000, density_method="kde", bandwidth=25.6,
                              seed=seed), True
    if algo == "dns":
        return DNSArchive(solution_dim=dim, measure_dim=2, capacity=1024, k_neighbors=3, seed=seed), False
    import torch  # DMS only
    from ribs.discount_models import MLP, DiscountModelManager

    torch.manual_seed(seed)
    model = MLP(layer_specs=[[2, 128], [128, 128], [128, 1]], activation=torch.nn.ReLU)
    manager = DiscountModelManager(
        model=model, optimizer=torch.optim.Adam(model.parameters(), lr=0.001, betas=(0.9, 0.999)),
        device=torch.device("cpu"), measures_low=[r[0] for r in ranges], measures_high=[r[1] for r in ranges],
        discount_low=0.0, discount_high=100.0, train_epochs=5, train_cutoff_loss=0.05, train_batch_size=32,
        normalize_measures="negative_one_one", normalize_discount="zero_one",
    )
    archive = DiscountArchive(solution_dim=dim, measure_dim=2, learning_rate=0.1, threshold_min=0.0,
                              discount_model_manager=manager, result_archive=result, init_train_points=1000,
                              empty_points=100, seed=seed)
    archive.init_discount_model()
    return archive, True


def sphere(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """pyribs' LP sphere: objective in [0, 100] and the sums of the clipped halves."""
    objective, _, measures, _ = sphere_with_gradients(x)
    return objective, measures


def sphere_with_gradients(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """pyribs' examples/sphere.py `sphere`: objective, its gradient, measures, their Jacobian."""
    dim = x.shape[1]
    shift = 0.4 * 5.12
    worst = (-5.12 - shift) ** 2 * dim
    objective = (np.sum(np.square(x - shift), axis=1) - worst) / (0.0 - worst) * 100
    objective_grad = -2 * (x - shift)  # as pyribs' example: the gradient's direction, unscaled
    clipped = x.copy()
    outside = (clipped < -5.12) | (clipped > 5.12)
    clipped[outside] = 5.12 / clipped[outside]
    measures = np.stack([clipped[:, : dim // 2].sum(1), clipped[:, dim // 2 :].sum(1)], axis=1)
    derivatives = np.ones(x.shape)
    derivatives[outside] = -5.12 / np.square(x[outside])
    first = np.arange(dim) < dim // 2
    measure_grads = np.stack([derivatives * first, derivatives * ~first], axis=1)
    return objective, objective_grad, measures, measure_grads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", required=True, choices=sorted({*OPTIONS, *SEARCH}))
    parser.add_argument("--budget", type=float, default=600.0)
    parser.add_argument("--max-iterations", type=int, default=10_000)
    parser.add_argument("--log-every", type=int, default=250)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dims", type=int, default=None, help="default: 100 (cma_mega: 1000)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    dim = args.dims or DEFAULT_DIMS.get(args.algo, 100)
    bound = dim / 2 * 5.12
    ranges = [(-bound, bound)] * 2
    extra = {"learning_rate": 0.01, "threshold_min": 0.0} if args.algo == "cma_mae" else {}
    archive = GridArchive(solution_dim=dim, dims=(100, 100), ranges=ranges, seed=args.seed, **extra)
    result_archive = (
        GridArchive(solution_dim=dim, dims=(100, 100), ranges=ranges, seed=args.seed)
        if args.algo == "cma_mae" else None
    )
    dqd = args.algo == "cma_mega"
    if args.algo in SEARCH:
        result_archive = GridArchive(solution_dim=dim, dims=(100, 100), ranges=ranges, seed=args.seed)
        archive, emit_from_result = search_archive(args.algo, dim, ranges, result_archive, args.seed)
        seeds = np.random.SeedSequence(args.seed).spawn(15)
        source = result_archive if emit_from_result else archive
        if args.algo == "dns":
            emitters = [IsoLineEmitter(source, x0=np.zeros(dim), iso_sigma=0.5, line_sigma=0.2, batch_size=36,
                                       seed=s) for s in seeds]
        else:
            emitters = [EvolutionStrategyEmitter(source, x0=np.zeros(dim), batch_size=36, seed=s,
                                                 **SEARCH[args.algo]) for s in seeds]
    elif dqd:
        seed = np.random.SeedSequence(args.seed).generate_state(1)[0]
        emitters = [GradientArborescenceEmitter(
            archive, x0=np.zeros(dim), sigma0=10.0, lr=1.0, grad_opt="gradient_ascent", batch_size=35,
            seed=int(seed), **OPTIONS[args.algo])]
    else:
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
        if dqd:
            solutions = scheduler.ask_dqd()
            objective, objective_grad, measures, measure_grads = sphere_with_gradients(solutions)
            jacobian = np.concatenate([objective_grad[:, None, :], measure_grads], axis=1)
            scheduler.tell_dqd(objective, measures, jacobian)
        solutions = scheduler.ask()
        objective, measures = sphere(solutions)
        scheduler.tell(objective, measures)
        if args.algo == "dms":
            archive.train_discount_model()
        running += time.perf_counter() - t0
        itr += 1
        if itr % args.log_every == 0:
            stats = metrics_archive.stats
            point = {
                "iteration": itr,
                "wall_s": round(running, 2),
                "normalised_qd_score": float(stats.qd_score) / 10_000,
                "coverage": float(stats.coverage),
                **({"search_size": len(archive)} if args.algo in SEARCH and args.algo not in ("dds", "dms") else {}),
            }
            curve.append(point)
            print(json.dumps(point), flush=True)
    result = {
        "algo": args.algo,
        "library": "pyribs 0.12",
        "seed": args.seed,
        "iterations": itr,
        "dims": dim,
        "s_per_iteration": running / max(itr, 1),
        "final": curve[-1] if curve else None,
        "curve": curve,
    }
    if args.out is not None:
        with args.out.open("a") as f:
            f.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
