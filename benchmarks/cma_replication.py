"""Replication of the CMA-ME / CMA-MAE / DQD papers' LP results with the specs in agents/.

Each run is `qdrl run agents/<spec>.toml --set experiment.seed=S` in a fresh process,
one at a time; its summary becomes one JSON line of `--out`. Runs already in the
file are skipped, so the script resumes where it stopped:

    python benchmarks/cma_replication.py --seeds 5 \
        --out benchmarks/results/cma_replication.jsonl
    python benchmarks/cma_replication.py --table --out benchmarks/results/cma_replication.jsonl

`--table` prints mean +- std of the final normalised QD score per spec beside the
published value (CMA-MAE paper Table 1 for the LP sphere 100-D; the DQD paper for
the 1000-D LP sphere and rastrigin). Each line also records the machine's load
average before and after the run: the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
# spec -> (label, published normalised QD score or None)
SPECS: dict[str, tuple[str, float | None]] = {
    "map_elites_lp_sphere": ("MAP-Elites, LP sphere 100-D", 41.64),
    "map_elites_line_lp_sphere": ("MAP-Elites (line), LP sphere 100-D", 49.07),
    "cma_me_lp_sphere": ("CMA-ME, LP sphere 100-D", 36.50),
    "cma_mae_lp_sphere": ("CMA-MAE (alpha 0.01), LP sphere 100-D", 64.86),
    "me_map_elites_lp_sphere": ("Multi-Emitter MAP-Elites (bandit over 60 CMA and GA emitters), LP sphere 100-D", None),
    "cma_maega_lp_sphere": ("CMA-MAEGA (alpha 0.01), LP sphere 1000-D", None),
    "omg_mega_lp_sphere": ("OMG-MEGA, LP sphere 1000-D", 71.58),
    "cma_mega_lp_sphere": ("CMA-MEGA, LP sphere 1000-D", 75.29),
    "cma_mega_adam_lp_sphere": ("CMA-MEGA (Adam), LP sphere 1000-D", None),
    "omg_mega_lp_rastrigin": ("OMG-MEGA, LP rastrigin 1000-D", 55.90),
    "cma_mega_lp_rastrigin": ("CMA-MEGA, LP rastrigin 1000-D", 62.54),
    "cma_mega_adam_lp_rastrigin": ("CMA-MEGA (Adam), LP rastrigin 1000-D", None),
}
# name -> (spec, --set overrides, label, published): runs of a spec with other settings
VARIANTS: dict[str, tuple[str, tuple[str, ...], str, float | None]] = {
    "omg_mega_lp_sphere_18": ("omg_mega_lp_sphere", ("emitter.batch_size=18",),
                              "OMG-MEGA, 18 offspring per iteration (the paper's), LP sphere 1000-D", 71.58),
    "omg_mega_lp_rastrigin_18": ("omg_mega_lp_rastrigin", ("emitter.batch_size=18",),
                                 "OMG-MEGA, 18 offspring per iteration (the paper's), LP rastrigin 1000-D", 55.90),
}
KEYS = ("normalised_qd_score", "qd_score", "coverage", "max_fitness", "iteration", "evaluations",
        "compile_s", "run_s", "wall_s", "evaluations_per_s", "restarts")


def run_one(name: str, seed: int, extra: list[str]) -> dict[str, Any]:
    """One `qdrl run` of `agents/<spec>.toml` (or a variant's) with `seed`, in a fresh process; its summary."""
    spec, sets = (VARIANTS[name][0], VARIANTS[name][1]) if name in VARIANTS else (name, ())
    extra = [*extra, *(a for s in sets for a in ("--set", s))]
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "qdrl.cli", "run", str(ROOT / "agents" / f"{spec}.toml"),
               "--set", f"experiment.seed={seed}", "--set", "log.progress=false",
               "--set", "log.plots=false", *extra, "--out", str(out)]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        elapsed = time.perf_counter() - t0
        summary = json.loads((out / "summary.json").read_text())
    record = {"spec": name, "seed": seed, **{k: summary.get(k) for k in KEYS}}
    if sets:
        record["set"] = list(sets)
    record.update(process_s=round(elapsed, 1), load_before=load_before, load_after=os.getloadavg()[0])
    return record


def table(records: list[dict[str, Any]]) -> str:
    lines = ["| run | normalised QD score (mean ± std, n) | published | run time per seed (s) |",
             "|---|---|---|---|"]
    labels = {**SPECS, **{k: (v[2], v[3]) for k, v in VARIANTS.items()}}
    for spec, (label, published) in labels.items():
        rs = [r["normalised_qd_score"] for r in records if r["spec"] == spec]
        if not rs:
            continue
        sd = statistics.stdev(rs) if len(rs) > 1 else 0.0
        secs = statistics.mean(r["run_s"] for r in records if r["spec"] == spec)
        pub = "—" if published is None else f"{published:.2f}"
        lines.append(f"| {label} | {statistics.mean(rs):.2f} ± {sd:.2f} ({len(rs)}) | {pub} | {secs:.0f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--specs", nargs="+", default=list(SPECS), help=f"of {[*SPECS, *VARIANTS]}")
    p.add_argument("--set", action="append", default=[], help="extra --set overrides for every run")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cma_replication.jsonl")
    p.add_argument("--table", action="store_true", help="print the table of --out and exit")
    args = p.parse_args()
    done = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    if args.table:
        print(table(done))
        return
    extra = [a for s in args.set for a in ("--set", s)]
    for seed in range(args.seeds):
        for spec in args.specs:
            if any(r["spec"] == spec and r["seed"] == seed for r in done):
                continue
            record = run_one(spec, seed, extra)
            done.append(record)
            with args.out.open("a") as f:
                f.write(json.dumps(record) + "\n")
            print(json.dumps(record), flush=True)
    print(table(done))


if __name__ == "__main__":
    main()
