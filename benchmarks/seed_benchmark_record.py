"""Records a run of the skill-discovery benchmark's suite: every run's final figures as one JSON.

    qdrl suite run benchmarks/suites/seed_benchmark_slice.toml --out runs/seed_benchmark_slice
    python benchmarks/seed_benchmark_record.py runs/seed_benchmark_slice \\
        --out benchmarks/results/seed_benchmark_slice_cpu.json

Per run (task, algorithm, seed): environment steps, wall and run time, log points, the passive
archive's (or repertoire's) QD score, range QD score, coverage and max fitness, and, where
`qdrl adapt` ran, the best return at each multiplier's extremes; plus the machine.
`--merge` keeps the runs already in `--out` that the folder does not hold (a suite recorded over
several sessions or machines): a run in both is taken from the folder.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
from pathlib import Path
from typing import Any

KEYS = ("env_steps", "wall_s", "run_s", "compile_s", "log_points", "num_log_points", "stopped_by",
        "qd_score", "range_qd_score", "coverage", "max_fitness", "evaluations")


def record(folder: Path) -> dict[str, Any]:
    runs = []
    for summary_path in sorted(folder.glob("*/*/seed_*/summary.json")):
        run = summary_path.parent
        summary = json.loads(summary_path.read_text())
        entry: dict[str, Any] = {"task": run.parent.parent.name, "algorithm": run.parent.name, "seed": int(run.name[5:])}
        entry.update({k: summary[k] for k in KEYS if k in summary})
        adaptation = run / "adaptation" / "adaptation.csv"
        if adaptation.is_file():
            with adaptation.open(newline="") as f:
                rows = list(csv.DictReader(f))
            entry["adaptation"] = {
                name: {row["value"]: float(row["best_return"]) for row in rows if row["perturbation"] == name}
                for name in dict.fromkeys(r["perturbation"] for r in rows)
            }
        runs.append(entry)
    return {
        "suite": str(folder), "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                                          "python": platform.python_version()},
        "runs": runs,
    }


def merge(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """`new`'s runs with those of `old` that it lacks, sorted by task, algorithm and seed, under
    `old`'s description (suite, machine)."""
    def key(run: dict[str, Any]) -> tuple[str, str, int]:
        return run["task"], run["algorithm"], run["seed"]

    have = {key(r) for r in new["runs"]}
    runs = sorted(new["runs"] + [r for r in old["runs"] if key(r) not in have], key=key)
    return {**new, **{k: v for k, v in old.items() if k != "runs"}, "runs": runs}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--merge", action="store_true", help="keep the runs of --out that the folder does not hold")
    args = parser.parse_args(argv)
    result = record(args.folder)
    if not result["runs"]:
        print(f"{args.folder}: no finished run of a suite", file=sys.stderr)
        return 1
    if args.merge and args.out.is_file():
        result = merge(json.loads(args.out.read_text()), result)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{len(result['runs'])} runs into {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
