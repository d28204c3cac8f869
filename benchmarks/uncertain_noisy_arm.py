"""MAP-Elites, ME-Sampling, ME-LS and Deep-Grid on the noisy arm at equal evaluations.

Runs the `*_noisy_arm_cpu` specs (512 evaluations per iteration each: 512 candidates x 1 sample,
or 64 x 8) for the given seeds and appends one JSON line per run to
benchmarks/results/uncertain_noisy_arm.jsonl: the stored and the corrected metrics (every
elite re-evaluated `qd.reevaluate_samples` times, Flageat & Cully 2023's corrected repertoire).

    python benchmarks/uncertain_noisy_arm.py --seeds 0 1 2
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
ALGORITHMS = ("map_elites", "me_sampling", "me_ls", "deep_grid")
KEYS = (
    "qd_score", "coverage", "max_fitness", "num_elites", "corrected_qd_score", "corrected_coverage",
    "corrected_max_fitness", "corrected_num_elites", "reevaluate_samples", "mean_spread", "wall_s",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS))
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "uncertain_noisy_arm.jsonl")
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as tmp:
        for algorithm in args.algorithms:
            spec = ROOT / "agents" / f"{algorithm}_noisy_arm_cpu.toml"
            for seed in args.seeds:
                s = run_spec(spec, [f"experiment.seed={seed}", "log.progress=false"], Path(tmp) / f"{algorithm}_{seed}")
                samples = int(s.get("num_samples", 1))
                line = {
                    "algorithm": algorithm, "spec": spec.relative_to(ROOT).as_posix(), "seed": seed,
                    "num_samples": samples, "candidates": s["evaluations"],
                    "evaluations": s["evaluations"] * samples, "iterations": s["iteration"],
                    **{k: s[k] for k in KEYS if k in s}, "device": str(jax.devices()[0]), "commit": commit.strip(),
                }
                print(json.dumps(line), flush=True)
                with args.out.open("a") as f:
                    f.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
