"""MOME on halfcheetah_multi against MAP-Elites on the forward reward alone, same budget (CPU).

MOME runs `agents/mome_halfcheetah_multi_cpu.toml` (episodes of 100 steps, 64 CVT
cells with fronts of up to 10 policies, 64 offspring per iteration by iso-line
variation, 150 iterations: 9,664 evaluations). MAP-Elites runs on the same cells
(the same k-means key), the same emitter, first population and number of
iterations, with the forward reward (objective 0 of the same evaluation) as its
fitness. Its elites are then scored on both objectives by the task's own
(deterministic, fixed-start) evaluation, and the two global fronts are compared:
hypervolume w.r.t. the task's reference point, and the energy of each front's
most frugal solution that still moves forward. Writes one JSON line per seed and
a plot of both fronts.

    python benchmarks/mome_halfcheetah_vs_map_elites.py --seeds 1 --out benchmarks/results/mome_halfcheetah_vs_map_elites.jsonl
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "agents" / "mome_halfcheetah_multi_cpu.toml"


def _front(points: np.ndarray) -> np.ndarray:
    import moocore

    points = points[np.all(np.isfinite(points), axis=1)]
    return points[moocore.is_nondominated(points, maximise=True, keep_weakly=True)]


def _summary(front: np.ndarray, reference: tuple[float, ...]) -> dict[str, Any]:
    from qdrl.qd.pareto import hypervolume_exact

    forward = front[:, 0] > 0
    return {
        "hypervolume": hypervolume_exact(front, reference),
        "front_size": len(front),
        "max_forward": float(front[:, 0].max()),
        "max_energy_objective": float(front[:, 1].max()),  # the least energy (objective = -cost)
        "least_energy_moving_forward": float(front[forward, 1].max()) if forward.any() else None,
        "front": front.tolist(),
    }


def run_map_elites(run_: Any, seed: int) -> tuple[np.ndarray, float]:
    """MAP-Elites on objective 0; returns the (k, 2) objectives of its elites and its run time."""
    from qdrl.algorithms.qd import make_repertoire
    from qdrl.qd.base import Evaluation
    from qdrl.qd.emitters.ga import isoline_emitter
    from qdrl.qd.map_elites import MapElites

    task, ec, qd = run_.qd.task, run_.sections["emitter"], run_.sections["qd"]

    def forward_only(genotypes: Any, key: jax.Array) -> Evaluation:
        e = task.scoring_fn(genotypes, key)
        return e._replace(fitnesses=e.fitnesses[:, 0])

    _, init_key, run_key = jax.random.split(jax.random.PRNGKey(seed), 3)  # as the QD recipe's
    # The cells of MOME's repertoire (k-means seeded by the seed, as the recipe's), one elite each.
    cells = make_repertoire(run_.sections["repertoire"], task, task.example_genotype(), seed)
    emitter = isoline_emitter(ec.batch_size, ec.iso_sigma, ec.line_sigma)
    me = MapElites(forward_only, emitter, cells)
    state = jax.jit(me.init)(task.init_genotypes(init_key, qd.init_batch_size), run_key)
    chunk = jax.jit(lambda s: me.run(s, qd.log_every))
    t0 = time.perf_counter()
    for _ in range(qd.num_iterations // qd.log_every):
        state, _ = chunk(state)
    jax.block_until_ready(state)
    run_s = time.perf_counter() - t0
    rep = jax.device_get(state.repertoire)
    filled = np.flatnonzero(np.isfinite(rep.fitnesses))
    width = ec.batch_size  # the task's eval_batch: the same blocks as during the run
    scored = []
    score = jax.jit(task.scoring_fn)
    for start in range(0, len(filled), width):
        idx = filled[start : start + width]
        idx = np.concatenate([idx, np.full(width - len(idx), idx[0])])
        g = jax.tree.map(lambda x, i=idx: x[i], rep.genotypes)
        scored.append(np.asarray(score(g, jax.random.PRNGKey(0)).fitnesses)[: min(width, len(filled) - start)])
    objectives = np.concatenate(scored)
    # the forward reward found during the run is what the re-scoring gives (deterministic)
    np.testing.assert_allclose(objectives[:, 0], rep.fitnesses[filled], rtol=1e-4, atol=1e-3)
    return objectives, run_s


def plot_fronts(rows: list[dict[str, Any]], seed: int, path: str | Path) -> Path:
    """Draws both global fronts of `seed`'s row (its last in `rows`, this script's JSON lines) with
    the reference point and writes it to `path`."""
    from qdrl import plotting

    row = [r for r in rows if r["seed"] == seed][-1]
    return plotting.plot_pareto_front(
        {"MOME": np.asarray(row["mome"]["front"]),
         "MAP-Elites (forward reward)": np.asarray(row["map_elites_forward"]["front"])},
        path,
        reference=tuple(row["reference_point"]),
        title="halfcheetah_multi, 100-step episodes, 9,664 evaluations",
        objective_names=["forward reward", "energy objective (-0.1 sum |a|^2)"],
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--set", action="append", default=[], help="spec overrides (smoke tests)")
    args = parser.parse_args()
    from qdrl.experiment import build_run, load_spec, run

    for seed in range(args.first_seed, args.first_seed + args.seeds):
        spec = load_spec(SPEC, [f"experiment.seed={seed}", "log.progress=false", *args.set])
        run_, _, _ = build_run(spec)
        reference = run_.qd.task.reference_point
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            summary = run(spec, Path(tmp) / "mome", overwrite=True)
            mome_wall = time.perf_counter() - t0
            mome_front = np.loadtxt(Path(tmp) / "mome" / "front.csv", delimiter=",", skiprows=1, ndmin=2)
        t0 = time.perf_counter()
        me_points, me_run_s = run_map_elites(run_, seed)
        me_wall = time.perf_counter() - t0
        me_front = _front(me_points)
        row = {
            "seed": seed,
            "spec": SPEC.name,
            "evaluations": summary["evaluations"],
            "env_steps": summary["env_steps"],
            "reference_point": list(reference),
            "mome": {**_summary(mome_front, reference), "moqd_score": summary["exact_moqd_score"],
                     "run_s": summary["run_s"], "wall_s": mome_wall},
            "map_elites_forward": {**_summary(me_front, reference), "num_elites": len(me_points),
                                   "run_s": me_run_s, "wall_s": me_wall},
        }
        plot_fronts([row], seed, args.out.with_name(f"{args.out.stem}_seed{seed}.png"))
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps({k: v for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
