"""PGA-ME on halfcheetah_uni, qdrl against QDax 0.5.0 (its old-pins venv), same settings.

    python benchmarks/pga_me_compare_qdax.py --qdax-python /path/to/qdax-venv/bin/python

qdrl runs `agents/pga_me_halfcheetah_uni_cpu.toml` through `qdrl run` with
`qd.log_every = qd.num_iterations`, so its iterations are ONE compiled `lax.scan`,
timed apart from its compilation, like `benchmarks/qdax_pga_me.py` does for QDax
with the same settings (spring, 100-step episodes, batch 64 = 32 GA + 31 PG +
greedy, CVT 256, TD3 256x256 critics, 50 critic steps, 20 PG steps, batches of 64).
Each run is a fresh process; which side goes first alternates per seed.
env steps/s = batch x iterations x episode length / run time, on both sides.
Writes every run, the means and the ratios to
`benchmarks/results/pga_me_halfcheetah_uni_vs_qdax.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from compare_qdax_map_elites import _json_from

HERE = Path(__file__).resolve().parent
SPEC = HERE.parent / "agents" / "pga_me_halfcheetah_uni_cpu.toml"
BATCH, EPISODE = 64, 100


def run_qdrl(seed: int, iterations: int, env: dict[str, str]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "qdrl.cli", "run", str(SPEC), "--out", str(Path(tmp) / "out"),
               "--set", f"experiment.seed={seed}", "--set", f"qd.num_iterations={iterations}",
               "--set", f"qd.log_every={iterations}", "--set", "log.progress=false",
               "--set", "log.plots=false"]
        subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
        s = json.loads((Path(tmp) / "out" / "summary.json").read_text())
    return {
        "library": "qdrl", "algorithm": "pga_me", "task": "halfcheetah_uni", "seed": seed,
        "iterations": iterations, "evaluations": s["evaluations"],
        "compile_s": round(s["compile_s"], 2), "run_s": round(s["run_s"], 3),
        "env_steps_per_s": round(BATCH * iterations * EPISODE / s["run_s"], 1),
        "qd_score": s["qd_score"], "coverage": s["coverage"], "max_fitness": s["max_fitness"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--qdax-python", required=True)
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--iterations", type=int, default=30)
    p.add_argument("--out", default=str(HERE / "results" / "pga_me_halfcheetah_uni_vs_qdax.json"))
    args = p.parse_args()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    runs: list[dict[str, Any]] = []
    for seed in range(args.seeds):
        for side in (["qdrl", "qdax"] if seed % 2 == 0 else ["qdax", "qdrl"]):
            if side == "qdrl":
                rec = run_qdrl(seed, args.iterations, env)
            else:
                cmd = [args.qdax_python, str(HERE / "qdax_pga_me.py"), "--seed", str(seed),
                       "--iterations", str(args.iterations)]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env).stdout
                rec = _json_from(out)
            rec["side"] = side
            runs.append(rec)
            print(json.dumps(rec), file=sys.stderr)
    summary: dict[str, Any] = {}
    for side in ("qdrl", "qdax"):
        rs = [r for r in runs if r["side"] == side]
        summary[side] = {k: round(statistics.mean(r[k] for r in rs), 3)
                         for k in ("env_steps_per_s", "compile_s", "run_s", "qd_score", "coverage", "evaluations")}
    summary["speed_ratio"] = round(summary["qdrl"]["env_steps_per_s"] / summary["qdax"]["env_steps_per_s"], 2)
    summary["qd_score_ratio"] = round(summary["qdrl"]["qd_score"] / summary["qdax"]["qd_score"], 4)
    from qdrl.bench import machine

    Path(args.out).write_text(json.dumps(
        {"machine": machine(), "task": "halfcheetah_uni", "settings": str(SPEC.name), "summary": summary, "runs": runs},
        indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
