"""The Uncertain-QD methods against MAP-Elites at equal evaluations, with corrected metrics.

Runs `agents/<algorithm>_<setting>_cpu.toml` for each algorithm and seed, one run at a time, seed
after seed, and appends one JSON line per run to `--out` (default
benchmarks/results/uncertain_<setting>.jsonl): the stored metrics and the corrected ones (every
final elite re-scored `qd.reevaluate_samples` times, Flageat & Cully 2023's corrected repertoire).
The settings:

- `noisy_arm`: the noisy arm, 512 evaluations per iteration for every method (512 offspring x 1,
  64 x 8, or offspring and re-evaluations of stored elites sharing the 512 rows);
- `halfcheetah_uni_noisy`: halfcheetah_uni with `[task] random_start = true` (every episode
  starts from its own random state, so return and feet-contact descriptor are noisy), 30
  iterations of 256 evaluations.

`evaluations` is the loop's own count of every evaluation: candidates times `num_samples` for
ME-Sampling and ME-LS, re-evaluations included for the resampling methods; the final re-scoring
is the measurement, not the run's.

    python benchmarks/uncertain.py noisy_arm --seeds 0 1 2
    python benchmarks/uncertain.py halfcheetah_uni_noisy --seeds 0 1 2 --algorithms map_elites deep_grid
    python benchmarks/uncertain.py noisy_arm --algorithms parallel_adaptive_sampling \\
        --set resampling.max_samples=4   # a variant, recorded with its overrides
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
SETTINGS = ("noisy_arm", "halfcheetah_uni_noisy")
ALGORITHMS = (
    "map_elites", "me_sampling", "me_ls", "deep_grid", "archive_sampling", "adaptive_sampling",
    "parallel_adaptive_sampling",
)
KEYS = (
    "evaluations", "iteration", "qd_score", "coverage", "max_fitness", "num_elites", "corrected_qd_score",
    "corrected_coverage", "corrected_max_fitness", "corrected_num_elites", "reevaluate_samples", "mean_spread",
    "num_samples", "wall_s", "compile_s",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("setting", choices=SETTINGS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS), choices=ALGORITHMS)
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="a spec override KEY=VALUE")
    parser.add_argument("--runs-dir", type=Path, default=None, help="keep the run directories here")
    parser.add_argument("--out", type=Path, default=None, help="default: benchmarks/results/uncertain_<setting>.jsonl")
    args = parser.parse_args()
    out = args.out or ROOT / "benchmarks" / "results" / f"uncertain_{args.setting}.jsonl"
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as tmp:
        runs = args.runs_dir or Path(tmp)
        for seed in args.seeds:
            for algorithm in args.algorithms:
                spec = ROOT / "agents" / f"{algorithm}_{args.setting}_cpu.toml"
                s = run_spec(
                    spec, [f"experiment.seed={seed}", "log.progress=false", "log.plots=false", *args.overrides],
                    runs / f"{algorithm}_s{seed}",
                )
                line = {
                    "algorithm": algorithm, "spec": spec.relative_to(ROOT).as_posix(), "seed": seed,
                    "overrides": args.overrides, **{k: s[k] for k in KEYS if k in s},
                    "device": str(jax.devices()[0]), "commit": commit.strip(),
                }
                print(json.dumps(line), flush=True)
                with out.open("a") as f:
                    f.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
