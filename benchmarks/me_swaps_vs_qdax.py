"""MAP-Elites on halfcheetah_uni, qdrl against QDax 0.5.0, by controlled swaps (the QD score gap of
`compare_qdax_brax.py`).

Per seed, QDax's run is traced (`qdax_me_trace.py`, in QDax's environment: every offspring,
its fitness and descriptor, the repertoire after each iteration), then qdrl replays parts of
it in this environment:

- **insertion**: QDax's own evaluations fed to qdrl's CVT repertoire (QDax's centroids) in
  QDax's order: the repertoire's fitnesses compared with QDax's after every iteration. No
  physics: any difference is a difference of insertion.
- **evaluation**: QDax's offspring, every one of them, scored by qdrl's task from QDax's start
  state, and inserted in QDax's order: per offspring the difference in fitness, descriptor and
  cell, and the QD score of QDax's run as qdrl scores it.
- **qdrl from QDax's start**: qdrl's MAP-Elites (its emitter and key stream) from QDax's initial
  population, centroids and start state.
- **qdrl, own population**: the same with qdrl's own initial population (the bench's init key).
- **QDax from qdrl's population** (`--swap-init`): QDax's run from qdrl's initial population.
- **corrected QD scores** (`--corrected-samples N`): QDax's final repertoire and qdrl's
  benchmark run's, each elite re-scored N times from random start states by one program
  neither run used, the repertoire rebuilt from the medians (`qdrl.qd.reevaluate`).
- **agreement** (`--agreement TRACE RESCORED`, after `qdax_me_trace.py --rescore`): one
  iteration's offspring scored five ways (QDax in its run's scan, QDax batched apart, QDax one
  at a time, qdrl batched, qdrl one at a time), compared pair by pair.
- **qdrl as it runs** (`--bench`): `qdrl bench policy_map_elites --seed S` (qdrl's own centroids,
  start state and population), the run `compare_qdax_brax.py` compares with QDax's.

    python benchmarks/me_swaps_vs_qdax.py --qdax-python QDAX_VENV/bin/python --seeds 10

Settings are `compare_qdax_brax.py`'s (spring, episodes of 100, batch 128, CVT 1024, 64x64 tanh
MLP, iso-line 0.005 / 0.05, 50 iterations, one fixed start state per seed). Traces (about 150 MB
each) go to `--work` and are deleted after use unless `--keep`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
EPISODE = 100
ITERATIONS = 50
BATCH = 128


def _genotypes(d: Any, prefix: str) -> dict[str, dict[str, Any]]:
    import jax.numpy as jnp

    return {f"policy/~/linear_{j}": {"w": jnp.asarray(d[f"{prefix}w{j}"]), "b": jnp.asarray(d[f"{prefix}b{j}"])}
            for j in range(3)}


def _qd(fitnesses: np.ndarray, offset: float) -> float:
    filled = fitnesses > -np.inf
    return float(np.sum(fitnesses[filled].astype(np.float64) + offset))


def _scoring_from(start_key: Any, eval_batch: int, warm: Any) -> tuple[Any, Any]:
    """qdrl's halfcheetah_uni task and its jitted scoring, every policy started from the state of
    QDax's `start_key` (qdrl's tasks compute their one start state at the first call: made here,
    on `warm`, while `fixed_start_state` is patched)."""
    import jax

    from qdrl.tasks import make_task
    from qdrl.tasks import policy as policy_module

    fixed = policy_module.fixed_start_state
    policy_module.fixed_start_state = lambda env, _key: fixed(env, start_key)
    try:
        task = make_task("halfcheetah_uni", episode_length=EPISODE, eval_batch=eval_batch)
        score = jax.jit(task.scoring_fn)
        score(warm, jax.random.PRNGKey(0))
    finally:
        policy_module.fixed_start_state = fixed
    return task, score


def _qdax_repertoires(d: Any, task: Any) -> list[Any]:
    """QDax's run's repertoire after its initial population and after each iteration, rebuilt by
    inserting QDax's own evaluations, in its order, into qdrl's CVT repertoire (QDax's centroids)."""
    import jax

    from qdrl.qd.repertoires import cvt_repertoire

    add = jax.jit(lambda rep, g, desc, fit: rep.add(g, desc, fit)[0])
    rep = cvt_repertoire(task.example_genotype(), jax.numpy.asarray(d["centroids"]),
                         task.descriptor_low, task.descriptor_high)
    reps = [add(rep, _genotypes(d, "init_"), d["init_descriptors"], d["init_fitness"])]
    offspring = _genotypes(d, "off_")
    for t in range(ITERATIONS):
        reps.append(add(reps[-1], jax.tree.map(lambda x, t=t: x[t], offspring), d["descriptors"][t], d["fitness"][t]))
    return reps


def qdrl_side(trace: str, seed: int, init_out: str | None) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp

    from qdrl.qd.emitters.ga import isoline_emitter
    from qdrl.qd.map_elites import MapElites
    from qdrl.qd.repertoires import cvt_repertoire

    d = np.load(trace)
    offset = float(d["qd_offset"])  # QDax's: reward offset x episode length (qdrl's qd_offset is its negative)
    task, score = _scoring_from(jnp.asarray(d["start_key"], jnp.uint32), BATCH, _genotypes(d, "init_"))
    assert abs(task.qd_offset + offset) < 1e-3, (task.qd_offset, offset)
    centroids = jnp.asarray(d["centroids"])

    def empty() -> Any:
        return cvt_repertoire(task.example_genotype(), centroids, task.descriptor_low, task.descriptor_high)

    add = jax.jit(lambda rep, g, desc, fit: rep.add(g, desc, fit)[0])
    off = [jax.tree.map(lambda x, t=t: x[t], _genotypes(d, "off_")) for t in range(ITERATIONS)]

    # 1. Insertion: QDax's evaluations into qdrl's repertoire.
    reps = _qdax_repertoires(d, task)
    stored = [d["init_rep_fitness"], *d["rep_fitness"]]
    mismatch = [int(np.sum(np.asarray(rep.fitnesses) != f)) for rep, f in zip(reps, stored, strict=True)]
    insertion = {
        "cells_differing_per_iteration_max": max(mismatch),
        "first_iteration_differing": next((i for i, m in enumerate(mismatch) if m), None),
        "qd_score": _qd(np.asarray(reps[-1].fitnesses), offset),
    }

    # 2. Evaluation: QDax's offspring scored by qdrl, inserted in QDax's order.
    fits, descs = [], []
    ev = score(_genotypes(d, "init_"), jax.random.PRNGKey(0))
    rep = add(empty(), _genotypes(d, "init_"), ev.descriptors, ev.fitnesses)
    init_fit_diff = np.asarray(ev.fitnesses) - d["init_fitness"]
    for t in range(ITERATIONS):
        ev = score(off[t], jax.random.PRNGKey(t + 1))
        fits.append(np.asarray(ev.fitnesses))
        descs.append(np.asarray(ev.descriptors))
        rep = add(rep, off[t], ev.descriptors, ev.fitnesses)
    fit_q, desc_q = np.stack(fits), np.stack(descs)
    diff = fit_q - d["fitness"]
    cell_of = jax.jit(lambda x: jnp.argmin(jnp.sum((x[:, None] - centroids[None]) ** 2, -1), -1))
    cells_q = np.asarray(cell_of(jnp.asarray(desc_q.reshape(-1, 2))))
    cells_x = np.asarray(cell_of(jnp.asarray(d["descriptors"].reshape(-1, 2))))
    evaluation = {
        "init_max_abs_fitness_diff": float(np.max(np.abs(init_fit_diff))),
        "offspring_mean_fitness_diff": float(np.mean(diff)),
        "offspring_mean_abs_fitness_diff": float(np.mean(np.abs(diff))),
        "offspring_share_abs_fitness_diff_over_1": float(np.mean(np.abs(diff) > 1.0)),
        "offspring_share_exact": float(np.mean(diff == 0.0)),
        "offspring_mean_abs_descriptor_diff": float(np.mean(np.abs(desc_q - d["descriptors"]))),
        "offspring_share_other_cell": float(np.mean(cells_q != cells_x)),
        "qd_score": _qd(np.asarray(rep.fitnesses), offset),
        "coverage": float(np.mean(np.asarray(rep.fitnesses) > -np.inf)),
    }

    # 3-4. qdrl's MAP-Elites from QDax's population, then from its own (same centroids, start).
    me = MapElites(score, isoline_emitter(BATCH, 0.005, 0.05), empty(), task.qd_offset)
    init_key, _cvt_key, run_key = jax.random.split(jax.random.PRNGKey(seed), 3)  # the bench's keys
    run = jax.jit(lambda s: me.run(s, ITERATIONS))
    own = {}
    for name, genotypes in (("from_qdax_population", _genotypes(d, "init_")),
                            ("own_population", task.init_genotypes(init_key, BATCH))):
        state, metrics = run(jax.jit(me.init)(genotypes, run_key))
        own[name] = {"qd_score": _qd(np.asarray(state.repertoire.fitnesses), offset),
                     "coverage": float(metrics["coverage"][-1])}
    if init_out is not None:
        g = task.init_genotypes(init_key, BATCH)
        np.savez(init_out, **{f"{k}{j}": np.asarray(g[f"policy/~/linear_{j}"][k]) for j in range(3) for k in "wb"})
    return {
        "seed": seed,
        "qdax": {"qd_score": float(d["qd_score"][-1]), "coverage": float(np.mean(d["rep_fitness"][-1] > -np.inf))},
        "insertion": insertion,
        "evaluation": evaluation,
        **{f"qdrl_{k}": v for k, v in own.items()},
    }


def agreement(trace: str, rescored: str, iteration: int) -> dict[str, Any]:
    """How far apart five evaluations of the same policies are: QDax inside its run's scan, QDax
    batched in a program of its own, QDax one at a time, qdrl batched, qdrl one at a time."""
    import jax
    import jax.numpy as jnp

    d, r = np.load(trace), np.load(rescored)
    start_key = jnp.asarray(d["start_key"], jnp.uint32)
    genotypes = jax.tree.map(lambda x: x[iteration], _genotypes(d, "off_"))
    _, batched = _scoring_from(start_key, BATCH, genotypes)
    ev = batched(genotypes, jax.random.PRNGKey(0))
    _, one = _scoring_from(start_key, 1, jax.tree.map(lambda x: x[:1], genotypes))
    ones = [one(jax.tree.map(lambda x, i=i: x[i : i + 1], genotypes), jax.random.PRNGKey(0)) for i in range(BATCH)]
    evals = {
        "qdax_scan": (r["scan_fitness"], r["scan_descriptors"]),
        "qdax_batch": (r["batch_fitness"], r["batch_descriptors"]),
        "qdax_one": (r["one_fitness"], r["one_descriptors"]),
        "qdrl_batch": (np.asarray(ev.fitnesses), np.asarray(ev.descriptors)),
        "qdrl_one": (np.array([float(e.fitnesses[0]) for e in ones]), np.stack([np.asarray(e.descriptors[0]) for e in ones])),
    }
    centroids = d["centroids"]

    def cells(desc: np.ndarray) -> np.ndarray:
        return np.argmin(((desc[:, None] - centroids[None]) ** 2).sum(-1), -1)

    names = list(evals)
    pairs = {}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            (fa, da), (fb, db) = evals[a], evals[b]
            pairs[f"{a}~{b}"] = {
                "fitness_corr": round(float(np.corrcoef(fa, fb)[0, 1]), 3),
                "mean_abs_fitness_diff": round(float(np.mean(np.abs(fa - fb))), 2),
                "share_identical": round(float(np.mean((fa == fb) & np.all(da == db, -1))), 3),
                "share_other_cell": round(float(np.mean(cells(da) != cells(db))), 3),
            }
    return {"seed": int(d["seed"]), "iteration": iteration if iteration >= 0 else ITERATIONS + iteration,
            "mean_fitness": {k: round(float(np.mean(v[0])), 2) for k, v in evals.items()}, "pairs": pairs}


def corrected(trace: str, seed: int, samples: int) -> dict[str, Any]:
    """QDax's final repertoire and qdrl's (its benchmark run of the same seed), each re-scored
    `samples` times from random start states by one neutral program (qdrl's random-start
    scoring, which neither run used) and rebuilt from the medians (`qdrl.qd.reevaluate`)."""
    import jax

    from qdrl.bench import policy_map_elites_setup
    from qdrl.qd.reevaluate import default_key, reevaluate

    d = np.load(trace)
    # qdrl's benchmark run of this seed (`qdrl bench policy_map_elites`'s setup), kept in hand.
    task, me, state = policy_map_elites_setup("halfcheetah_uni", episode_length=EPISODE, batch_size=BATCH,
                                              seed=seed, eval_batch=BATCH)
    state, _ = jax.jit(lambda s: me.run(s, ITERATIONS))(state)
    random_starts = task.scoring(fixed_start=False)
    key = default_key(seed)
    # QDax's final repertoire, rebuilt exactly (qdrl_side's insertion check: no cell ever differs).
    rep = _qdax_repertoires(d, task)[-1]
    assert np.array_equal(np.asarray(rep.fitnesses), d["rep_fitness"][-1])
    qdax = reevaluate(rep, random_starts, key, samples, task.qd_offset)
    ours = reevaluate(state.repertoire, random_starts, key, samples, task.qd_offset)

    def pick(r: Any) -> dict[str, float]:
        return {"stored_qd_score": r.stored_metrics["qd_score"], "corrected_qd_score": r.corrected_metrics["qd_score"],
                "stored_coverage": r.stored_metrics["coverage"], "corrected_coverage": r.corrected_metrics["coverage"]}

    return {"seed": seed, "samples": samples, "qdax": pick(qdax), "qdrl_bench": pick(ours)}


def _last_json(text: str) -> dict[str, Any]:
    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    def stats(values: list[float]) -> dict[str, float]:
        m = statistics.mean(values)
        sd = statistics.stdev(values) if len(values) > 1 else 0.0
        return {"mean": round(m, 1), "std": round(sd, 1), "se": round(sd / len(values) ** 0.5, 1),
                "median": round(statistics.median(values), 1), "min": round(min(values), 1),
                "max": round(max(values), 1)}

    arms = {
        "qdax": [r["qdax"]["qd_score"] for r in runs],
        "qdax_scored_by_qdrl": [r["evaluation"]["qd_score"] for r in runs],
        "qdrl_from_qdax_population": [r["qdrl_from_qdax_population"]["qd_score"] for r in runs],
        "qdrl_own_population": [r["qdrl_own_population"]["qd_score"] for r in runs],
    }
    for arm in ("qdax_from_qdrl_population", "qdrl_bench"):
        if all(arm in r for r in runs):
            arms[arm] = [r[arm]["qd_score"] for r in runs]
    if all("corrected" in r for r in runs):
        for side in ("qdax", "qdrl_bench"):
            arms[f"{side}_corrected"] = [r["corrected"][side]["corrected_qd_score"] for r in runs]
    return {
        "seeds": len(runs),
        "qd_score": {k: stats(v) for k, v in arms.items()},
        "insertion_cells_differing_max": max(r["insertion"]["cells_differing_per_iteration_max"] for r in runs),
        "evaluation_share_other_cell_mean": round(statistics.mean(
            r["evaluation"]["offspring_share_other_cell"] for r in runs), 4),
        "evaluation_mean_fitness_diff_mean": round(statistics.mean(
            r["evaluation"]["offspring_mean_fitness_diff"] for r in runs), 3),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--qdax-python", help="QDax's interpreter (runs qdax_me_trace.py)")
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--work", default="/tmp/me_swaps", help="where the traces go")
    p.add_argument("--keep", action="store_true", help="keep the traces")
    p.add_argument("--swap-init", action="store_true", help="also run QDax from qdrl's initial population")
    p.add_argument("--bench", action="store_true", help="also run qdrl's own benchmark run per seed")
    p.add_argument("--corrected-samples", type=int, default=0,
                   help="also re-score QDax's and qdrl's final repertoires this many times per elite "
                        "from random starts (corrected QD score; 0: not)")
    p.add_argument("--qdrl-only", metavar="TRACE", help="(internal) the qdrl side on one trace")
    p.add_argument("--seed", type=int, default=0, help="(with --qdrl-only)")
    p.add_argument("--init-out", default=None, help="(with --qdrl-only) write qdrl's initial population")
    p.add_argument("--agreement", nargs=2, metavar=("TRACE", "RESCORED"),
                   help="(internal) five evaluations of one iteration's offspring compared")
    p.add_argument("--iteration", type=int, default=-1, help="(with --agreement)")
    p.add_argument("--corrected", metavar="TRACE",
                   help="(internal) QDax's final repertoire and qdrl's benchmark run's, re-scored from random starts")
    p.add_argument("--samples", type=int, default=8, help="(with --corrected) re-evaluations per elite")
    p.add_argument("--out", default=str(HERE / "results" / "map_elites_halfcheetah_uni_swaps.json"))
    args = p.parse_args()
    if args.corrected:
        print(json.dumps(corrected(args.corrected, args.seed, args.samples)))
        return
    if args.agreement:
        print(json.dumps(agreement(*args.agreement, args.iteration)))
        return
    if args.qdrl_only:
        print(json.dumps(qdrl_side(args.qdrl_only, args.seed, args.init_out)))
        return
    if not args.qdax_python:
        p.error("--qdax-python is required (QDax's interpreter)")
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    out = Path(args.out)
    runs: list[dict[str, Any]] = json.loads(out.read_text())["runs"] if out.exists() else []
    done = {r["seed"] for r in runs}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        if seed in done:
            continue
        trace = work / f"trace_{seed}.npz"
        if not trace.exists():
            subprocess.run([args.qdax_python, str(HERE / "qdax_me_trace.py"), "--seed", str(seed), "--out", str(trace)],
                           check=True, env=env, capture_output=True, text=True)
        init = work / f"qdrl_init_{seed}.npz"
        cmd = [sys.executable, __file__, "--qdrl-only", str(trace), "--seed", str(seed), "--init-out", str(init)]
        rec = _last_json(subprocess.run(cmd, check=True, env=env, capture_output=True, text=True).stdout)
        if args.swap_init:
            swapped = subprocess.run(
                [args.qdax_python, str(HERE / "qdax_me_trace.py"), "--seed", str(seed), "--init", str(init),
                 "--out", str(work / f"trace_{seed}_qdrl_init.npz")],
                check=True, env=env, capture_output=True, text=True)
            s = _last_json(swapped.stdout)
            rec["qdax_from_qdrl_population"] = {"qd_score": s["qd_score"], "coverage": s["coverage"]}
            if not args.keep:
                (work / f"trace_{seed}_qdrl_init.npz").unlink()
        if args.bench:
            bench = subprocess.run([sys.executable, "-m", "qdrl.cli", "bench", "policy_map_elites",
                                    "--config", "halfcheetah_uni", "--seed", str(seed)],
                                   check=True, env=env, capture_output=True, text=True).stdout
            b = json.loads(bench[bench.index("{"):])["results"][0]
            rec["qdrl_bench"] = {"qd_score": b["qd_score"], "coverage": b["coverage"]}
        if args.corrected_samples:
            cmd = [sys.executable, __file__, "--corrected", str(trace), "--seed", str(seed),
                   "--samples", str(args.corrected_samples)]
            rec["corrected"] = _last_json(subprocess.run(cmd, check=True, env=env, capture_output=True, text=True).stdout)
        if not args.keep:
            trace.unlink()
        runs.append(rec)
        print(json.dumps(rec), file=sys.stderr)
        out.write_text(json.dumps({"runs": runs, "summary": summarise(runs)}, indent=1) + "\n")
    print(json.dumps(summarise(runs)))


if __name__ == "__main__":
    main()
