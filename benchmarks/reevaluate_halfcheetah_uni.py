"""Stored against corrected QD metrics of MAP-Elites and PGA-ME on halfcheetah_uni (CPU specs).

    python benchmarks/reevaluate_halfcheetah_uni.py --seeds 0 1 --samples 32 --runs-dir runs_bench

For each algorithm and seed, runs `agents/<algorithm>_halfcheetah_uni_cpu.toml` with
`qdrl run` into `--runs-dir/<algorithm>_halfcheetah_uni_cpu_s<seed>` (a finished run
found there is reused: its `config.toml` is recorded), then re-scores every elite of
its final repertoire `--samples` times from random start states, as
`qdrl reevaluate DIR --samples N` does (Flageat & Cully 2023; `qdrl.qd.reevaluate`):
each elite moves to the cell of its median descriptor with its median return, the
best keeping a shared cell. The run's own figures come from one evaluation per
elite, from the one fixed start state of the QD-RL benchmarks.

Writes `benchmarks/results/reevaluate_halfcheetah_uni.json`: per run, the stored and
the corrected QD score, coverage and max fitness, and per algorithm their means and
the corrected / stored ratios.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
TASK = "halfcheetah_uni"
KEYS = ("qd_score", "coverage", "max_fitness")


def run_dir(runs_dir: Path, algorithm: str, seed: int, iterations: int | None) -> Path:
    """A finished `qdrl run` of the algorithm's CPU spec with this seed (run now if absent)."""
    from qdrl.experiment import run_spec

    out = runs_dir / f"{algorithm}_{TASK}_cpu_s{seed}" if iterations is None else (
        runs_dir / f"{algorithm}_{TASK}_cpu_s{seed}_it{iterations}"
    )
    if not (out / "summary.json").exists():
        overrides = [f"experiment.seed={seed}", "log.progress=false"]
        if iterations is not None:
            overrides.append(f"qd.num_iterations={iterations}")
        run_spec(ROOT / "agents" / f"{algorithm}_{TASK}_cpu.toml", overrides, out, overwrite=True)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algorithms", nargs="+", default=["map_elites", "pga_me"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    p.add_argument("--samples", type=int, default=32, help="re-evaluations per elite")
    p.add_argument("--iterations", type=int, default=None, help="override qd.num_iterations (default: the spec's)")
    p.add_argument("--runs-dir", default=str(ROOT / "runs" / "reevaluate"))
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "reevaluate_halfcheetah_uni.json"))
    args = p.parse_args()

    from qdrl import load_run
    from qdrl.bench import machine

    runs: list[dict[str, Any]] = []
    for seed in args.seeds:
        for algorithm in args.algorithms:
            run = load_run(run_dir(Path(args.runs_dir), algorithm, seed, args.iterations))
            report = run.reevaluate(args.samples)
            assert run.summary is not None
            rec = {
                "algorithm": algorithm,
                "seed": seed,
                "spec": f"agents/{algorithm}_{TASK}_cpu.toml",
                "iterations": int(run.config["qd"]["num_iterations"]),
                "evaluations": run.summary["evaluations"],
                "run_wall_s": run.summary["wall_s"],
                "config": run.config,
                **{k: report[k] for k in ("samples", "elites_reevaluated", "elites_moved", "stored", "corrected")},
                "reevaluation_wall_s": report["wall_s"],
            }
            runs.append(rec)
            print(json.dumps({k: rec[k] for k in ("algorithm", "seed", "stored", "corrected")}), file=sys.stderr)

    summary: dict[str, Any] = {}
    for algorithm in args.algorithms:
        mine = [r for r in runs if r["algorithm"] == algorithm]
        entry: dict[str, Any] = {"seeds": len(mine)}
        for which in ("stored", "corrected"):
            entry[which] = {k: round(statistics.fmean(r[which][k] for r in mine), 4) for k in KEYS}
        entry["corrected_over_stored"] = {
            k: round(entry["corrected"][k] / entry["stored"][k], 3) for k in ("qd_score", "coverage")
        }
        summary[algorithm] = entry
    result = {
        "command": "python " + " ".join(shlex.quote(a) for a in [Path(sys.argv[0]).as_posix(), *sys.argv[1:]]),
        "task": TASK,
        "samples": args.samples,
        "machine": machine(),
        "summary": summary,
        "runs": runs,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
