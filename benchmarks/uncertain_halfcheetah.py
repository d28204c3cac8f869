"""The Uncertain-QD methods on halfcheetah_uni with random start states, at equal evaluations.

Runs `agents/<algorithm>_halfcheetah_uni_noisy_cpu.toml` (`[task] random_start = true`: every
evaluation starts from its own random state, so return and feet-contact descriptor are noisy;
30 iterations of 256 evaluations each for every method: 256 offspring x 1 evaluation, 32 x 8,
or offspring and re-evaluations of stored elites sharing the 256 rows) for the given seeds, one
run at a time, seed after seed, and appends one JSON line per run to
benchmarks/results/uncertain_halfcheetah_uni_noisy.jsonl: the stored metrics and the corrected
ones (every final elite re-scored `qd.reevaluate_samples` times from random starts, Flageat &
Cully 2023's corrected repertoire).

    python benchmarks/uncertain_halfcheetah.py --seeds 0 1 2 \
        --algorithms map_elites me_sampling adaptive_sampling deep_grid

`evaluations` counts every episode: candidates times `num_samples` for ME-Sampling and ME-LS,
re-evaluations included for the resampling methods (the loop's own count); the final
re-scoring is the measurement, not the run's.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

import jax

import qdrl.algorithms  # noqa: F401  (the full spec check)
from qdrl.experiment import run_spec

ROOT = Path(__file__).resolve().parents[1]
ALGORITHMS = (
    "map_elites", "me_sampling", "adaptive_sampling", "deep_grid", "archive_sampling", "me_ls",
    "parallel_adaptive_sampling",
)
SAMPLING = ("me_sampling", "me_ls")  # `evaluations` counts candidates, each evaluated num_samples times
KEYS = (
    "qd_score", "coverage", "max_fitness", "num_elites", "corrected_qd_score", "corrected_coverage",
    "corrected_max_fitness", "corrected_num_elites", "reevaluate_samples", "wall_s", "compile_s",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS), choices=ALGORITHMS)
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="a spec override KEY=VALUE")
    parser.add_argument("--runs-dir", type=Path, default=None, help="keep the run directories here")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "uncertain_halfcheetah_uni_noisy.jsonl"
    )
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as tmp:
        runs = args.runs_dir or Path(tmp)
        for seed in args.seeds:
            for algorithm in args.algorithms:
                spec = ROOT / "agents" / f"{algorithm}_halfcheetah_uni_noisy_cpu.toml"
                s = run_spec(
                    spec, [f"experiment.seed={seed}", "log.progress=false", "log.plots=false", *args.overrides],
                    runs / f"{algorithm}_s{seed}",
                )
                samples = int(s.get("num_samples", 1))
                evaluations = s["evaluations"] * samples if algorithm in SAMPLING else s["evaluations"]
                line = {
                    "algorithm": algorithm, "spec": spec.relative_to(ROOT).as_posix(), "seed": seed,
                    "overrides": args.overrides, "num_samples": samples, "evaluations": evaluations,
                    "iterations": s["iteration"], **{k: s[k] for k in KEYS if k in s},
                    "device": str(jax.devices()[0]), "commit": commit.strip(),
                }
                print(json.dumps(line), flush=True)
                with args.out.open("a") as f:
                    f.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
